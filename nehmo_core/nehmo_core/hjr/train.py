"""The training loop of a value network (DeepReach-style): loss, steps, checkpoints, resume.

Schedule (a budget of ``samples`` states, pretraining included, in steps of ``batch_size``):

1. ``pretrain_fraction`` of the steps at ``τ = 0`` only, Dirichlet loss only.
2. The rest with a linear time curriculum ``τ ~ U[0, T·min(1, k/K)]``, ``K`` being
   ``curriculum_fraction`` of the remaining steps; the last ``boundary_fraction`` of every batch
   is forced to ``τ = 0``. Loss ``dirichlet_weight·mean|W − l̂|`` over the ``τ = 0`` points plus
   ``pde_weight·mean|∂W/∂τ − min(0, H(x, ∇ₓW))|`` over all points (each term squared instead
   with ``dirichlet_loss`` / ``pde_loss`` ``"l2"``).

Adam with a learning rate that is a pure function of the step (``lr_schedule``): ``constant``;
``cosine`` from ``learning_rate`` down to ``lr_final_fraction·learning_rate`` over all steps;
``exponential`` by the same overall factor. Being a function of the step, it needs no state of its
own and a resumed run sets the same rates.

``bc+sym`` folds every drawn state into ``X_train`` (``f⁻¹`` is measure preserving, so the batch is
uniform on ``X_train``); nothing is discarded, so the budget counts the states trained on.
Every step's batch comes from its own generator seeded by ``(seed, step)``, which makes a resumed
run identical to an uninterrupted one.

Settings and presets: :mod:`.train_settings`; file formats: :mod:`.model_files`; the
``nehmo train`` command: :mod:`.train_cli`.
"""

from __future__ import annotations

import csv
import math
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from nehmo_core.errors import (
    InvalidValueError,
    ModelFileError,
)
from nehmo_core.hjr.model_files import (
    CHECKPOINT,
    MODEL,
    _checkpoint_tensors,
    _read_sidecar,
    _read_tensors,
    _save,
    _sidecar,
    _strip_prefix,
)
from nehmo_core.hjr.networks import ValueNetwork
from nehmo_core.hjr.systems import HJISystem
from nehmo_core.hjr.train_settings import Schedule, TrainSettings

__all__ = ["TrainResult", "draw_batch", "loss_terms", "train"]

LOG_FILE = "train_log.csv"
LOG_COLUMNS = ("step", "samples", "tau_max", "loss", "dirichlet", "pde", "wall_s")


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


def _penalty(kind: str, residual: Tensor) -> Tensor:
    """A term of the loss: mean ``|r|`` (``l1``) or mean ``r²`` (``l2``); ``kind`` is the
    settings' ``dirichlet_loss`` or ``pde_loss``."""
    if kind == "l2":
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
    slope = zero  # mean excess of ‖∇ₓNN‖₁ over ‖∇ₓl̂‖₁ (bc variants)
    if pretraining:
        _, residual = network.forward_with_residual(tau, x)
        dirichlet = residual.abs().mean()
        penalty = _penalty(settings.dirichlet_loss, residual)
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
        # the residual's slope beyond the boundary's (ripples; a value's own slope costs nothing)
        slope = torch.relu(dn_dx.abs().sum(dim=1) - dl_dx.abs().sum(dim=1)).mean()
    hamiltonian = network.system.hamiltonian(x, dw_dx)
    pde_residual = dw_dtau - hamiltonian.clamp(max=0.0)
    pde = pde_residual.abs().mean()
    if bool(boundary_mask.any()):
        on_boundary = residual[boundary_mask]
        dirichlet, penalty = (
            on_boundary.abs().mean(),
            _penalty(settings.dirichlet_loss, on_boundary),
        )
    else:
        dirichlet = penalty = zero
    pde_penalty = _penalty(settings.pde_loss, pde_residual)
    loss = settings.dirichlet_weight * penalty + settings.pde_weight * pde_penalty
    if settings.gradient_weight > 0:
        loss = loss + settings.gradient_weight * slope
    return {"loss": loss, "dirichlet": dirichlet, "pde": pde}


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
    device: str = "cpu",
) -> TrainResult:
    """Train (or resume) a value network for ``system``; write checkpoints and the model.

    ``stop_after_steps`` ends the call early after a checkpoint (used to test resume).
    ``device`` (``cpu``, ``cuda``, ``auto``: see :func:`resolve_device`) holds the network and
    the system's boundary module; batches are drawn on the CPU (so a seed draws the same
    states everywhere) and moved there. Saved files are CPU tensors either way.
    """
    target = resolve_device(device)
    out_dir = Path(out_dir)
    resuming = _prepare_out_dir(out_dir, resume)
    schedule = Schedule.from_settings(settings)
    generator = torch.Generator().manual_seed(settings.seed)
    network = ValueNetwork(system, settings.variant, settings.network, generator)
    optimizer = torch.optim.Adam(network.parameters(), lr=settings.learning_rate)
    step, wall = _restore(out_dir, system, settings, network, optimizer) if resuming else (0, 0.0)
    _move(network, system, optimizer, target)
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


DEVICES = ("auto", "cpu", "cuda")


def resolve_device(name: str) -> torch.device:
    """``cpu``; ``cuda`` (a clear error when no CUDA device is present); ``auto``: cuda if
    present, else cpu."""
    if name not in DEVICES:
        raise InvalidValueError("device", f"must be one of {list(DEVICES)}", name)
    if name == "cuda" and not torch.cuda.is_available():
        raise InvalidValueError(
            "device",
            "asks for CUDA, but torch sees no CUDA device (torch.cuda.is_available() is False; "
            f"this torch is {torch.__version__}); use --device cpu or auto",
            name,
        )
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    return torch.device(name)


def _move(
    network: ValueNetwork, system: HJISystem, optimizer: torch.optim.Optimizer, device: torch.device
) -> None:
    """Put the network, its optimizer state and the system's boundary module on ``device``."""
    if device.type == "cpu":
        return
    network.to(device)
    boundary = getattr(system, "boundary_fn", None)
    if isinstance(boundary, torch.nn.Module):
        boundary.to(device)
    for state in optimizer.state.values():
        for key, value in state.items():
            if isinstance(value, Tensor):
                state[key] = value.to(device)


def _train_step(
    network: ValueNetwork,
    optimizer: torch.optim.Optimizer,
    system: HJISystem,
    settings: TrainSettings,
    schedule: Schedule,
    step: int,
) -> dict[str, float]:
    tau, x, mask = draw_batch(system, settings, schedule, step)
    device = network._center.device
    if device.type != "cpu":
        tau, x, mask = tau.to(device), x.to(device), mask.to(device)
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
