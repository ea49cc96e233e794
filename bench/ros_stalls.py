"""Planner processes frozen at random through the node suite: does a late arm stay safe?

    python bench/ros_stalls.py [--cell five_ur5] [--seed 99] [--count 10] [--planner-processes 2]
        [--rows before,today] [--stall-rate 1.5] [--stall-ms 40,320] [--name ros_stalls]
        [--results DIR] [--keep DIR]

An overloaded machine runs a planner process's ticks late; here that is made to happen on
purpose and at a known rate: while an episode runs, a thread of this script freezes one planner
process at a time (SIGSTOP, then SIGCONT after 40–320 ms, uniform; the freezes start as a Poisson
process of ``--stall-rate`` per second over the whole suite), so every arm of that process gets
no command for that long and then catches up. The same episodes (``orchestrate run --cell CELL
--seed SEED --count COUNT --planner-processes K``, real time, simulated clock) run once per
row (``--rows``): ``today`` is the defaults (the bridge applies a command for at most
``command_validity`` 0.06 s; a planner never sends a plan over ``plan_age`` 1.5 periods old);
``before`` turns both rules off as they were before they existed (``command_validity`` 0.2 s,
the watchdog's timeout; ``plan_age`` .inf), so a late arm keeps its last command for up to five
periods and then runs on a plan made before the freeze. Freezes follow the same seeded schedule
in each row.

Per episode: the outcome, the closest approach between any two arms (exact distance at every
second logged instant), the bridge's steps held on expired commands and watchdog trips, and the
freezes made. Results: ``bench/results/<name>.json`` and ``.md`` (``--results`` elsewhere);
``--keep`` keeps the bags and process outputs.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np
from _report import machine_at_end, write_report

RESULTS = Path(__file__).resolve().parent / "results"
PLANNERS = ("nehmo_ros.arm_planner", "nehmo_ros.planner_group")
BRIDGE = "sim_bridge.bridge"
COUNTS = re.compile(r"sim_bridge: counts (\{.*\})")


def _processes() -> dict[int, str]:
    out = {}
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            out[int(pid)] = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
        except OSError:
            continue
    return out


class Freezer(threading.Thread):
    """Freezes a random planner process now and then while a bridge runs (see the module)."""

    def __init__(self, rate: float, ms: tuple[float, float], seed: int) -> None:
        super().__init__(daemon=True)
        self.rate, self.ms = rate, ms
        self.rng = np.random.default_rng(seed)
        self.halt = threading.Event()
        self.freezes: list[float] = []  # [ms] of each freeze made

    def run(self) -> None:
        while not self.halt.wait(self.rng.exponential(1.0 / self.rate)):
            duration = float(self.rng.uniform(*self.ms)) / 1e3
            procs = _processes()
            if not any(BRIDGE in cmd for cmd in procs.values()):
                continue  # between episodes: planners starting or stopping
            pids = sorted(p for p, cmd in procs.items() if any(m in cmd for m in PLANNERS))
            if not pids:
                continue
            pid = pids[int(self.rng.integers(len(pids)))]
            try:
                os.kill(pid, signal.SIGSTOP)
            except OSError:
                continue
            try:
                self.halt.wait(duration)
            finally:
                with contextlib.suppress(OSError):
                    os.kill(pid, signal.SIGCONT)
            self.freezes.append(duration * 1e3)


def closest_approach(bag: Path) -> float:
    """The smallest exact distance [m] between two arms over the episode (every 2nd instant)."""
    from nehmo_core.eval.episode_log import read_episode_log
    from nehmo_core.eval.render import distance_series

    _, series = distance_series(read_episode_log(bag), stride=2)
    return float(min(s.min() for s in series.values()))


ROWS = {
    "before": ["--bridge-param", "command_validity=0.2", "--planner-param", "plan_age=.inf"],
    "today": [],
}


def run(args: argparse.Namespace, row: str, out: Path) -> dict[str, Any]:
    argv = [sys.executable, "-m", "nehmo_ros.orchestrate", "run", "--cell", args.cell]
    argv += ["--seed", str(args.seed), "--count", str(args.count), "--out", str(out)]
    argv += ["--planner-processes", str(args.planner_processes), *ROWS[row]]
    freezer = Freezer(args.stall_rate, args.stall_ms, args.seed)
    freezer.start()
    start = time.monotonic()
    done = subprocess.run(argv, capture_output=True, text=True)
    freezer.halt.set()
    freezer.join()
    summary = json.loads((out / "summary.json").read_text())
    episodes = []
    for e in summary["episodes"]:
        log = (out / "logs" / Path(e["log"]).name / "sim_bridge.log").read_text(errors="replace")
        found = COUNTS.findall(log)
        counts = json.loads(found[-1]) if found else {}
        ok = e["outcome"] != "error"
        episodes.append(
            {
                "episode": e["episode"],
                "outcome": e["outcome"],
                "end_time": e["end_time"],
                "closest_m": round(closest_approach(Path(e["log"])), 4) if ok else None,
                "expired_steps": sum(counts.get("expired_command_steps", {}).values()),
                "watchdog_trips": sum(counts.get("watchdog_trips", {}).values()),
            }
        )
        print(f"{row} episode {e['episode']}: {episodes[-1]}", flush=True)
    return {
        "row": row,
        "orchestrate_options": " ".join(ROWS[row]),
        "exit_code": done.returncode,
        "wall_seconds": round(time.monotonic() - start, 1),
        "freezes": len(freezer.freezes),
        "frozen_ms_total": round(sum(freezer.freezes)),
        "metrics": summary["metrics"],
        "episodes": episodes,
    }


def markdown(result: dict[str, Any]) -> str:
    lines = [
        f"# Frozen planner processes: {result['cell']}, {result['planner_processes']} planner "
        f"processes, scenario seed {result['seed']}",
        "",
        f"{result['machine']}. `{result['command']}`. Freezes: {result['stall_rate']:g} per "
        f"second over the suite, {result['stall_ms'][0]:g}–{result['stall_ms'][1]:g} ms each "
        "(SIGSTOP/SIGCONT of one planner process). Rows run one after the other, same episodes; "
        "*before*: `command_validity` 0.2 s and `plan_age` .inf (the rules off), *today*: the "
        "defaults (0.06 s, 1.5 periods).",
        "",
        "| row | episodes | success | collision | stuck | error | closest "
        "approach min / median [cm] | freezes | steps held on expired commands | watchdog "
        "trips |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in result["runs"]:
        outcomes = [e["outcome"] for e in r["episodes"]]
        closest = [e["closest_m"] * 100 for e in r["episodes"] if e["closest_m"] is not None]
        near = f"{min(closest):.1f} / {np.median(closest):.1f}" if closest else "–"
        lines.append(
            f"| {r['row']} | {len(outcomes)} | {outcomes.count('success')} | "
            f"{outcomes.count('collision')} | {outcomes.count('stuck')} | "
            f"{outcomes.count('error')} | {near} | {r['freezes']} | "
            f"{sum(e['expired_steps'] for e in r['episodes'])} | "
            f"{sum(e['watchdog_trips'] for e in r['episodes'])} |"
        )
    lines += ["", "Per episode (outcome, closest approach [cm]):", ""]
    header = "| episode | " + " | ".join(r["row"] for r in result["runs"])
    lines += [header + " |", "|---" * (len(result["runs"]) + 1) + "|"]
    for i in range(len(result["runs"][0]["episodes"])):
        cells = []
        for r in result["runs"]:
            e = r["episodes"][i]
            near = f"{e['closest_m'] * 100:.1f}" if e["closest_m"] is not None else "–"
            cells.append(f"{e['outcome']}, {near}")
        lines.append(f"| {r['episodes'][i]['episode']} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cell", default="five_ur5")
    parser.add_argument("--seed", type=int, default=99, help="scenario seed (and freeze seed)")
    parser.add_argument("--count", type=int, default=10, help="episodes per row")
    parser.add_argument("--planner-processes", type=int, default=2)
    parser.add_argument("--rows", default="before,today", help=f"rows, of {sorted(ROWS)}")
    parser.add_argument("--stall-rate", type=float, default=1.5, help="freezes per second")
    parser.add_argument("--stall-ms", default="40,320", help="freeze length range [ms]")
    parser.add_argument("--name", default="ros_stalls", help="report name: results/<name>.md")
    parser.add_argument("--keep", help="directory for the bags and the process outputs")
    parser.add_argument("--results", default=str(RESULTS), help="where the report goes")
    args = parser.parse_args()
    rows = [x.strip() for x in args.rows.split(",") if x.strip()]
    low, high = (float(x) for x in args.stall_ms.split(","))
    args.stall_ms = (low, high)
    if not rows or set(rows) - set(ROWS):
        parser.error(f"--rows takes names of {sorted(ROWS)}, got {args.rows}")
    if not 0 < low <= high or not args.stall_rate > 0 or args.count < 1:
        parser.error("--stall-ms needs 0 < low <= high, --stall-rate > 0, --count >= 1")
    runs = []
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(args.keep) if args.keep else Path(tmp)
        for row in rows:
            runs.append(run(args, row, root / row))
    command = (
        f"python bench/ros_stalls.py --cell {args.cell} --seed {args.seed} --count {args.count} "
        f"--planner-processes {args.planner_processes} --rows {args.rows} "
        f"--stall-rate {args.stall_rate:g} --stall-ms {low:g},{high:g} --name {args.name}"
    )
    result = {
        "cell": args.cell,
        "seed": args.seed,
        "planner_processes": args.planner_processes,
        "stall_rate": args.stall_rate,
        "stall_ms": [low, high],
        "command": command,
        "runs": runs,
        "machine": machine_at_end(),
    }
    print(write_report(Path(args.results), args.name, result, markdown))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
