"""One task through the node suite: did it succeed, and did every planner keep 25 Hz?

    python bench/ros_task.py TASK_FILE [--name ros_task] [--keep DIR]

Runs ``orchestrate run --task TASK_FILE`` (a task in Ha et al.'s format, e.g. from ``nehmo tasks
generate``): the recorder, one ``arm_planner`` per arm and the ``sim_bridge`` as separate rclpy
processes, simulated time at real-time factor 1. The episode is evaluated from its bag as
``orchestrate`` does; per arm, the command periods at the planner (the wall-clock publish
instants ``publish_wall_ns`` of its statuses) and at the recorder (receive times of its commands)
are reported as percentiles and as the share within 40 ± 5 ms (the first second left out), with
the planners' missed deadlines and fail-safes. Results: ``bench/results/<name>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

from _report import machine_at_end, write_report
from ros_rate import analyse, period_rows

from nehmo_core.eval.ha_tasks import load_task

RESULTS = Path(__file__).resolve().parent / "results"


def run(task: Path, out: Path) -> dict[str, Any]:
    argv = [sys.executable, "-m", "nehmo_ros.orchestrate", "run", "--task", str(task)]
    done = subprocess.run([*argv, "--out", str(out)], capture_output=True, text=True)
    summary = json.loads((out / "summary.json").read_text())
    episode = summary["episodes"][0]
    bag = Path(episode["log"])
    arms = list(load_task(task).cell.arm_ids)
    return {
        "task": task.name,
        "arms": len(arms),
        "exit_code": done.returncode,
        "outcome": episode["outcome"],
        "end_time": episode["end_time"],
        "process_exit_codes": episode["exit_codes"],
        "rmw": summary.get("rmw", ""),
        "per_arm": analyse(bag, arms, skip_s=1.0),
    }


def markdown(result: dict[str, Any]) -> str:
    lines = [
        f"# Task {result['task']} through the node suite ({result['arms']} arms)",
        "",
        f"{result['machine']}; rclpy on {result.get('rmw') or '?'}; outcome **{result['outcome']}**"
        f" at {result['end_time']} s (simulated, real-time factor 1); orchestrate exit code"
        f" {result['exit_code']}; process exit codes {result['process_exit_codes']}.",
        "",
        "| arm | where | periods | within 40±5 ms | p0.1 / p1 / p50 / p99 / p99.9 [ms] | max |"
        " misses | fail-safes |",
        "|---|---|---|---|---|---|---|---|",
    ]
    return "\n".join(lines + period_rows(result["per_arm"])) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("task", type=Path, help="a task file (Ha et al.'s format)")
    parser.add_argument("--name", default="ros_task", help="report name: results/<name>.md")
    parser.add_argument("--keep", help="directory for the bag and the process outputs")
    parser.add_argument("--results", default=str(RESULTS), help="where the report goes")
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.keep) if args.keep else Path(tmp)
        result = run(args.task, out)
    result["machine"] = machine_at_end()
    print(write_report(Path(args.results), args.name, result, markdown))
    return 0 if result["outcome"] == "success" else 1


if __name__ == "__main__":
    raise SystemExit(main())
