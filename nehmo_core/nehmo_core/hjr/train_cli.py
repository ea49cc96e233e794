"""The ``nehmo train`` command: options, presets by name, and running :func:`.train.train`."""

from __future__ import annotations

import argparse
import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from nehmo_core.errors import (
    InvalidValueError,
    NehmoError,
    as_options,
)
from nehmo_core.hjr.model_files import CHECKPOINT
from nehmo_core.hjr.systems import make_system, system_names
from nehmo_core.hjr.train import DEVICES, train
from nehmo_core.hjr.train_settings import DIRICHLET_LOSSES, LR_SCHEDULES, PRESETS, TrainSettings

__all__ = ["add_train_arguments", "main", "parse_count", "run_train", "settings_from_args"]


_SUFFIXES = {"": 1, "k": 1_000, "m": 1_000_000, "g": 1_000_000_000}


def parse_count(text: str, parameter: str = "samples", minimum: int = 1) -> int:
    """Parse ``"40M"``, ``"500k"``, ``"2e6"`` or ``"20000"`` into a whole count of at least
    ``minimum`` (1: positive; 0: zero allowed)."""
    match = re.fullmatch(r"\s*([0-9]*\.?[0-9]+(?:[eE][+-]?[0-9]+)?)\s*([kKmMgG]?)\s*", text)
    if match is None:
        raise InvalidValueError(parameter, "must be a count like 40M, 500k or 2e6", text)
    value = float(match.group(1)) * _SUFFIXES[match.group(2).lower()]
    if value < minimum or value != int(value):
        rule = "a positive whole count" if minimum == 1 else f"a whole count >= {minimum}"
        raise InvalidValueError(parameter, f"must be {rule}", text)
    return int(value)


def add_train_arguments(parser: argparse.ArgumentParser) -> None:
    """Add the ``nehmo train`` options to ``parser``."""
    parser.add_argument("--system", required=True, help=f"one of {system_names()}")
    parser.add_argument("--variant", default="bc+sym", help="deepreach | bc | bc+sym | exact")
    parser.add_argument("--samples", default="40M", help="budget of states drawn, e.g. 40M")
    parser.add_argument("--out", required=True, help="run directory")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--resume", action="store_true", help="continue from out/checkpoint")
    parser.add_argument("--preset", default="cpu", help=f"settings preset: {sorted(PRESETS)}")
    parser.add_argument("--width", type=int, help="SIREN width")
    parser.add_argument("--hidden-layers", type=int, help="SIREN width×width layers")
    parser.add_argument("--batch-size", type=int, help="states per step")
    parser.add_argument("--lr", type=float, help="initial Adam learning rate")
    parser.add_argument("--lr-schedule", help=f"one of {list(LR_SCHEDULES)}")
    parser.add_argument("--lr-final", type=float, help="last rate as a share of --lr")
    parser.add_argument("--dirichlet-loss", help=f"one of {list(DIRICHLET_LOSSES)}")
    parser.add_argument(
        "--pde-loss", help=f"one of {list(DIRICHLET_LOSSES)}: |r| or r² of the PDE residual"
    )
    parser.add_argument("--omega0", type=float, help="SIREN first-layer frequency")
    parser.add_argument(
        "--gradient-weight",
        type=float,
        help="weight of the residual network's slope beyond the boundary's (bc variants)",
    )
    parser.add_argument("--checkpoint-every", default=None, help="samples between checkpoints")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    parser.add_argument(
        "--device",
        default="cpu",
        choices=DEVICES,
        help="where to train: cpu, cuda (an error if absent) or auto (cuda when present)",
    )
    parser.add_argument("--no-progress", action="store_true", help="hide the progress bar")


_OPTIONS = {
    "variant": "--variant",
    "samples": "--samples",
    "seed": "--seed",
    "preset": "--preset",
    "width": "--width",
    "hidden_layers": "--hidden-layers",
    "batch_size": "--batch-size",
    "learning_rate": "--lr",
    "lr_schedule": "--lr-schedule",
    "lr_final_fraction": "--lr-final",
    "dirichlet_loss": "--dirichlet-loss",
    "pde_loss": "--pde-loss",
    "gradient_weight": "--gradient-weight",
    "omega0": "--omega0",
    "checkpoint_every": "--checkpoint-every",
}
"""``TrainSettings`` fields set from the command line, and their options (for error messages)."""


def settings_from_args(args: argparse.Namespace) -> TrainSettings:
    """Build :class:`TrainSettings` from parsed ``nehmo train`` arguments; a bad value is
    reported under the option that set it."""
    with as_options(_OPTIONS):
        return _settings_from_args(args)


def _settings_from_args(args: argparse.Namespace) -> TrainSettings:
    base = TrainSettings.preset(args.preset)
    net = base.network
    if args.width is not None:
        net = replace(net, width=args.width)
    if args.hidden_layers is not None:
        net = replace(net, hidden_layers=args.hidden_layers)
    if args.omega0 is not None:
        net = replace(net, omega0=args.omega0)
    overrides: dict[str, Any] = {
        "variant": args.variant,
        "network": net,
        "samples": parse_count(args.samples),
        "seed": args.seed,
    }
    if args.batch_size is not None:
        overrides["batch_size"] = args.batch_size
    if args.lr is not None:
        overrides["learning_rate"] = args.lr
    if args.lr_schedule is not None:
        overrides["lr_schedule"] = args.lr_schedule
    if args.lr_final is not None:
        overrides["lr_final_fraction"] = args.lr_final
    if args.dirichlet_loss is not None:
        overrides["dirichlet_loss"] = args.dirichlet_loss
    if args.pde_loss is not None:
        overrides["pde_loss"] = args.pde_loss
    if args.gradient_weight is not None:
        overrides["gradient_weight"] = args.gradient_weight
    if args.checkpoint_every is not None:
        overrides["checkpoint_every"] = parse_count(args.checkpoint_every, "checkpoint_every")
    return replace(base, **overrides)


def run_train(args: argparse.Namespace) -> int:
    """Run ``nehmo train`` from parsed arguments; returns the process exit code."""
    system = make_system(args.system)
    settings = settings_from_args(args)
    if args.resume and not (Path(args.out) / f"{CHECKPOINT}.json").exists():
        raise InvalidValueError("out", "holds no checkpoint to --resume from", str(args.out))
    if args.threads is not None:
        if args.threads < 1:
            raise InvalidValueError("threads", "must be >= 1", args.threads)
        torch.set_num_threads(args.threads)
    result = train(
        system,
        settings,
        args.out,
        resume=args.resume,
        progress=not args.no_progress,
        device=args.device,
    )
    print(
        f"{system.name} {settings.variant}: {result.steps} steps, {result.samples} samples, "
        f"{result.wall_seconds:.1f} s ({result.samples_per_second:.0f} samples/s), "
        f"final loss {result.final_loss:.4g}; model in {result.out_dir}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m nehmo_core.hjr.train_cli --system air3d --out runs/a``."""
    parser = argparse.ArgumentParser(prog="nehmo train", description=__doc__.splitlines()[0])
    add_train_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run_train(args)
    except NehmoError as exc:
        parser.exit(2, f"nehmo train: error: {exc}\n")


if __name__ == "__main__":
    raise SystemExit(main())
