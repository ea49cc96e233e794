"""One task through the node suite: did it succeed, and did every planner keep 25 Hz?

    python bench/ros_task.py TASK_FILE [--name ros_task] [--layouts 0,2,1] [--repeats 2]
        [--real-time-factors 1,0.5] [--results DIR] [--keep DIR]

Runs ``orchestrate run --task TASK_FILE`` (a task in Ha et al.'s format, e.g. from ``nehmo tasks
generate``): the recorder, the planners and the ``sim_bridge`` as separate rclpy processes,
simulated time at real-time factor 1 (or each of ``--real-time-factors``: below 1 the bridge steps
slower than the wall clock, as a simulator does whose machine cannot keep up, and the planners get
that much more wall time per tick). ``--layouts`` lists how the planners are housed, one run (or
``--repeats``) each, in turn: 0 is one ``arm_planner`` process per arm, k > 0 is the arms' planner
nodes in k ``arm_planners`` processes (``orchestrate --planner-processes k``). Each episode is
evaluated from its bag as ``orchestrate`` does; per arm, the command periods at the planner (the
wall-clock publish instants ``publish_wall_ns`` of its statuses, the periods times the
real-time factor), at the planner in simulated time
(``tick_ns``: its node clock at each tick, which is what the simulated arms see) and at the
recorder (receive times of its commands) are reported as percentiles and as the share within 40 ± 5
ms (the first second left out), with how fast simulated time ran against the wall clock over the
ticks (below 1: the bridge fell behind real time), the planners' missed deadlines and fail-safes,
and the planner processes' peak memory (summed PSS) and CPU seconds from ``/proc``. Results:
``bench/results/<name>.json`` and ``.md`` (``--results`` elsewhere); ``--keep`` keeps every run's
bag and process outputs.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
from _report import machine_at_end, write_report
from ros_rate import analyse, period_rows

from nehmo_core.eval.ha_tasks import load_task

RESULTS = Path(__file__).resolve().parent / "results"


def layout_name(processes: int, arms: int) -> str:
    if processes == 0:
        return f"{arms} processes (one per arm)"
    k = min(processes, arms)
    return f"{k} process{'es' if k > 1 else ''} ({-(-arms // k)} nodes each at most)"


class PlannerUsage(threading.Thread):
    """Samples the planner processes (command lines naming the planner modules) every 0.5 s
    from ``/proc``: the peak of their summed proportional set size (PSS: shared pages split
    among the processes sharing them) and the CPU seconds (user + system) each used."""

    MARKS = ("nehmo_ros.arm_planner", "nehmo_ros.planner_group")

    def __init__(self) -> None:
        super().__init__(daemon=True)
        self.halt = threading.Event()
        self.peak_pss_mb = 0.0
        self.cpu_s: dict[int, float] = {}
        self.tick = os.sysconf("SC_CLK_TCK")

    def run(self) -> None:
        while not self.halt.wait(0.5):
            total_kb = 0
            for pid in filter(str.isdigit, os.listdir("/proc")):
                try:
                    cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
                    if not any(m in cmd for m in self.MARKS):
                        continue
                    rollup = Path(f"/proc/{pid}/smaps_rollup").read_text().splitlines()
                    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
                except OSError:
                    continue  # ended meanwhile
                total_kb += next(int(ln.split()[1]) for ln in rollup if ln.startswith("Pss:"))
                self.cpu_s[int(pid)] = (int(stat[11]) + int(stat[12])) / self.tick
            self.peak_pss_mb = max(self.peak_pss_mb, total_kb / 1024)


def run(
    task: Path, out: Path, processes: int, rtf: float = 1.0, bridge: Sequence[str] = ()
) -> dict[str, Any]:
    argv = [sys.executable, "-m", "nehmo_ros.orchestrate", "run", "--task", str(task)]
    argv += ["--planner-processes", str(processes), "--out", str(out)]
    argv += ["--real-time-factor", str(rtf)]
    for param in bridge:
        argv += ["--bridge-param", param]
    usage = PlannerUsage()
    usage.start()
    start = time.monotonic()
    done = subprocess.run(argv, capture_output=True, text=True)
    wall = time.monotonic() - start
    usage.halt.set()
    usage.join()
    summary = json.loads((out / "summary.json").read_text())
    episode = summary["episodes"][0]
    arms = list(load_task(task).cell.arm_ids)
    return {
        "planner_processes": processes,
        "layout": layout_name(processes, len(arms)),
        "real_time_factor": rtf,
        "exit_code": done.returncode,
        "outcome": episode["outcome"],
        "error": episode.get("error", ""),
        "end_time": episode["end_time"],
        "process_exit_codes": episode["exit_codes"],
        "wall_seconds": round(wall, 1),
        "planner_processes_seen": len(usage.cpu_s),
        "planner_peak_pss_mb": round(usage.peak_pss_mb, 1),
        "planner_cpu_seconds": round(sum(usage.cpu_s.values()), 1),
        "rmw": summary.get("rmw", ""),
        "per_arm": analyse(Path(episode["log"]), arms, skip_s=1.0, real_time_factor=rtf),
    }


def _shares(r: dict[str, Any], where: str) -> list[float]:
    return [s[where].get("within_40pm5_pct", 0.0) for s in r["per_arm"].values() if where in s]


def markdown(result: dict[str, Any]) -> str:
    runs = result["runs"]
    lines = [
        f"# Task {result['task']} through the node suite ({result['arms']} arms)",
        "",
        f"{result['machine']}; rclpy on {runs[0].get('rmw') or '?'}; the bridge's real-time factor "
        f"per row (RTF). `{result['command']}`. Runs in the order listed, one at a time.",
        "",
        "Share of each arm's command periods within 40 ± 5 ms (worst arm / median arm), at the "
        "planner (publish instants on the wall clock, times the RTF: below 1 a tick is due every "
        "40 ms / RTF of wall time), at the planner in simulated time (its node clock at each "
        "tick) and at the recorder (receive instants); the planner "
        "processes' peak summed PSS and CPU seconds (user + system, start-up included) over the "
        "run, sampled from `/proc` every 0.5 s:",
        "",
        "| planners in | RTF | run | outcome | end [s] | at planner worst / median | at planner, "
        "simulated time, worst / median | simulated / wall time | at recorder worst "
        "/ median | worst arm p1 / p99 at planner [ms] | misses | fail-safes | planners' peak "
        "PSS [MB] | planners' CPU [s] | exit codes |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in runs:
        planner, recorder = _shares(r, "at_planner"), _shares(r, "at_recorder")
        sim = _shares(r, "at_planner_node_clock")
        sim_cell = f"{min(sim):.1f} / {np.median(sim):.1f} %" if sim else "–"
        rates = [s["clock_rate"] for s in r["per_arm"].values() if "clock_rate" in s]
        rate_cell = f"{np.median(rates):.3f}" if rates else "–"
        worst = min(r["per_arm"].values(), key=lambda s: s["at_planner"].get("within_40pm5_pct", 0))
        q = worst["at_planner"].get("p0.1_p1_p50_p99_p99.9_ms", [float("nan")] * 5)
        misses = sum(s["deadline_misses"] for s in r["per_arm"].values())
        fails = sum(s["fail_safes"] for s in r["per_arm"].values())
        codes = "all 0" if all(c == 0 for c in r["process_exit_codes"].values()) else "see json"
        lines.append(
            f"| {r['layout']} | {r['real_time_factor']:g} | {r['repeat']} | "
            f"{r['outcome']} | {r['end_time']} | "
            f"{min(planner):.1f} / {np.median(planner):.1f} % | {sim_cell} | {rate_cell} | "
            f"{min(recorder):.1f} / {np.median(recorder):.1f} % | {q[1]} / {q[3]} | {misses} | "
            f"{fails} | {r['planner_peak_pss_mb']:.0f} | {r['planner_cpu_seconds']:.0f} | {codes} |"
        )
    for r in runs:
        if r["repeat"] != 0:
            continue
        lines += [
            "",
            f"## {r['layout']}, real-time factor {r['real_time_factor']:g}, run 0",
            "",
            "| arm | where | periods | within 40±5 ms | p0.1 / p1 / p50 / p99 / p99.9 [ms] | max |"
            " misses | fail-safes |",
            "|---|---|---|---|---|---|---|---|",
            *period_rows(r["per_arm"]),
        ]
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("task", type=Path, help="a task file (Ha et al.'s format)")
    parser.add_argument("--name", default="ros_task", help="report name: results/<name>.md")
    parser.add_argument(
        "--layouts", default="0", help="planner processes per run, comma-separated (0: one per arm)"
    )
    parser.add_argument("--repeats", type=int, default=1, help="runs per layout")
    parser.add_argument(
        "--real-time-factors", default="1", help="the bridge's real-time factors, comma-separated"
    )
    parser.add_argument(
        "--bridge-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a sim_bridge parameter for every run (orchestrate --bridge-param; repeatable)",
    )
    parser.add_argument("--keep", help="directory for the bags and the process outputs")
    parser.add_argument("--results", default=str(RESULTS), help="where the report goes")
    args = parser.parse_args()
    layouts = [int(x) for x in args.layouts.split(",") if x.strip()]
    rtfs = [float(x) for x in args.real_time_factors.split(",") if x.strip()]
    if not layouts or any(k < 0 for k in layouts) or args.repeats < 1:
        parser.error("--layouts takes integers >= 0, --repeats an integer >= 1")
    if not rtfs or any(not 0 < f <= 1 for f in rtfs):
        parser.error(f"--real-time-factors takes numbers in (0, 1], got {args.real_time_factors}")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep) if args.keep else Path(tmp)
        for repeat in range(args.repeats):
            for rtf in rtfs:
                for k in layouts:
                    r = run(
                        args.task,
                        root / f"layout{k}_rtf{rtf:g}_run{repeat}",
                        k,
                        rtf,
                        args.bridge_param,
                    )
                    runs.append({**r, "repeat": repeat})
                    print(f"{r['layout']} at RTF {rtf:g}, run {repeat}: {r['outcome']}", flush=True)
    command = f"python bench/ros_task.py {args.task.name} --name {args.name}"
    command += f" --layouts {args.layouts} --repeats {args.repeats}"
    if args.real_time_factors != "1":
        command += f" --real-time-factors {args.real_time_factors}"
    command += "".join(f" --bridge-param {p}" for p in args.bridge_param)
    result = {
        "task": args.task.name,
        "arms": len(load_task(args.task).cell.arm_ids),
        "command": command,
        "runs": runs,
        "machine": machine_at_end(),
    }
    print(write_report(Path(args.results), args.name, result, markdown))
    return 0 if all(r["outcome"] == "success" for r in runs) else 1


if __name__ == "__main__":
    raise SystemExit(main())
