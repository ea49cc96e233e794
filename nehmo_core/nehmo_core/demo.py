"""A short simulated dual-UR5 run through ``nehmo_core`` (``./run demo``).

Both arms drive straight toward their goals (the naive planner, clamped to 0.5 rad/s) at 25 Hz
while the exact PyBullet check watches every pair; the learned distance is printed beside the
exact one. This shows the robot models, the geometry and the learned distance at work; the
safety-aware planner replaces the naive one as it lands.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from nehmo_core.geometry.distance_model import load_distance_model
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import goal_error, sample_scenario

U_MAX = 0.5  # [rad/s]
RATE = 25.0  # [Hz]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--seed", type=int, default=3, help="scenario seed")
    parser.add_argument("--time-limit", type=float, default=20.0, help="[s] of simulated time")


def run(args: argparse.Namespace) -> int:
    cell = load_cell("dual_ur5")
    model = load_distance_model("ur5_ur5")
    rng = np.random.default_rng(args.seed)
    t0 = time.perf_counter()
    with CellWorld(cell) as world:
        sc = sample_scenario(cell, rng, world)
        q = {k: v.copy() for k, v in sc.start.items()}
        dt = 1.0 / RATE
        steps, outcome, min_exact, worst_model_err = 0, "time limit", np.inf, 0.0
        while steps * dt < args.time_limit:
            for arm in cell.arms:
                e = goal_error(q[arm.arm_id], sc.goal[arm.arm_id], arm.robot)
                q[arm.arm_id] = q[arm.arm_id] - np.clip(e / dt, -U_MAX, U_MAX) * dt
            steps += 1
            world.set_configuration(q)
            exact = world.distance("ur5_0", "ur5_1")
            learned = float(model.distance(np.concatenate([q["ur5_0"], q["ur5_1"]])))
            min_exact = min(min_exact, exact)
            worst_model_err = max(worst_model_err, abs(min(exact, 1.0) - learned))
            if world.in_collision():
                outcome = "collision"
                break
            errs = [np.linalg.norm(goal_error(q[a], sc.goal[a], cell.arm(a).robot)) for a in q]
            if max(errs) < 0.1:
                outcome = "success"
                break
    print(f"dual_ur5 naive run, scenario seed {args.seed}: {outcome} after {steps * dt:.2f} s")
    print(f"  minimum exact arm-arm distance: {min_exact:.3f} m")
    print(f"  worst |learned - exact| distance along the run: {worst_model_err:.3f} m")
    print(f"  wall time: {time.perf_counter() - t0:.2f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="nehmo demo", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
