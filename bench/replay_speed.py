"""Planning time per ``plan()`` call on recorded closed-loop inputs, for comparing two versions
of the planner side by side (a refactor must not slow it down).

    python bench/replay_speed.py [--passes 5]            # this checkout: one line of JSON
    python bench/replay_speed.py --compare OLD_TREE NEW_TREE --rounds 5 --out bench/results/x.md

Run from the repository root. Each measurement replays the inputs of
``tests/data/reference_ticks/*.npz`` (closed loops with
the shipped models: five UR5 with every stage acting, a reckless Kinova, the paper's Opt) through
freshly built planners, tick by tick, solve deadlines lifted, ``--passes`` times, and reports the
median and p95 of every call's wall time per case. ``--compare`` runs this script on two source
trees (``PYTHONPATH`` set to each tree's ``nehmo_core``) in alternating subprocesses, ``--rounds``
times each, and writes the medians and their ratio (new / old); the commands of both trees must
agree (the replay also checks them against the reference).
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

DATA = Path("tests") / "data" / "reference_ticks"  # of the tree it runs in (the working dir)
CASES = ("five_ur5", "five_ur5_guard", "reckless_kinova", "dual_ur5_paper")


def _measure(passes: int) -> dict[str, dict[str, float]]:
    from nehmo_core.eval.planners import build_planners
    from nehmo_core.eval.setups import get_setup, parse_row
    from nehmo_core.planning.models.registry import ModelRegistry
    from nehmo_core.sim.scenarios import generate_scenario_set

    def preset(name: str) -> Any:
        try:  # settings in groups
            from nehmo_core.planning.settings import PlannerSettings

            return PlannerSettings.preset(name, {"opt.deadline": 3600.0})
        except ImportError:  # a tree from before the groups: flat settings
            old = importlib.import_module("nehmo_core.planning.opt.settings")
            return old.PlannerSettings.preset(name, deadline=3600.0)

    out = {}
    for name in CASES:
        with np.load(DATA / f"{name}.npz") as data:
            meta = json.loads(str(data["meta"]))
            peers_all, goals, commands = data["peers"], data["goals"], data["commands"]
        setup = get_setup(meta["setup"])
        cell = setup.load_cell()
        scenario = generate_scenario_set(cell, meta["seed"], 1).scenarios[0]
        settings = preset(meta["preset"])
        times: list[float] = []
        worst = 0.0
        for _ in range(passes):
            planners = build_planners(
                cell, parse_row(meta["row"], cell), scenario, 0.04, ModelRegistry(()), settings
            )
            for planner in planners.values():
                planner.reset()
            for k, arm in enumerate(meta["call_arms"]):
                peers = dict(zip(meta["peers"], peers_all[k], strict=True))
                bounds = meta["bounds"][k]
                start = time.perf_counter()
                args = (peers[arm], peers, goals[k])
                plan = planners[arm].plan
                result = plan(*args) if bounds is None else plan(*args, bounds)
                times.append(time.perf_counter() - start)
                worst = max(worst, float(np.abs(result.velocity - commands[k]).max()))
        ms = np.array(times) * 1e3
        out[name] = {
            "median_ms": float(np.median(ms)),
            "p95_ms": float(np.percentile(ms, 95)),
            "calls": len(times),
            "max_command_gap": worst,
        }
    return out


def _run_tree(tree: Path, passes: int) -> dict[str, dict[str, float]]:
    env = dict(os.environ, OMP_NUM_THREADS="1")
    env["PYTHONPATH"] = os.pathsep.join([str(tree / "nehmo_core"), env.get("PYTHONPATH", "")])
    proc = subprocess.run(
        [sys.executable, str(Path(__file__).resolve()), "--passes", str(passes)],
        env=env,
        cwd=tree,
        capture_output=True,
        text=True,
        check=False,
    )
    if proc.returncode != 0:
        raise SystemExit(f"replay in {tree} failed:\n{proc.stderr[-3000:]}")
    result: dict[str, dict[str, float]] = json.loads(proc.stdout.strip().splitlines()[-1])
    return result


def _compare(old: Path, new: Path, rounds: int, passes: int, out: Path | None) -> None:
    runs: dict[str, list[dict[str, dict[str, float]]]] = {"old": [], "new": []}
    for r in range(rounds):  # alternate, so that drifts of the machine hit both alike
        for label, tree in (
            (("old", old), ("new", new)) if r % 2 == 0 else (("new", new), ("old", old))
        ):
            runs[label].append(_run_tree(tree, passes))
            print(f"round {r + 1}/{rounds}: {label} done", file=sys.stderr)
    lines = [
        "# Planning time per call, two versions side by side",
        "",
        f"Old: `{old}`; new: `{new}`. {rounds} alternating rounds of {passes} passes over the "
        "recorded closed-loop inputs of `tests/data/reference_ticks/` (shipped models, one "
        f"thread, deadlines lifted); load average at the end {os.getloadavg()[0]:.2f}.",
        "",
        "| case | calls per round | old median ms (rounds) | new median ms (rounds) | "
        "new / old (median of rounds) | new p95 / old p95 | largest command gap |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in CASES:
        o = [x[name]["median_ms"] for x in runs["old"]]
        n = [x[name]["median_ms"] for x in runs["new"]]
        op = statistics.median(x[name]["p95_ms"] for x in runs["old"])
        np95 = statistics.median(x[name]["p95_ms"] for x in runs["new"])
        gap = max(x[name]["max_command_gap"] for x in runs["old"] + runs["new"])
        lines.append(
            f"| {name} | {runs['new'][0][name]['calls']:.0f} "
            f"| {statistics.median(o):.3f} ({', '.join(f'{v:.3f}' for v in o)}) "
            f"| {statistics.median(n):.3f} ({', '.join(f'{v:.3f}' for v in n)}) "
            f"| {statistics.median(n) / statistics.median(o):.3f} | {np95 / op:.3f} | {gap:.1e} |"
        )
    text = "\n".join(lines) + "\n"
    print(text)
    if out is not None:
        out.write_text(text)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--passes", type=int, default=3)
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("OLD_TREE", "NEW_TREE"))
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    if args.compare:
        _compare(args.compare[0], args.compare[1], args.rounds, args.passes, args.out)
    else:
        print(json.dumps(_measure(args.passes)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
