"""Has a value network learned the HJ PDE, or only its boundary condition?

With the ``bc`` variants (``W = l̂ + NN``) a network whose residual ``NN`` stays at zero meets
the Dirichlet condition exactly and every test of symmetry, gradients and ``V(0, ·) = l``, yet
it is no reachability value: ``V(τ, x) = l(x)`` for every ``τ``. The PDE tells the two apart.
At ``V = l`` its residual is ``|min(0, H(x, ∇l))|``, which is positive wherever the adversary
can close in faster than the arm can retreat; a network that learned the value must do
clearly better than that trivial level.

:func:`pde_diagnostics` measures, on states drawn as training draws them (folded into
``X_train`` for ``bc+sym``) and ``τ`` uniform in ``[0, T]``:

- the model's mean PDE residual ``|∂W/∂τ − min(0, H(x, ∇W))|`` and the same for ``W = l̂``,
  in the network's normalized units (the training loss's ``pde`` term), and their ratio;
- the share of states where ``V`` must fall below ``l`` (``H(x, ∇l) < 0``);
- how far ``V(T, ·)`` falls below ``l`` [m] (the mean, and the 99th percentile of ``l − V``);
- for the ``bc`` variants (``W = l̂ + NN``, uncapped): the share of states where the model's own
  ``H(x, ∇W) < 0``, and ``mean ‖∇ₓNN‖₁ / mean ‖∇ₓl̂‖₁``. A network that meets the PDE with steep
  ripples instead of a value (:class:`~nehmo_core.hjr.train_settings.TrainSettings`'
  ``gradient_weight``) shows as a slope ratio well above 1 with almost no state where ``H < 0``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from nehmo_core.errors import InvalidValueError
from nehmo_core.hjr.networks import ValueFunction

__all__ = [
    "SLOPE_LIMIT",
    "TRIVIAL_RATIO",
    "PdeDiagnostics",
    "learned_value",
    "pde_diagnostics",
    "unlearned_warning",
]

SLOPE_LIMIT = 1.0
"""A residual network steeper than its boundary (``slope_ratio``) is rippling, not a value: the
shipped models that learned their game measure 0.12-0.28, the Panda pairs' first ones 1.4-2.8."""
TRIVIAL_RATIO = 0.7
"""A PDE residual at this share of ``V = l``'s or above: the network learned little (the
shipped models that learned their game measure 0.20-0.43)."""


@dataclass(frozen=True)
class PdeDiagnostics:
    """See the module docstring; residuals in normalized units, distances in metres."""

    samples: int
    pde_residual: float
    trivial_residual: float  # the residual of W = l̂ (a network that learned nothing)
    residual_ratio: float  # pde_residual / trivial_residual: 1 means V = l
    must_fall_share: float  # share of states with H(x, ∇l) < 0
    mean_fall_at_horizon: float  # mean of l(x) − V(T, x) [m]
    p99_fall_at_horizon: float  # 99th percentile of l(x) − V(T, x) [m]
    model_fall_share: float | None = None  # share of H(x, ∇W) < 0, W = l̂ + NN uncapped (bc)
    slope_ratio: float | None = None  # mean ‖∇ₓNN‖₁ / mean ‖∇ₓl̂‖₁ (bc variants)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def pde_diagnostics(
    value_function: ValueFunction, samples: int = 4096, seed: int = 0
) -> PdeDiagnostics:
    """Measure ``value_function`` against the PDE (see the module docstring)."""
    if samples < 2:
        raise InvalidValueError("samples", "must be >= 2", samples)
    network = value_function.network
    system = network.system
    dtype = value_function.dtype
    generator = torch.Generator().manual_seed(seed)
    x = system.sample_states(samples, generator)
    if network.uses_symmetry:
        x = system.fold(x)
    x = x.to(dtype)
    horizon = float(system.horizon)
    tau = (horizon * torch.rand(samples, generator=generator)).to(dtype)
    with torch.enable_grad():
        xg = x.clone().requires_grad_(True)
        tg = tau.clone().requires_grad_(True)
        w = network(tg, xg)
        dw_dtau, dw_dx = torch.autograd.grad(w.sum(), [tg, xg])
        xl = x.clone().requires_grad_(True)
        lhat = network.boundary_normalized(xl)
        (dl_dx,) = torch.autograd.grad(lhat.sum(), xl)
    with torch.no_grad():
        pde = (dw_dtau - system.hamiltonian(x, dw_dx).clamp(max=0.0)).abs().mean()
        h_l = system.hamiltonian(x, dl_dx)
        trivial = h_l.clamp(max=0.0).abs().mean()
        at_horizon = value_function.value_torch(torch.full_like(tau, horizon), x)
        fall = (system.boundary(x) - at_horizon).double().numpy()
    model_fall = slope = None
    if network.variant in ("bc", "bc+sym"):
        with torch.enable_grad():
            xn = x.clone().requires_grad_(True)
            (dn_dx,) = torch.autograd.grad(network.siren(network.network_input(tau, xn)).sum(), xn)
        with torch.no_grad():
            model_fall = float((system.hamiltonian(x, dl_dx + dn_dx) < 0.0).double().mean())
            slope = float(dn_dx.abs().sum(dim=1).mean() / dl_dx.abs().sum(dim=1).mean())
    trivial_value = float(trivial)
    return PdeDiagnostics(
        samples=samples,
        pde_residual=float(pde),
        trivial_residual=trivial_value,
        residual_ratio=float(pde) / trivial_value if trivial_value > 0.0 else float("nan"),
        must_fall_share=float((h_l < 0.0).double().mean()),
        mean_fall_at_horizon=float(np.mean(fall)),
        p99_fall_at_horizon=float(np.percentile(fall, 99)),
        model_fall_share=model_fall,
        slope_ratio=slope,
    )


def learned_value(d: PdeDiagnostics) -> bool:
    """Whether ``d`` reads as a learned value: a PDE residual clearly below ``V = l``'s
    (:data:`TRIVIAL_RATIO`) and, for the ``bc`` variants, no steeper than its boundary
    (:data:`SLOPE_LIMIT`) with ``H(x, ∇W) < 0`` on at least half the states where
    ``H(x, ∇l) < 0``."""
    if d.residual_ratio >= TRIVIAL_RATIO:
        return False
    if d.slope_ratio is None or d.model_fall_share is None:
        return True
    return d.slope_ratio < SLOPE_LIMIT and d.model_fall_share >= 0.5 * d.must_fall_share


def unlearned_warning(game: str, pde: dict[str, Any], tried: Sequence[str] = ()) -> str:
    """The line a pair build prints for a value function that reads as no learned value
    (``pde``: a :class:`PdeDiagnostics` as a dict; ``tried``: the PDE losses already trained,
    so the advice does not repeat them)."""
    slope, fall = pde.get("slope_ratio"), pde.get("model_fall_share")
    advice = "train longer or with a larger --gradient-weight"
    if "l2" not in tried:
        advice += ", or with --pde-loss l2"
    done = ""
    if len(tried) > 1:
        done = f" (trained with --pde-loss {', '.join(tried)}; the attempt nearest its PDE kept)"
    return (
        f"value function {game}{done} learned little beyond its boundary (residual "
        f"{pde['residual_ratio']:.2f} of V = l's, slope ratio "
        f"{'-' if slope is None else f'{slope:.2f}'}, H < 0 on "
        f"{'-' if fall is None else f'{fall:.2f}'} of states against "
        f"{pde['must_fall_share']:.2f} for V = l, mean l - V(T) "
        f"{pde['mean_fall_at_horizon']:.4f} m): its certificates hold, but its V is close to a "
        f"distance; {advice} (docs/value-functions.md)"
    )
