"""How NeHMO's per-step cost grows with the number of peers, on one thread.

    OMP_NUM_THREADS=1 ./run python bench/peer_scaling.py   # writes bench/results/peer_scaling.*
    OMP_NUM_THREADS=1 ./run python bench/peer_scaling.py --tasks DIR --out NAME

Cells: one UR5 at the origin and k = 1, 2, 4, 5, 7 UR5 peers on a ring around it (k evenly
spread angles, base distances cycling through 0.75, 0.9, 1.05 and 1.2 m, each peer turned to face
the centre), so every peer of the centre arm is in reach and served by the conditioned
``ur5_ur5_any`` model, the model of arbitrary layouts. Per cell, ``--scenarios`` scenarios are
drawn by the paper's sampler (start and goal collision-free) with ``--seed``; every arm runs
``nehmo`` (default settings) for ``--steps`` steps of 0.1 s in closed loop, and the centre arm's
``plan()`` wall time is recorded per step. Reported per k: median, p95 and max, the share of
steps that needed the SQP (a constraint active), the fail-safe share, and the median per peer.
``plan()`` is called without announced speed bounds (every peer counts as silent), and the
silent-path watch is off, as in ``bench/planning_speed.py``. The outer arms' own far peers
across the ring may be beyond every shipped model's range; they are then left unconstrained
(``allow_unmodelled``): only the centre arm is timed, and all its peers are modelled.

With ``--tasks DIR`` (task files of ``nehmo tasks generate`` or Ha et al.'s): crowds as the
evaluation runs them. Every arm of each task runs ``nehmo`` with the default settings (the
silent-path watch on) at 25 Hz for ``--steps`` steps, integrating its commands (no physics);
each ``plan()`` gets the speed bounds its peers announced on the step before, as in ``nehmo
evaluate``. Every arm's ``plan()`` wall time is recorded and grouped by how many peers it
constrains (the modelled peers in reach), written to ``bench/results/NAME.{json,md}``.
"""

from __future__ import annotations

import argparse
import gc
import json
import math
import os
import platform
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import torch
from _report import cpu_model

from nehmo_core.eval.ha_tasks import load_tasks
from nehmo_core.eval.planners import build_planners
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.sim.scenarios import Scenario, sample_scenario

RESULTS = Path(__file__).resolve().parent / "results"
PEERS = (1, 2, 4, 5, 7)
RADII = (0.75, 0.9, 1.05, 1.2)
SETTINGS = PlannerSettings().override({"silent_watch.lookahead": 0.0})


def ring_cell(peers: int) -> Cell:
    """The centre arm ``ur5_0`` and ``peers`` arms around it, facing it."""
    ur5 = load_robot("ur5")
    arms = [ArmSpec("ur5_0", ur5, Pose())]
    for i in range(peers):
        angle = 2 * math.pi * i / peers + 0.3
        r = RADII[i % len(RADII)]
        xyz = (r * math.cos(angle), r * math.sin(angle), 0.0)
        arms.append(ArmSpec(f"ur5_{i + 1}", ur5, Pose(xyz, (0.0, 0.0, angle + math.pi))))
    return Cell(f"ring_{peers}", tuple(arms))


def scenarios(cell: Cell, count: int, seed: int) -> list[Scenario]:
    with CellWorld(cell) as world:
        return [
            sample_scenario(cell, np.random.default_rng([seed, k]), world, start_tries=2000)
            for k in range(count)
        ]


def run_cell(peers: int, count: int, steps: int, seed: int) -> dict[str, Any]:
    cell = ring_cell(peers)
    registry = ModelRegistry()
    kinds = dict.fromkeys(cell.arm_ids, "nehmo")
    times: list[float] = []
    statuses: list[str] = []
    fail_safes = 0
    for scenario in scenarios(cell, count, seed):
        planners = build_planners(
            cell, kinds, scenario, 0.1, registry, SETTINGS, allow_unmodelled=True
        )
        gc.collect()
        gc.freeze()
        q = {a: np.array(v, dtype=float) for a, v in scenario.start.items()}
        for _ in range(steps):
            commands = {}
            for a, planner in planners.items():
                if a == "ur5_0":
                    start = time.perf_counter()
                    result = planner.plan(q[a], q, scenario.goal[a])
                    times.append(time.perf_counter() - start)
                    statuses.append(result.telemetry.status)
                    fail_safes += bool(result.telemetry.fail_safe)
                else:
                    result = planner.plan(q[a], q, scenario.goal[a])
                commands[a] = result.velocity
            q = {a: q[a] + 0.1 * commands[a] for a in q}
        gc.unfreeze()
    return _row(peers, np.array(times) * 1e3, statuses, fail_safes)


def _row(peers: int, ms: np.ndarray, statuses: list[str], fail_safes: int) -> dict[str, Any]:
    constrained = sum(s not in ("naive", "unconstrained") for s in statuses)
    return {
        "peers": peers,
        "steps": int(ms.size),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "max_ms": float(ms.max()),
        "constrained_share": constrained / len(statuses),
        "fail_safe_share": fail_safes / len(statuses),
        "median_per_peer_ms": float(np.median(ms)) / max(peers, 1),
    }


def run_tasks(directory: Path, steps: int) -> tuple[list[dict[str, Any]], list[str]]:
    """Every arm's ``plan()`` time over the tasks of ``directory``, by constrained peers."""
    registry = ModelRegistry()
    by_peers: dict[int, tuple[list[float], list[str], list[bool]]] = {}
    names = []
    for task in load_tasks(directory):
        cell, scenario = task.cell, task.scenario
        names.append(task.task_id)
        planners = build_planners(
            cell, dict.fromkeys(cell.arm_ids, "nehmo"), scenario, 0.04, registry
        )
        gc.collect()
        gc.freeze()
        q = {a: np.array(v, dtype=float) for a, v in scenario.start.items()}
        bounds = dict.fromkeys(cell.arm_ids, 1.0)
        for _ in range(steps):
            commands, announced = {}, {}
            for a, planner in planners.items():
                peers = {b: q[b] for b in q if b != a}
                start = time.perf_counter()
                result = planner.plan(q[a], peers, scenario.goal[a], {b: bounds[b] for b in peers})
                elapsed = time.perf_counter() - start
                t = result.telemetry
                times, statuses, fails = by_peers.setdefault(len(t.peers_constrained), ([], [], []))
                times.append(elapsed)
                statuses.append(t.status)
                fails.append(t.fail_safe)
                commands[a] = result.velocity
                announced[a] = t.speed_bound
            bounds = announced
            q = {a: q[a] + 0.04 * commands[a] for a in q}
        gc.unfreeze()
    rows = [_row(k, np.array(v[0]) * 1e3, v[1], sum(v[2])) for k, v in sorted(by_peers.items())]
    return rows, names


def write(rows: list[dict[str, Any]], meta: dict[str, Any], name: str = "peer_scaling") -> None:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    if "tasks" in meta:
        what = (
            f"`OMP_NUM_THREADS=1 ./run python bench/peer_scaling.py --tasks DIR --out {name}` "
            f"({len(meta['tasks'])} tasks of {meta['tasks_source']} × {meta['steps']} steps at "
            f"25 Hz, {meta['cpu']}, torch {meta['torch']}). Every arm runs `nehmo` (default "
            "settings) in closed loop without physics; every arm's `plan()` wall time per step, "
            "by the number of peers it constrains."
        )
    else:
        what = (
            f"`OMP_NUM_THREADS=1 ./run python bench/peer_scaling.py` ({meta['scenarios']} "
            f"scenarios × {meta['steps']} steps per cell, seed {meta['seed']}, {meta['cpu']}, "
            f"torch {meta['torch']}). The centre UR5 of a ring of k peers at 0.75–1.2 m, all arms "
            "running `nehmo` in closed loop; the centre arm's `plan()` wall time per step."
        )
    lines = [
        "# Planning step cost against the number of peers",
        "",
        what,
        "",
        "| peers | steps | median ms | p95 ms | max ms | constrained steps | fail-safe "
        "| median per peer ms |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['peers']} | {r['steps']} | {r['median_ms']:.3f} | {r['p95_ms']:.3f} | "
            f"{r['max_ms']:.2f} | {100 * r['constrained_share']:.0f} % | "
            f"{100 * r['fail_safe_share']:.1f} % | "
            + (f"{r['median_per_peer_ms']:.3f} |" if r["peers"] > 0 else "– |")
        )
    lines.append("")
    timed = [r for r in rows if r["peers"] > 0]
    if len(timed) > 1:
        first, last = timed[0], timed[-1]
        growth = (last["median_ms"] - first["median_ms"]) / (last["peers"] - first["peers"])
        lines += [
            f"From {first['peers']} to {last['peers']} peers the median grows by about "
            f"{growth:.3f} ms per added peer.",
            "",
        ]
    (RESULTS / f"{name}.md").write_text("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=5)
    parser.add_argument("--steps", type=int, help="steps per scenario (150) or task (500)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--peers", default=",".join(map(str, PEERS)))
    parser.add_argument("--tasks", type=Path, help="a directory of task files: crowds instead")
    parser.add_argument("--out", default="peer_scaling", help="results name (bench/results/)")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.tasks is not None:
        steps = args.steps or 500  # 20 s at 25 Hz, an evaluation's episode
        rows, names = run_tasks(args.tasks, steps)
        meta = {
            "tasks": names,
            "tasks_source": args.tasks.name,
            "steps": steps,
            "cpu": cpu_model(),
            "python": platform.python_version(),
            "torch": torch.__version__,
        }
        write(rows, meta, args.out)
        return
    rows = []
    args.steps = args.steps or 150
    for k in (int(v) for v in args.peers.split(",")):
        rows.append(run_cell(k, args.scenarios, args.steps, args.seed))
        print(json.dumps(rows[-1]), flush=True)
    meta = {
        "scenarios": args.scenarios,
        "steps": args.steps,
        "seed": args.seed,
        "cpu": cpu_model(),
        "python": platform.python_version(),
        "torch": torch.__version__,
    }
    write(rows, meta)


if __name__ == "__main__":
    main()
