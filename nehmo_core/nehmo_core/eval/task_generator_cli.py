"""``nehmo tasks generate``: task files in Ha et al.'s format (:mod:`.task_generator`).

    nehmo tasks generate --arms 3 --count 20 --seed 0 --out DIR [--robot NAME] \\
        [--clearance 0.02] [--min-goal-distance 0.5]

writes ``DIR/gen_3arm_s0_000.json`` … ``gen_3arm_s0_019.json``, which
``nehmo evaluate --tasks DIR`` runs. Bad input (arms or count below 1, a negative seed, an
unknown robot, an output that is not a writable directory) stops before any work with one line
naming the option, exit code 2.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from nehmo_core.errors import InvalidValueError, as_options
from nehmo_core.eval.task_generator import CONFIGS, TaskSpec, task_rng, write_tasks
from nehmo_core.robots.descriptions import robot_names
from nehmo_core.robots.registry import HA_BENCHMARK_ROBOT

__all__ = ["add_arguments", "run"]

_OPTIONS = {
    "arms": "--arms",
    "robot": "--robot",
    "clearance": "--clearance",
    "min_goal_distance": "--min-goal-distance",
    "configs": "--configs",
    "count": "--count",
    "seed": "--seed",
    "out": "--out",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    g = sub.add_parser(
        "generate",
        help="random bases (Ha et al.'s protocol) with collision-free starts and goals",
        description="Write task files in Ha et al.'s format for `nehmo evaluate --tasks`.",
    )
    g.add_argument("--arms", type=int, required=True, help="arms per task (>= 1)")
    g.add_argument("--count", type=int, default=20, help="tasks to write (default 20)")
    g.add_argument("--seed", type=int, default=0, help="task k draws from (seed, arms, k)")
    g.add_argument("--out", type=Path, required=True, help="output directory")
    g.add_argument(
        "--robot",
        default=HA_BENCHMARK_ROBOT,
        help=f"a registered robot, one of {', '.join(robot_names())} (default: the benchmark's, "
        f"{HA_BENCHMARK_ROBOT}; only its tasks run under `nehmo evaluate --tasks`)",
    )
    g.add_argument(
        "--clearance",
        type=float,
        default=TaskSpec.clearance,
        help="[m] every pair of arms at least this far apart at start and at goal (default "
        f"{TaskSpec.clearance})",
    )
    g.add_argument(
        "--min-goal-distance",
        type=float,
        default=TaskSpec.min_goal_distance,
        help="[rad] each arm's goal at least this far from its start, L2 of the wrapped joint "
        f"differences (default {TaskSpec.min_goal_distance})",
    )
    g.add_argument(
        "--configs",
        default=TaskSpec.configs,
        help=f"how starts and goals are drawn, one of {', '.join(CONFIGS)}: uniform in the "
        "robot's sampling box, or by "
        "inverse kinematics toward a point in the workspace hemisphere as Ha et al.'s code draws "
        f"them (default {TaskSpec.configs})",
    )
    g.add_argument("--no-progress", action="store_true", help="no progress bar")


def _prepare_out(out: Path) -> None:
    """Create ``out``, or say in one line why it cannot hold the task files."""
    if out.exists() and not out.is_dir():
        raise InvalidValueError("out", "must be a directory (it is a file)", str(out))
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        rule = f"must be a writable directory ({exc.strerror or exc})"
        raise InvalidValueError("out", rule, str(out)) from None
    if not os.access(out, os.W_OK | os.X_OK):
        raise InvalidValueError("out", "must be a writable directory", str(out))


def run(args: argparse.Namespace) -> int:
    with as_options(_OPTIONS):
        spec = TaskSpec(
            args.arms, args.robot, args.clearance, args.min_goal_distance, configs=args.configs
        )
        if args.count < 1:
            raise InvalidValueError("count", "must be >= 1", args.count)
        task_rng(args.seed, spec.arms, 0)  # checks the seed
        _prepare_out(args.out)
        if spec.robot != HA_BENCHMARK_ROBOT:
            print(
                f"note: `nehmo evaluate --tasks` reads task files as {HA_BENCHMARK_ROBOT} arms; "
                f"these {spec.robot} tasks name their robot under 'robot' for other tools",
                file=sys.stderr,
            )
        paths = write_tasks(spec, args.seed, args.count, args.out, not args.no_progress)
    print(f"wrote {len(paths)} task files to {args.out}", file=sys.stderr)
    return 0
