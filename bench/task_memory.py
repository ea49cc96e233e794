"""A pool worker's memory over a run of generated tasks, with and without the collection after
each task.

    python bench/task_memory.py TASK_DIR [--per-count 3] [--name task_memory]

Runs the ``nehmo`` row of each task the way an ``nehmo evaluate --tasks`` worker does (the
worker's own function, one torch thread), in one process, the first ``--per-count`` tasks of each
arm count in the directory in name order, and reads the process's resident memory (VmRSS) after
each task. It does so twice, each in a fresh process: as the worker runs today (the cyclic
garbage of each task collected after it) and with that collection turned off (garbage left to the
collector's own pace). Results: ``bench/results/<name>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from _report import machine_at_end, write_report

RESULTS = Path(__file__).parent / "results"


def _rss_mb() -> float:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def worker(files: list[str], out: str, collect: bool) -> None:
    """One process's run (``--worker``): a JSON line per task on stdout."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)
    from nehmo_core.eval import task_runner
    from nehmo_core.eval.ha_tasks import load_task

    if not collect:
        task_runner.gc.collect = lambda *a, **k: 0
    config = task_runner.TaskConfig(out_dir=Path(out))
    print(json.dumps({"task": "start", "rss_mb": round(_rss_mb(), 1)}), flush=True)
    for f in files:
        task = load_task(Path(f))
        start = time.perf_counter()
        result, _ = task_runner._run(config, "nehmo", task)
        row = {"task": task.task_id, "arms": task.arm_count, "outcome": result.outcome}
        row |= {"seconds": round(time.perf_counter() - start, 1), "rss_mb": round(_rss_mb(), 1)}
        print(json.dumps(row), flush=True)


def _files(directory: Path, per_count: int) -> list[str]:
    by_count: dict[int, list[Path]] = {}
    for p in sorted(directory.glob("*.json")):
        m = re.match(r"gen_(\d+)arm_", p.name)
        if m:
            by_count.setdefault(int(m.group(1)), []).append(p)
    return [str(p) for n in sorted(by_count) for p in by_count[n][:per_count]]


def markdown(result: dict[str, Any]) -> str:
    modes = result["modes"]
    lines = [
        "# A task worker's memory over generated tasks",
        "",
        f"{result['machine']}. `{result['command']}`: the `nehmo` row of each task in one "
        "process, as an `nehmo evaluate --tasks` worker runs it; resident memory (VmRSS) after "
        "each task, each mode in a fresh process, one after the other.",
        "",
        "| task | arms | " + " | ".join(f"{m} [MB]" for m in modes) + " |",
        "|---|---|" + "---|" * len(modes),
    ]
    rows = list(zip(*(modes[m] for m in modes), strict=True))
    for per_mode in rows:
        first = per_mode[0]
        cells = " | ".join(f"{r['rss_mb']:.0f}" for r in per_mode)
        lines.append(f"| {first['task']} | {first.get('arms', '')} | {cells} |")
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("tasks", type=Path, help="a directory of generated task files")
    parser.add_argument("--per-count", type=int, default=3, help="tasks per arm count")
    parser.add_argument("--name", default="task_memory", help="report name")
    parser.add_argument("--worker", choices=["collect", "no-collect"], help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args()
    files = _files(args.tasks, args.per_count)
    if not files:
        parser.error(f"{args.tasks}: no generated task files (gen_<n>arm_*.json)")
    if args.worker:
        worker(files, args.out, args.worker == "collect")
        return 0
    modes: dict[str, list[dict[str, Any]]] = {}
    labels = {"collect": "collected after each task", "no-collect": "collector's own pace"}
    for mode in ("collect", "no-collect"):
        with tempfile.TemporaryDirectory() as tmp:
            argv = [sys.executable, __file__, str(args.tasks), "--per-count", str(args.per_count)]
            argv += ["--worker", mode, "--out", tmp]
            done = subprocess.run(argv, capture_output=True, text=True, check=True)
        modes[labels[mode]] = [json.loads(ln) for ln in done.stdout.splitlines() if ln[:1] == "{"]
        print(f"{labels[mode]}: {modes[labels[mode]][-1]['rss_mb']} MB at the end", flush=True)
    result = {
        "command": f"python bench/task_memory.py TASKS --per-count {args.per_count}",
        "tasks": [Path(f).stem for f in files],
        "modes": modes,
        "machine": machine_at_end(),
    }
    print(write_report(RESULTS, args.name, result, markdown))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
