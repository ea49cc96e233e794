"""Do the planners hold 25 Hz? Three arms, the bridge and the recorder for 60 s of wall time.

    python bench/ros_rate.py [--seconds 60] [--cell triple_ur5] [--model shipped]

Starts the node suite as separate rclpy processes (ROS 2 Jazzy, Fast DDS, discovery on this machine
only, own DDS domain) in real time (wall-clock stamps, no /clock), lets it run ``--seconds``, stops
it with SIGINT and reads the recorder's bag. Per arm it reports the command periods measured two
ways: at the planner (its timer's publish instants, ``publish_wall_ns`` in
``/<arm>/planner/status``) and at the recorder (receive times of
``/<arm>/velocity_controller/commands``), as percentiles and as the share within 40 ± 5 ms (target ≥
99 %), plus deadline misses and fail-safes. Results go to ``bench/results/ros_rate.json`` and
``.md``. The episode is scenario 0 of seed 0 of the cell; arms that reach their goals keep planning
(and commanding zero) until the end."""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
from _report import machine_at_end, write_report

from nehmo_core.logs import iter_log
from nehmo_core.logs.messages import DiagnosticStatus
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import save_scenario_set
from nehmo_core.sim.scenarios import generate_scenario_set
from nehmo_ros.processes import Process, child_env, isolated_domain, node_command, reported_rmw
from nehmo_ros.suite_settings import SuiteSettings

RESULTS = Path(__file__).resolve().parent / "results"
PERIOD_MS, TOLERANCE_MS = 40.0, 5.0


def period_stats(periods_ms: np.ndarray) -> dict[str, Any]:
    """Percentiles [ms] and the share within 40 ± 5 ms."""
    if len(periods_ms) == 0:
        return {"count": 0}
    within = np.abs(periods_ms - PERIOD_MS) <= TOLERANCE_MS
    q = np.percentile(periods_ms, [0.1, 1, 50, 99, 99.9])
    return {
        "count": len(periods_ms),
        "within_40pm5_pct": float(100.0 * within.mean()),
        "p0.1_p1_p50_p99_p99.9_ms": [round(float(x), 2) for x in q],
        "min_ms": round(float(periods_ms.min()), 2),
        "max_ms": round(float(periods_ms.max()), 2),
    }


def analyse(
    log: Path, arm_ids: list[str], skip_s: float, real_time_factor: float = 1.0
) -> dict[str, Any]:
    """Per-arm period statistics from the log (the first ``skip_s`` seconds left out). With the
    simulation run at ``real_time_factor`` below 1, a tick is due every ``40 ms / factor`` of wall
    time, so the wall-clock periods at the planner are scaled by the factor before they are
    compared with 40 ms."""
    publish: dict[str, list[int]] = {a: [] for a in arm_ids}
    ticks: dict[str, list[int]] = {a: [] for a in arm_ids}  # the node clock at each tick
    receive: dict[str, list[int]] = {a: [] for a in arm_ids}
    last_status: dict[str, dict[str, str]] = {}
    for rec in iter_log(log):
        arm = rec.topic.split("/")[1] if rec.topic.count("/") >= 2 else ""
        if arm not in publish:
            continue
        if rec.topic.endswith("/velocity_controller/commands"):
            receive[arm].append(rec.log_time_ns)
        elif rec.topic.endswith("/planner/status") and isinstance(rec.message, DiagnosticStatus):
            values = {kv.key: kv.value for kv in rec.message.values}
            publish[arm].append(int(values["publish_wall_ns"]))
            if "tick_ns" in values:  # statuses of older planners lack it
                ticks[arm].append(int(values["tick_ns"]))
            last_status[arm] = values
    out: dict[str, Any] = {}
    for a in arm_ids:
        stats: dict[str, Any] = {}
        for name, stamps, scale in (
            ("at_planner", publish[a], real_time_factor),
            ("at_recorder", receive[a], 1.0),
        ):
            t = np.sort(np.asarray(stamps, dtype=np.int64))
            t = t[t >= t[0] + skip_s * 1e9] if len(t) else t
            stats[name] = period_stats(np.diff(t) * scale / 1e6)
        if len(ticks[a]) == len(publish[a]) > 2:
            # the same ticks on the node clock (simulated time under use_sim_time), and how
            # fast that clock ran against the wall clock over them
            sim, wall = np.asarray(ticks[a], dtype=np.int64), np.asarray(publish[a], np.int64)
            keep = wall >= wall.min() + skip_s * 1e9
            sim, wall = sim[keep], wall[keep]
            stats["at_planner_node_clock"] = period_stats(np.diff(np.sort(sim)) / 1e6)
            if len(sim) > 1 and wall.max() > wall.min():
                stats["clock_rate"] = round(float(np.ptp(sim) / np.ptp(wall)), 4)
        values = last_status.get(a, {})
        stats["ticks"] = int(values.get("ticks", 0))
        stats["deadline_misses"] = int(values.get("deadline_misses", 0))
        stats["fail_safes"] = int(values.get("fail_safes", 0))
        out[a] = stats
    return out


def run(cell_name: str, model: str, seconds: float, out: Path) -> dict[str, Any]:
    cell = load_cell(cell_name)
    settings = SuiteSettings(model=model)
    domain = isolated_domain()
    env = child_env(settings, domain)
    scenario_file = save_scenario_set(generate_scenario_set(cell, 0, 1), out / "scenarios.json")
    log = out / "ros_rate_bag"
    procs: list[Process] = []
    try:
        recorder = Process(
            "recorder",
            node_command(
                "nehmo_ros.recorder",
                {"cell": cell.name, "output": str(log), "stamp_source": "receive"},
            ),
            env,
            out / "recorder.log",
            settings.recorder_nice,
        )
        procs.append(recorder)
        if not recorder.wait_for("recording", 60):
            raise RuntimeError(recorder.output())
        for arm_id in cell.arm_ids:
            params = {
                "arm_id": arm_id,
                "cell": cell.name,
                "planner": "nehmo",
                "model": model,
                # synthetic stand-ins exist for 0.6 m pairs only (the shipped models cover all)
                "allow_unmodelled": model == "synthetic",
            }
            argv = node_command("nehmo_ros.arm_planner", params, ["-r", f"__node:=p_{arm_id}"])
            procs.append(Process(arm_id, argv, env, out / f"planner_{arm_id}.log", 0))
        for p in procs[1:]:
            if not p.wait_for("of cell", 120):
                raise RuntimeError(p.output())
        bridge_params = {
            "cell": cell.name,
            "scenarios": str(scenario_file),
            "time_limit": 3600.0,
            "planners": "nehmo",
            "min_subscribers": len(cell.arm_ids) + 1,  # every planner and the recorder
        }
        argv = node_command("sim_bridge.bridge", bridge_params)
        procs.append(Process("bridge", argv, env, out / "bridge.log", 0))
        if not procs[-1].wait_for("episode started", 60):
            raise RuntimeError(procs[-1].output())
        time.sleep(seconds)
    finally:
        codes = {p.name: p.stop(10.0) for p in reversed(procs)}
    per_arm = analyse(log, list(cell.arm_ids), skip_s=1.0)
    return {
        "cell": cell.name,
        "model": model,
        "scenario": {"seed": 0, "index": 0},
        "rmw": reported_rmw(procs[-1].output()) if procs else "",
        "seconds": seconds,
        "recorder_nice": settings.recorder_nice,
        "exit_codes": codes,
        **per_arm,
    }


def markdown(result: dict[str, Any]) -> str:
    lines = [
        f"# Command periods over {result['seconds']:.0f} s, cell {result['cell']}",
        "",
        f"{result['machine']}; rclpy on {result.get('rmw') or '?'}; model {result['model']};"
        f" scenario 0 of seed 0; recorder at niceness +{result.get('recorder_nice', 0)};"
        " target: ≥ 99 % within 40 ± 5 ms at the planners (the recorder's receive times"
        " add its own scheduling delay).",
        "",
        "| arm | where | periods | within 40±5 ms | p0.1 / p1 / p50 / p99 / p99.9 [ms] | max |"
        " misses | fail-safes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    per_arm = {a: s for a, s in result.items() if isinstance(s, dict) and "at_planner" in s}
    return "\n".join(lines + period_rows(per_arm)) + "\n"


def period_rows(per_arm: dict[str, Any]) -> list[str]:
    """Markdown table rows of :func:`analyse`'s per-arm statistics (planner in wall time, planner
    on its node clock, recorder)."""
    rows = []
    for arm, stats in per_arm.items():
        for where in ("at_planner", "at_planner_node_clock", "at_recorder"):
            if where not in stats:
                continue
            s = stats[where]
            rows.append(
                f"| {arm} | {where} | {s.get('count', 0)} | {s.get('within_40pm5_pct', 0):.2f} %"
                f" | {s.get('p0.1_p1_p50_p99_p99.9_ms')} | {s.get('max_ms')} |"
                f" {stats['deadline_misses']} | {stats['fail_safes']} |"
            )
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--cell", default="triple_ur5")
    parser.add_argument("--model", default="shipped", help="shipped | synthetic | a path")
    parser.add_argument("--keep", help="directory for the log and the process outputs")
    args = parser.parse_args()
    out = Path(args.keep or tempfile.mkdtemp(prefix="ros_rate_"))
    out.mkdir(parents=True, exist_ok=True)
    result = run(args.cell, args.model, args.seconds, out)
    result["machine"] = machine_at_end(f", niceness {os.nice(0)}")
    print(write_report(RESULTS, "ros_rate", result, markdown))
    print(f"log and process outputs: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
