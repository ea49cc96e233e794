"""Stage ``value:<game>`` of ``nehmo pair build``: train, measure against the PDE, try again.

Each attempt is a ``nehmo train`` run in its own folder of the work folder, copied to the model
folder and measured there (``value-check``: below its boundary, and against its PDE,
:mod:`nehmo_core.hjr.diagnostics`). The first attempt takes the mean absolute PDE residual (as
every shipped model was trained). Where fewer than half the states must fall (``H(x, ∇l) < 0``)
that loss can hold the residual network at zero: until the network tells those states apart, the
cheapest slope in ``τ`` is the median of its targets, which is 0. A game whose first network
reads as no learned value is trained once more with the squared residual (``--pde-loss l2``),
whose pull toward 0 vanishes at 0; the pair keeps the first attempt that learned, else the one
closest to the PDE, and its card records every attempt.
"""

from __future__ import annotations

import json
import platform
import shlex
import shutil
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tqdm import tqdm

from nehmo_core.hjr.diagnostics import unlearned_warning
from nehmo_core.robots.loader import atomic_write

if TYPE_CHECKING:
    from nehmo_core.pairs.build import PairBuild

__all__ = ["PDE_LOSSES", "value_stage"]

PDE_LOSSES = ("l1", "l2")
"""The PDE losses of a value stage's attempts, in order; the next runs only when the last did
not learn."""


def _train(build: PairBuild, game: str, run: Path, pde_loss: str) -> str:
    """Train (or find trained, or resume) one attempt in ``run``; the command as typed."""
    args = [
        "train", "--system", game, "--variant", build.variant,
        "--preset", build.budget.value_preset,
        "--samples", build.budget.value_samples, "--seed", str(build.seed),
        "--threads", str(build.threads), "--device", build.device, "--out", str(run),
        "--gradient-weight", f"{build.budget.value_gradient_weight:g}",
    ]  # fmt: skip
    if pde_loss != PDE_LOSSES[0]:
        args += ["--pde-loss", pde_loss]
    if (run / "checkpoint.safetensors").exists() and not (run / "model.safetensors").exists():
        args.append("--resume")
    if (run / "model.safetensors").exists():  # trained before the stage was recorded
        return "nehmo " + shlex.join(args)
    return build.nehmo(f"value:{game}", args)


def _install(build: PairBuild, game: str, run: Path, command: str) -> dict[str, Any]:
    """Copy the attempt in ``run`` to the model folder with its card; its sidecar."""
    target = build.models / f"value_{game}_{build.slug}"
    meta = json.loads((run / "model.json").read_text())
    meta.setdefault("card", {}).update(
        {
            "what": f"neural HJR avoid value function of {game} (pose-conditioned)",
            "training": command,
            "boundary": f"l(x) = learned distance distance_{build.pair} (frozen)",
            "hardware": f"{build.threads} CPU threads ({platform.machine()})",
            "pair_card": f"{build.pair}.card.json",
            "cap_residual": True,
            "evaluation": "V = l + min(W - l, 0): an avoid value never exceeds its boundary",
        }
    )
    shutil.copyfile(run / "model.safetensors", target.with_suffix(".safetensors"))
    atomic_write(target.with_suffix(".json"), json.dumps(meta, indent=2, sort_keys=True) + "\n")
    return dict(meta)


def value_stage(build: PairBuild, game: str) -> tuple[list[str], dict[str, Any]]:
    """The stage's commands and figures (see the module docstring)."""
    attempts: list[dict[str, Any]] = []
    for pde_loss in PDE_LOSSES:
        # the first attempt's folder is the one builds before the retry used (they resume)
        suffix = "" if pde_loss == PDE_LOSSES[0] else f"_{pde_loss}"
        run = build.work / f"value_{game}{suffix}"
        command = _train(build, game, run, pde_loss)
        meta = _install(build, game, run, command)
        check = build.probe(
            f"value check of {game}",
            ["value-check", game, "--variant", build.variant, "--samples", "4000", "--seed", "3"],
        )
        attempts.append(
            {"pde_loss": pde_loss, "run": run, "command": command, "meta": meta, "check": check}
        )
        if check["learned"]:
            break
        if pde_loss != PDE_LOSSES[-1]:
            ratio = check["pde"]["residual_ratio"]
            tqdm.write(
                f"  value function {game} (--pde-loss {pde_loss}) learned little beyond its "
                f"boundary (residual {ratio:.2f} of V = l's): training it again with the next "
                "PDE loss",
                file=sys.stderr,
            )
    kept = next(
        (a for a in attempts if a["check"]["learned"]),
        min(attempts, key=lambda a: a["check"]["pde"]["residual_ratio"]),
    )
    if not kept["check"]["learned"]:  # the kept attempt's figures, and what was tried
        tried = [a["pde_loss"] for a in attempts]
        warning = unlearned_warning(game, kept["check"]["pde"], tried)
        tqdm.write(f"  warning: {warning}", file=sys.stderr)
    if kept is not attempts[-1]:  # the model folder holds the last attempt: put the kept one back
        _install(build, game, kept["run"], kept["command"])
    figures = {
        "samples": kept["meta"].get("samples"),
        "train_wall_time_s": kept["meta"].get("wall_seconds"),
        "pde_loss": kept["pde_loss"],
        "below_boundary": kept["check"],
        "attempts": [
            {
                "pde_loss": a["pde_loss"],
                "learned": a["check"]["learned"],
                "residual_ratio": a["check"]["pde"]["residual_ratio"],
                "train_wall_time_s": a["meta"].get("wall_seconds"),
            }
            for a in attempts
        ],
    }
    return [a["command"] for a in attempts], figures
