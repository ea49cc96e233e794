"""``nehmo pair``: build a robot pair's certified models in one command, or see a build's state."""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from nehmo_core.errors import InvalidValueError
from nehmo_core.pairs.budgets import BUDGETS
from nehmo_core.pairs.build import PairBuild, default_models_dir, pair_names
from nehmo_core.robots import registry

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="pair_command", required=True, metavar="ACTION")
    b = sub.add_parser(
        "build",
        help="labels, learned distance, value functions, certificates and cards of a robot pair",
        description=(
            "Build the pose-conditioned models of robots A and B (B may equal A). Resumable: "
            "run it again with the same --work and it goes on where it stopped."
        ),
    )
    b.add_argument("robot_a", help="registered robot (nehmo robot add makes one from a URDF)")
    b.add_argument("robot_b", help="registered robot (may be robot_a)")
    b.add_argument(
        "--models",
        type=Path,
        help="model folder the pair's files go to (default: first NEHMO_MODELS folder, else "
        "./nehmo_models); add it to NEHMO_MODELS to plan with the pair",
    )
    b.add_argument("--work", type=Path, help="work folder (default: runs/pairs/<pair>)")
    b.add_argument("--budget", default="standard", help=f"one of {sorted(BUDGETS)}")
    b.add_argument("--seed", type=int, default=0)
    b.add_argument("--threads", type=int, default=2, help="CPU threads / label workers")
    b.add_argument(
        "--device",
        default="auto",
        choices=("cpu", "cuda", "auto"),
        help="where value functions train (auto: a CUDA GPU when present, else the CPU)",
    )
    b.add_argument(
        "--cluster",
        default="local",
        help="where the distance labels and the certificates' and falsification's rollouts "
        "run: 'local', 'ray', 'ray://HOST:PORT' or 'ray:HOST:PORT' (docs/cluster.md); the "
        "figures are the same",
    )
    b.add_argument(
        "--base-range",
        nargs=2,
        type=float,
        metavar=("LOW", "HIGH"),
        help="[m] cover only these base distances (default: every distance at which the arms' "
        "collision geometry can touch); needs --tag",
    )
    b.add_argument(
        "--tag",
        default="any",
        help="the pair's name is A_B_TAG (default any: every distance); e.g. far with "
        "--base-range for the far part beside a shipped pair",
    )
    b.add_argument("--no-progress", action="store_true", help="no progress bars")
    s = sub.add_parser("status", help="what a build has done, stage by stage")
    s.add_argument("work", type=Path, help="the build's work folder")


def run(args: argparse.Namespace) -> int:
    if args.pair_command == "status":
        state_path = args.work / "state.json"
        if not state_path.exists():
            raise InvalidValueError("work", "holds no pair build (no state.json)", str(args.work))
        print(describe(json.loads(state_path.read_text())))
        return 0
    pair = pair_names(args.robot_a, args.robot_b, args.tag)[0]
    build = PairBuild(
        args.robot_a,
        args.robot_b,
        models=args.models or default_models_dir(),
        work=args.work or Path("runs") / "pairs" / pair,
        budget=args.budget,
        seed=args.seed,
        threads=args.threads,
        progress=not args.no_progress,
        device=args.device,
        cluster=args.cluster,
        base_range=None if args.base_range is None else tuple(args.base_range),
        tag=args.tag,
    )
    card = build.run()
    print(f"{pair}: models and card in {build.models} ({card.name})")
    for warning in json.loads(card.read_text()).get("warnings", []):
        print(f"warning: {warning}")
    if str(build.models) not in registry.model_dirs_env():
        print(f"plan with them: export {registry.MODELS_ENV}={build.models}")
    return 0


def describe(state: dict[str, Any]) -> str:
    """A few lines on a build's progress (``nehmo pair status``)."""
    lines = [
        f"pair {state['pair']} ({state['budget']}, seed {state['seed']}): "
        f"models in {state['models']}"
    ]
    for name, rec in state["stages"].items():
        lines.append(f"  {name}: {rec['wall_time_s']:.0f} s")
    return "\n".join(lines)
