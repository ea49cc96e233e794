"""DeepReach-style training of a value network, with checkpoints, resume and a CLI.

Schedule (a budget of ``samples`` states, pretraining included, in steps of ``batch_size``):

1. ``pretrain_fraction`` of the steps at ``τ = 0`` only, Dirichlet loss only.
2. The rest with a linear time curriculum ``τ ~ U[0, T·min(1, k/K)]``, ``K`` being
   ``curriculum_fraction`` of the remaining steps; the last ``boundary_fraction`` of every batch
   is forced to ``τ = 0``. Loss ``dirichlet_weight·mean|W − l̂|`` over the ``τ = 0`` points plus
   ``pde_weight·mean|∂W/∂τ − min(0, H(x, ∇ₓW))|`` over all points.

Adam with a learning rate that is a pure function of the step (``lr_schedule``): ``constant``;
``cosine`` from ``learning_rate`` down to ``lr_final_fraction·learning_rate`` over all steps;
``exponential`` by the same overall factor. Being a function of the step, it needs no state of its
own and a resumed run sets the same rates.

``bc+sym`` folds every drawn state into ``X_train`` (``f⁻¹`` is measure preserving, so the batch is
uniform on ``X_train``); nothing is discarded, so the budget counts the states trained on.
Every step's batch comes from its own generator seeded by ``(seed, step)``, which makes a resumed
run identical to an uninterrupted one.

Files in the output directory: ``checkpoint.safetensors`` + ``checkpoint.json`` (network and Adam
state, schedule position), ``model.safetensors`` + ``model.json`` (the final network),
``train_log.csv``. Loading never unpickles: tensors come from safetensors, the rest from JSON.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import re
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

import nehmo_core
from nehmo_core.errors import (
    InvalidValueError,
    ModelFileError,
    NehmoError,
    UnknownNameError,
    as_options,
)
from nehmo_core.hjr.networks import NetworkSettings, ValueFunction, ValueNetwork, check_variant
from nehmo_core.hjr.systems import HJISystem, make_system, system_names

__all__ = [
    "DIRICHLET_LOSSES",
    "LR_SCHEDULES",
    "PRESETS",
    "TrainResult",
    "TrainSettings",
    "add_train_arguments",
    "load_value_function",
    "main",
    "parse_count",
    "run_train",
    "train",
]

FORMAT = "nehmo-hjr"
FORMAT_VERSION = 1
CHECKPOINT = "checkpoint"
MODEL = "model"
LOG_FILE = "train_log.csv"
LOG_COLUMNS = ("step", "samples", "tau_max", "loss", "dirichlet", "pde", "wall_s")
LR_SCHEDULES = ("constant", "cosine", "exponential")
DIRICHLET_LOSSES = ("l1", "l2")


@dataclass(frozen=True)
class TrainSettings:
    """Everything that defines a training run (stored in every checkpoint's JSON sidecar).

    Presets: :meth:`preset` ``"cpu"`` (3×64, batch 500, Adam 3e-4 cosine-decayed, tuned for
    one CPU thread), ``"cpu_12d"`` (``cpu`` at 3×128, batch 2000, squared Dirichlet term: for
    the 12-D arm pairs), ``"cpu_legacy"`` (the dataclass defaults: 3×128, batch 10k, constant
    1e-4) and ``"authors"`` (3×512, 65k batch, lr 2e-5, the authors' proportions).

    ``dirichlet_loss``: ``"l1"`` is DeepReach's ``|W − l̂|`` at ``τ = 0``; ``"l2"`` its square.
    With ``l1`` and the ``bc`` variants, the 12-D arm pairs never leave the trivial ``NN ≡ 0``
    (``V = l``, see :mod:`nehmo_core.hjr.diagnostics`): the absolute value's constant slope at
    zero pins the residual network there, at any weight we tried. The square's slope vanishes
    at zero, so small boundary errors cost little and the PDE term can shape the network.
    """

    variant: str = "bc+sym"
    network: NetworkSettings = field(default_factory=NetworkSettings)
    samples: int = 40_000_000  # total states drawn, pretraining included
    batch_size: int = 10_000
    boundary_fraction: float = 10 / 65  # share of each curriculum batch forced to τ = 0
    pretrain_fraction: float = 1 / 12  # share of the steps spent at τ = 0
    curriculum_fraction: float = 0.9  # share of the remaining steps over which τ_max grows to T
    learning_rate: float = 1e-4  # initial Adam rate
    lr_schedule: str = "constant"  # one of LR_SCHEDULES
    lr_final_fraction: float = 0.01  # last step's rate / learning_rate (cosine, exponential)
    dirichlet_weight: float = 40.0
    dirichlet_loss: str = "l1"  # one of DIRICHLET_LOSSES
    pde_weight: float = 1.0
    seed: int = 0
    checkpoint_every: int = 2_000_000  # [samples]
    log_every: int = 10  # [steps]

    def __post_init__(self) -> None:
        check_variant(self.variant)
        positive = ("samples", "batch_size", "learning_rate", "checkpoint_every", "log_every")
        for name in positive:
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        for name in ("boundary_fraction", "pretrain_fraction"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise InvalidValueError(name, "must lie in [0, 1)", getattr(self, name))
        if not 0.0 < self.curriculum_fraction <= 1.0:
            raise InvalidValueError(
                "curriculum_fraction", "must lie in (0, 1]", self.curriculum_fraction
            )
        if self.dirichlet_loss not in DIRICHLET_LOSSES:
            raise UnknownNameError("Dirichlet loss", self.dirichlet_loss, DIRICHLET_LOSSES)
        if self.lr_schedule not in LR_SCHEDULES:
            raise UnknownNameError("learning-rate schedule", self.lr_schedule, LR_SCHEDULES)
        if not 0.0 < self.lr_final_fraction <= 1.0:
            raise InvalidValueError(
                "lr_final_fraction", "must lie in (0, 1]", self.lr_final_fraction
            )
        for name in ("dirichlet_weight", "pde_weight"):
            if not getattr(self, name) >= 0:
                raise InvalidValueError(name, "must be >= 0", getattr(self, name))

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> TrainSettings:
        """A named preset with optional field overrides."""
        if name not in PRESETS:
            raise UnknownNameError("preset", name, PRESETS)
        return replace(PRESETS[name], **overrides)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    def learning_rate_at(self, step: int, total_steps: int) -> float:
        """Adam rate for ``step`` of ``total_steps`` (``lr_schedule``; a pure function)."""
        if self.lr_schedule == "constant" or total_steps <= 1:
            return self.learning_rate
        progress = min(1.0, step / (total_steps - 1))
        if self.lr_schedule == "cosine":
            share = self.lr_final_fraction + (1.0 - self.lr_final_fraction) * 0.5 * (
                1.0 + math.cos(math.pi * progress)
            )
        elif self.lr_schedule == "exponential":
            share = self.lr_final_fraction**progress
        else:
            raise UnknownNameError("learning-rate schedule", self.lr_schedule, LR_SCHEDULES)
        return self.learning_rate * share

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> TrainSettings:
        values = dict(data)
        values["network"] = NetworkSettings(**values.get("network", {}))
        return cls(**values)


# Tuned on Air3D for one CPU thread (bench/results/hjr_tuning.md): a small SIREN and many small
# steps with a cosine-decayed rate beat a wide network and few large steps at the same sample
# budget; most of the time budget goes to the full horizon.
_CPU = TrainSettings(
    network=NetworkSettings(width=64, hidden_layers=3),
    batch_size=500,
    learning_rate=3e-4,
    lr_schedule="cosine",
    lr_final_fraction=0.01,
    pretrain_fraction=0.02,
    curriculum_fraction=0.5,
)

PRESETS: dict[str, TrainSettings] = {
    "cpu": _CPU,
    # The 12-D arm pairs: "cpu" with the width and batch of the shipped models and the squared
    # Dirichlet term, without which their bc / bc+sym networks stay at V = l (hjr_tuning.md).
    "cpu_12d": replace(
        _CPU,
        network=NetworkSettings(width=128, hidden_layers=3),
        batch_size=2000,
        dirichlet_loss="l2",
    ),
    # The first CPU defaults (3×128, batch 10k, constant 1e-4): resumes runs started with them.
    "cpu_legacy": TrainSettings(),
    "authors": TrainSettings(
        network=NetworkSettings(width=512, hidden_layers=3, input_scaling="raw"),
        batch_size=65_000,
        learning_rate=2e-5,
        curriculum_fraction=1.0,
    ),
}


@dataclass(frozen=True)
class Schedule:
    """Step counts derived from the settings."""

    total_steps: int
    pretrain_steps: int
    curriculum_steps: int
    samples: int
    batch_size: int

    @classmethod
    def from_settings(cls, settings: TrainSettings) -> Schedule:
        total = math.ceil(settings.samples / settings.batch_size)
        # The exact variant meets the boundary by construction: pretraining would teach nothing.
        pretrain = 0 if settings.variant == "exact" else round(settings.pretrain_fraction * total)
        curriculum = max(1, round(settings.curriculum_fraction * (total - pretrain)))
        return cls(total, pretrain, curriculum, settings.samples, settings.batch_size)

    def batch_size_at(self, step: int) -> int:
        """States drawn at ``step`` (the last step takes what is left of the budget)."""
        return min(self.batch_size, self.samples - step * self.batch_size)

    def samples_before(self, step: int) -> int:
        return min(self.samples, step * self.batch_size)

    def tau_max(self, step: int, horizon: float) -> float:
        """Upper end of the sampled time-to-go at ``step`` [s]; 0 while pretraining."""
        if step < self.pretrain_steps:
            return 0.0
        return horizon * min(1.0, (step - self.pretrain_steps + 1) / self.curriculum_steps)


@dataclass(frozen=True)
class TrainResult:
    """Summary of a finished run."""

    out_dir: Path
    steps: int
    samples: int
    wall_seconds: float
    final_loss: float

    @property
    def samples_per_second(self) -> float:
        return self.samples / max(self.wall_seconds, 1e-9)


# ------------------------------------------------------------------------------------------------
# One step
# ------------------------------------------------------------------------------------------------


def _step_generator(seed: int, step: int) -> torch.Generator:
    state = np.random.SeedSequence([seed, step]).generate_state(2, dtype=np.uint32)
    return torch.Generator().manual_seed(int(state[0]) << 32 | int(state[1]))


def draw_batch(
    system: HJISystem, settings: TrainSettings, schedule: Schedule, step: int
) -> tuple[Tensor, Tensor, Tensor]:
    """``(τ (B,), x (B, n), boundary mask (B,))`` for ``step``, deterministic in (seed, step)."""
    generator = _step_generator(settings.seed, step)
    count = schedule.batch_size_at(step)
    x = system.sample_states(count, generator)
    if settings.variant == "bc+sym":
        x = system.fold(x)
    tau = torch.rand(count, generator=generator) * schedule.tau_max(step, system.horizon)
    pretraining = step < schedule.pretrain_steps
    n_boundary = count if pretraining else round(settings.boundary_fraction * count)
    mask = torch.arange(count) >= count - n_boundary
    tau = torch.where(mask, torch.zeros_like(tau), tau)
    return tau, x, mask


def _boundary_and_gradient(network: ValueNetwork, x: Tensor) -> tuple[Tensor, Tensor]:
    """``(l̂(x), ∇ₓl̂(x))`` without a graph: the boundary function is frozen."""
    with torch.enable_grad():
        xl = x.detach().requires_grad_(True)
        lhat = network.boundary_normalized(xl)
        (grad,) = torch.autograd.grad(lhat.sum(), xl)
    return lhat.detach(), grad.detach()


def _dirichlet_penalty(settings: TrainSettings, residual: Tensor) -> Tensor:
    """The Dirichlet term of the loss: mean ``|r|`` (``l1``) or mean ``r²`` (``l2``)."""
    if settings.dirichlet_loss == "l2":
        return (residual * residual).mean()
    return residual.abs().mean()


def loss_terms(
    network: ValueNetwork,
    settings: TrainSettings,
    tau: Tensor,
    x: Tensor,
    boundary_mask: Tensor,
    pretraining: bool,
) -> dict[str, Tensor]:
    """``{"loss", "dirichlet", "pde"}`` (scalars; ``loss`` carries the graph). ``dirichlet``
    and ``pde`` are mean absolute residuals whatever ``dirichlet_loss`` puts into ``loss``."""
    zero = tau.new_zeros(())
    if pretraining:
        _, residual = network.forward_with_residual(tau, x)
        dirichlet = residual.abs().mean()
        penalty = _dirichlet_penalty(settings, residual)
        return {"loss": settings.dirichlet_weight * penalty, "dirichlet": dirichlet, "pde": zero}
    tau = tau.detach().requires_grad_(True)
    x = x.detach().requires_grad_(True)
    if network.variant == "deepreach":
        w, residual = network.forward_with_residual(tau, x)
        dw_dtau, dw_dx = torch.autograd.grad(w.sum(), [tau, x], create_graph=True)
    else:
        # l is frozen: take l̂ and ∇l̂ once, detached, so the second-order graph (needed for the
        # PDE term) runs through the SIREN only, not through the boundary network.
        lhat, dl_dx = _boundary_and_gradient(network, x)
        nn_out = network.siren(network.network_input(tau, x))
        dn_dtau, dn_dx = torch.autograd.grad(nn_out.sum(), [tau, x], create_graph=True)
        if network.variant == "exact":
            residual = tau * nn_out
            dw_dtau, dw_dx = nn_out + tau * dn_dtau, dl_dx + tau[:, None] * dn_dx
        else:
            residual = nn_out
            dw_dtau, dw_dx = dn_dtau, dl_dx + dn_dx
        w = lhat + residual
    hamiltonian = network.system.hamiltonian(x, dw_dx)
    pde = (dw_dtau - hamiltonian.clamp(max=0.0)).abs().mean()
    if bool(boundary_mask.any()):
        on_boundary = residual[boundary_mask]
        dirichlet, penalty = on_boundary.abs().mean(), _dirichlet_penalty(settings, on_boundary)
    else:
        dirichlet = penalty = zero
    loss = settings.dirichlet_weight * penalty + settings.pde_weight * pde
    return {"loss": loss, "dirichlet": dirichlet, "pde": pde}


# ------------------------------------------------------------------------------------------------
# Files
# ------------------------------------------------------------------------------------------------


def _sidecar(
    kind: str,
    system: HJISystem,
    settings: TrainSettings,
    step: int,
    schedule: Schedule,
    wall_seconds: float,
) -> dict[str, Any]:
    return {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "kind": kind,
        "nehmo_version": nehmo_core.__version__,
        "torch_version": torch.__version__,
        "system": system.describe(),
        "variant": settings.variant,
        "settings": settings.to_dict(),
        "step": step,
        "total_steps": schedule.total_steps,
        "samples": schedule.samples_before(step),
        "wall_seconds": wall_seconds,
        "complete": step >= schedule.total_steps,
    }


def _write_atomic(path: Path, write: Any) -> None:
    tmp = path.with_name(path.name + ".tmp")
    write(tmp)
    os.replace(tmp, path)


def _save(
    out_dir: Path,
    stem: str,
    tensors: dict[str, Tensor],
    meta: dict[str, Any],
) -> None:
    from safetensors.torch import save_file

    tensors = {k: v.detach().clone().contiguous() for k, v in tensors.items()}
    _write_atomic(out_dir / f"{stem}.safetensors", lambda p: save_file(tensors, str(p)))
    text = json.dumps(meta, indent=2, sort_keys=True)
    _write_atomic(out_dir / f"{stem}.json", lambda p: p.write_text(text + "\n"))


def _checkpoint_tensors(network: ValueNetwork, optimizer: torch.optim.Optimizer) -> dict:
    tensors = {f"model.{k}": v for k, v in network.state_dict().items()}
    for index, state in optimizer.state_dict()["state"].items():
        for name, value in state.items():
            tensors[f"optim.{index}.{name}"] = torch.as_tensor(value)
    return tensors


def _read_sidecar(path: Path) -> dict[str, Any]:
    try:
        meta = json.loads(path.read_text())
    except FileNotFoundError as exc:
        raise ModelFileError(f"missing model sidecar {path}") from exc
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"model sidecar {path} is not valid JSON: {exc}") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ModelFileError(f"{path} is not a {FORMAT} sidecar")
    if meta.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(
            f"{path} has format_version {meta.get('format_version')}; expected {FORMAT_VERSION}"
        )
    return meta


def _read_tensors(path: Path) -> dict[str, Tensor]:
    from safetensors import SafetensorError
    from safetensors.torch import load_file

    try:
        return load_file(str(path))
    except FileNotFoundError as exc:
        raise ModelFileError(f"missing weights file {path}") from exc
    except (SafetensorError, OSError) as exc:
        raise ModelFileError(f"cannot read weights file {path}: {exc}") from exc


def _strip_prefix(tensors: dict[str, Tensor], prefix: str) -> dict[str, Tensor]:
    return {k[len(prefix) :]: v for k, v in tensors.items() if k.startswith(prefix)}


SHIPPED_VALUE_FUNCTIONS: dict[str, tuple[str, ...]] = {
    "ur5_ur5": ("bc+sym", "bc", "deepreach"),
    "ur5_ur5_diag": ("bc+sym",),
    "ur5_ur5_opposite": ("bc+sym",),
    "ur5_kinova": ("bc+sym",),
    "kinova_ur5": ("bc+sym",),
}


def shipped_value_path(name: str, variant: str = "bc+sym") -> Path:
    """File of a shipped value function: ``models/value_<pair>_<variant>.safetensors``."""
    if name not in SHIPPED_VALUE_FUNCTIONS:
        raise UnknownNameError("shipped value function", name, SHIPPED_VALUE_FUNCTIONS)
    if variant not in SHIPPED_VALUE_FUNCTIONS[name]:
        raise UnknownNameError(
            f"variant shipped for {name}", variant, SHIPPED_VALUE_FUNCTIONS[name]
        )
    slug = variant.replace("+", "_")
    return Path(__file__).resolve().parents[1] / "models" / f"value_{name}_{slug}.safetensors"


def load_value_function(
    path: str | Path, system: HJISystem | None = None, variant: str | None = None
) -> ValueFunction:
    """Load a trained value function: a shipped one by name, a run directory or a file.

    ``load_value_function("ur5_ur5", variant="bc+sym")`` loads a shipped model (variants per
    :data:`SHIPPED_VALUE_FUNCTIONS`). A directory loads its ``model.safetensors`` (or, for an
    unfinished run, its checkpoint). ``system`` must be given for systems that are not
    registered by name; when given, its name must match the file's. Never unpickles.
    """
    if isinstance(path, str) and path in SHIPPED_VALUE_FUNCTIONS:
        import nehmo_core.hjr.arm_pairs  # noqa: F401  (registers the arm-pair systems)

        path = shipped_value_path(path, variant or "bc+sym")
    elif isinstance(path, str) and "/" not in path and not Path(path).exists():
        raise UnknownNameError("shipped value function", path, SHIPPED_VALUE_FUNCTIONS)
    elif variant is not None:
        raise InvalidValueError("variant", "is only used with a shipped model name", variant)
    path = Path(path)
    if path.is_dir():
        model = path / f"{MODEL}.safetensors"
        path = model if model.exists() else path / f"{CHECKPOINT}.safetensors"
    if path.suffix != ".safetensors":
        raise ModelFileError(f"expected a run directory or a .safetensors file; got {path}")
    meta = _read_sidecar(path.with_suffix(".json"))
    name = meta["system"]["name"]
    if system is None:
        system = make_system(name)
    elif system.name != name:
        raise ModelFileError(f"{path} was trained for system {name!r}, not {system.name!r}")
    settings = TrainSettings.from_dict(meta["settings"])
    network = ValueNetwork(system, settings.variant, settings.network)
    tensors = _read_tensors(path)
    if meta["kind"] == CHECKPOINT:
        tensors = _strip_prefix(tensors, "model.")
    try:
        network.load_state_dict(tensors)
    except RuntimeError as exc:
        raise ModelFileError(f"weights in {path} do not fit the network: {exc}") from exc
    value_function = ValueFunction(network)
    value_function.card = dict(meta.get("card", {}))
    return value_function


# ------------------------------------------------------------------------------------------------
# The loop
# ------------------------------------------------------------------------------------------------


class _CsvLog:
    def __init__(self, path: Path, keep_before_step: int) -> None:
        rows: list[list[str]] = []
        if keep_before_step > 0 and path.exists():
            with path.open(newline="") as handle:
                rows = [r for r in list(csv.reader(handle))[1:] if int(r[0]) < keep_before_step]
        self.handle = path.open("w", newline="")
        self.writer = csv.writer(self.handle)
        self.writer.writerow(LOG_COLUMNS)
        self.writer.writerows(rows)

    def write(self, row: Sequence[Any]) -> None:
        self.writer.writerow(row)

    def close(self) -> None:
        self.handle.close()


def _prepare_out_dir(out_dir: Path, resume: bool) -> bool:
    """Create ``out_dir``; return whether a checkpoint to resume from exists."""
    out_dir.mkdir(parents=True, exist_ok=True)
    has_checkpoint = (out_dir / f"{CHECKPOINT}.json").exists()
    if not resume and (has_checkpoint or (out_dir / f"{MODEL}.json").exists()):
        raise InvalidValueError(
            "out", "already holds a run; resume it or choose another directory", str(out_dir)
        )
    return resume and has_checkpoint


def _restore(
    out_dir: Path,
    system: HJISystem,
    settings: TrainSettings,
    network: ValueNetwork,
    optimizer: torch.optim.Optimizer,
) -> tuple[int, float]:
    meta = _read_sidecar(out_dir / f"{CHECKPOINT}.json")
    # Compared as settings (not dicts) so a checkpoint from before a field existed, which
    # therefore ran with that field's default, still resumes.
    if TrainSettings.from_dict(meta["settings"]) != settings:
        raise ModelFileError(
            f"checkpoint in {out_dir} was written with settings {meta['settings']}, "
            f"not {settings.to_dict()}"
        )
    if meta["system"] != system.describe():
        raise ModelFileError(f"checkpoint in {out_dir} is for system {meta['system']}")
    tensors = _read_tensors(out_dir / f"{CHECKPOINT}.safetensors")
    network.load_state_dict(_strip_prefix(tensors, "model."))
    state: dict[int, dict[str, Tensor]] = {}
    for key, value in _strip_prefix(tensors, "optim.").items():
        index, name = key.split(".", 1)
        state.setdefault(int(index), {})[name] = value
    optimizer.load_state_dict(
        {"state": state, "param_groups": optimizer.state_dict()["param_groups"]}
    )
    return int(meta["step"]), float(meta["wall_seconds"])


def train(
    system: HJISystem,
    settings: TrainSettings,
    out_dir: str | Path,
    resume: bool = False,
    progress: bool = True,
    stop_after_steps: int | None = None,
) -> TrainResult:
    """Train (or resume) a value network for ``system``; write checkpoints and the model.

    ``stop_after_steps`` ends the call early after a checkpoint (used to test resume).
    """
    out_dir = Path(out_dir)
    resuming = _prepare_out_dir(out_dir, resume)
    schedule = Schedule.from_settings(settings)
    generator = torch.Generator().manual_seed(settings.seed)
    network = ValueNetwork(system, settings.variant, settings.network, generator)
    optimizer = torch.optim.Adam(network.parameters(), lr=settings.learning_rate)
    step, wall = _restore(out_dir, system, settings, network, optimizer) if resuming else (0, 0.0)
    log = _CsvLog(out_dir / LOG_FILE, keep_before_step=step)
    ckpt_steps = max(1, settings.checkpoint_every // settings.batch_size)
    last = (
        schedule.total_steps
        if stop_after_steps is None
        else min(schedule.total_steps, step + stop_after_steps)
    )
    bar = _progress_bar(progress, schedule, step, system.name, settings.variant)
    start, terms = time.perf_counter() - wall, {}
    try:
        while step < last:
            terms = _train_step(network, optimizer, system, settings, schedule, step)
            step += 1
            wall = time.perf_counter() - start
            if step % settings.log_every == 0 or step == schedule.total_steps:
                row = _log_row(step - 1, schedule, system, terms, wall)
                log.write(row)
                if bar is not None:
                    bar.set_postfix(tau=f"{row[2]:.3f}", dir=f"{row[4]:.2e}", pde=f"{row[5]:.2e}")
            if bar is not None:
                bar.update(schedule.batch_size_at(step - 1))
            if step % ckpt_steps == 0 or step == last:
                meta = _sidecar(CHECKPOINT, system, settings, step, schedule, wall)
                _save(out_dir, CHECKPOINT, _checkpoint_tensors(network, optimizer), meta)
    finally:
        log.close()
        if bar is not None:
            bar.close()
    if step >= schedule.total_steps:
        meta = _sidecar(MODEL, system, settings, step, schedule, wall)
        _save(out_dir, MODEL, dict(network.state_dict()), meta)
    final = float(terms["loss"]) if terms else math.nan
    return TrainResult(out_dir, step, schedule.samples_before(step), wall, final)


def _train_step(
    network: ValueNetwork,
    optimizer: torch.optim.Optimizer,
    system: HJISystem,
    settings: TrainSettings,
    schedule: Schedule,
    step: int,
) -> dict[str, float]:
    tau, x, mask = draw_batch(system, settings, schedule, step)
    for group in optimizer.param_groups:
        group["lr"] = settings.learning_rate_at(step, schedule.total_steps)
    terms = loss_terms(network, settings, tau, x, mask, step < schedule.pretrain_steps)
    optimizer.zero_grad(set_to_none=True)
    terms["loss"].backward()
    optimizer.step()
    return {k: float(v.detach()) for k, v in terms.items()}


def _log_row(
    step: int, schedule: Schedule, system: HJISystem, terms: dict[str, float], wall: float
) -> list[Any]:
    return [
        step,
        schedule.samples_before(step + 1),
        schedule.tau_max(step, system.horizon),
        terms["loss"],
        terms["dirichlet"],
        terms["pde"],
        round(wall, 3),
    ]


def _progress_bar(enabled: bool, schedule: Schedule, step: int, name: str, variant: str) -> Any:
    if not enabled:
        return None
    from tqdm import tqdm

    return tqdm(
        total=schedule.samples,
        initial=schedule.samples_before(step),
        unit="sample",
        unit_scale=True,
        desc=f"{name} {variant}",
        dynamic_ncols=True,
    )


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------

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
    parser.add_argument("--checkpoint-every", default=None, help="samples between checkpoints")
    parser.add_argument("--threads", type=int, default=None, help="torch CPU threads")
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
    result = train(system, settings, args.out, resume=args.resume, progress=not args.no_progress)
    print(
        f"{system.name} {settings.variant}: {result.steps} steps, {result.samples} samples, "
        f"{result.wall_seconds:.1f} s ({result.samples_per_second:.0f} samples/s), "
        f"final loss {result.final_loss:.4g}; model in {result.out_dir}"
    )
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m nehmo_core.hjr.train --system air3d --out runs/a``."""
    parser = argparse.ArgumentParser(prog="nehmo train", description=__doc__.splitlines()[0])
    add_train_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run_train(args)
    except NehmoError as exc:
        parser.exit(2, f"nehmo train: error: {exc}\n")


if __name__ == "__main__":
    raise SystemExit(main())
