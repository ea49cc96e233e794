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
- how far ``V(T, ·)`` falls below ``l`` [m] (the mean, and the 99th percentile of ``l − V``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch

from nehmo_core.errors import InvalidValueError
from nehmo_core.hjr.networks import ValueFunction

__all__ = ["PdeDiagnostics", "pde_diagnostics"]


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
    trivial_value = float(trivial)
    return PdeDiagnostics(
        samples=samples,
        pde_residual=float(pde),
        trivial_residual=trivial_value,
        residual_ratio=float(pde) / trivial_value if trivial_value > 0.0 else float("nan"),
        must_fall_share=float((h_l < 0.0).double().mean()),
        mean_fall_at_horizon=float(np.mean(fall)),
        p99_fall_at_horizon=float(np.percentile(fall, 99)),
    )
