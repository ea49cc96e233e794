"""The ``nehmo`` command: one entry point with a sub-command per job.

Errors derived from :class:`~nehmo_core.errors.NehmoError` are printed as one line
(``nehmo: error: ...``) with exit code 2, never as a traceback.
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable, Sequence

from nehmo_core.errors import NehmoError

# sub-command: (module, add-arguments function, run function, help).
_COMMANDS: dict[str, tuple[str, str, str, str]] = {
    "distance": (
        "nehmo_core.geometry.distance_cli",
        "add_arguments",
        "run",
        "learned arm-arm distance: generate data, train, evaluate",
    ),
    "evaluate": (
        "nehmo_core.eval.cli",
        "add_arguments",
        "run",
        "evaluate planners on the paper's setups (metrics from the logs)",
    ),
    "pair": (
        "nehmo_core.pairs.cli",
        "add_arguments",
        "run",
        "build a robot pair's learned distance, value functions and certificates in one command",
    ),
    "robot": (
        "nehmo_core.robots.robot_cli",
        "add_arguments",
        "run",
        "check a URDF as an arm NeHMO can plan for",
    ),
    "tasks": (
        "nehmo_core.eval.task_generator_cli",
        "add_arguments",
        "run",
        "generate task files in Ha et al.'s format (random bases, collision-free starts, goals)",
    ),
    "train": (
        "nehmo_core.hjr.train_cli",
        "add_train_arguments",
        "run_train",
        "train a neural HJR value function (deepreach | bc | bc+sym)",
    ),
    "verify": (
        "nehmo_core.verify.cli",
        "add_arguments",
        "run",
        "certify a value function's safe level set (scenario bound over HJI rollouts)",
    ),
    "validate": (
        "nehmo_core.hjr.ground_truth",
        "add_validate_arguments",
        "run_validate",
        "compare a value function with the grid ground truth",
    ),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="nehmo", description="NeHMO: safety-aware decentralized multi-arm motion planning"
    )
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, (module, add_fn, run_fn, help_text) in _COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        mod = importlib.import_module(module)
        getattr(mod, add_fn)(p)
        runner: Callable[[argparse.Namespace], int] = getattr(mod, run_fn)
        p.set_defaults(_run=runner)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args._run(args))
    except NehmoError as exc:
        print(f"nehmo {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nehmo {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
