"""How NeHMO's per-step cost grows with the number of peers, on one thread.

    OMP_NUM_THREADS=1 ./run python bench/peer_scaling.py   # writes bench/results/peer_scaling.*

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
    ms = np.array(times) * 1e3
    constrained = sum(s not in ("naive", "unconstrained") for s in statuses)
    return {
        "peers": peers,
        "steps": int(ms.size),
        "median_ms": float(np.median(ms)),
        "p95_ms": float(np.percentile(ms, 95)),
        "max_ms": float(ms.max()),
        "constrained_share": constrained / len(statuses),
        "fail_safe_share": fail_safes / len(statuses),
        "median_per_peer_ms": float(np.median(ms)) / peers,
    }


def write(rows: list[dict[str, Any]], meta: dict[str, Any]) -> None:
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "peer_scaling.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    lines = [
        "# Planning step cost against the number of peers",
        "",
        f"`OMP_NUM_THREADS=1 ./run python bench/peer_scaling.py` ({meta['scenarios']} scenarios × "
        f"{meta['steps']} steps per cell, seed {meta['seed']}, {meta['cpu']}, torch "
        f"{meta['torch']}). The centre UR5 of a ring of k peers at 0.75–1.2 m, all arms running "
        "`nehmo` in closed loop; the centre arm's `plan()` wall time per step.",
        "",
        "| peers | steps | median ms | p95 ms | max ms | constrained steps | fail-safe "
        "| median per peer ms |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['peers']} | {r['steps']} | {r['median_ms']:.3f} | {r['p95_ms']:.3f} | "
            f"{r['max_ms']:.2f} | {100 * r['constrained_share']:.0f} % | "
            f"{100 * r['fail_safe_share']:.1f} % | {r['median_per_peer_ms']:.3f} |"
        )
    first, last = rows[0], rows[-1]
    growth = (last["median_ms"] - first["median_ms"]) / (last["peers"] - first["peers"])
    lines += [
        "",
        f"From {first['peers']} to {last['peers']} peers the median grows by about "
        f"{growth:.3f} ms per added peer.",
        "",
    ]
    (RESULTS / "peer_scaling.md").write_text("\n".join(lines))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=5)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--peers", default=",".join(map(str, PEERS)))
    args = parser.parse_args()
    torch.set_num_threads(1)
    rows = []
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
