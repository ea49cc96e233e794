"""SIREN value networks, the training variants, and the :class:`ValueFunction` they produce.

Variants (``VARIANTS``), all in the system's normalized value units ``W`` (see
:class:`~nehmo_core.hjr.systems.HJISystem`), with ``l̂(x) = (l(x) − value_mean)·value_scale``:

- ``deepreach``: ``W = NN(τ, x)`` (DeepReach).
- ``bc``: ``W = l̂(x) + NN(τ, x)`` (boundary residual).
- ``bc+sym``: ``bc`` trained on ``X_train`` only and evaluated as ``W(τ, fold(x))``;
  ``fold`` maps ``X_sym`` back through ``f⁻¹`` and never touches ``τ``; gradients follow by the
  chain rule (autograd through ``fold``).
- ``exact``: ``W = l̂(x) + τ·NN(τ, x)``, which meets ``W(0, x) = l̂(x)`` exactly.

Network input: ``(τ̂, x̂)`` with ``input_scaling = "unit"`` mapping ``τ ∈ [0, T]`` and every state
coordinate's domain to ``[−1, 1]``; ``"raw"`` feeds seconds and state units as they are (what the
authors do for arms, raw radians: with ``ω0 = 30`` that gives the first layer ~π× higher
frequencies than ``"unit"``).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.hjr.systems import HJISystem

__all__ = [
    "INPUT_SCALINGS",
    "VARIANTS",
    "NetworkSettings",
    "Siren",
    "ValueFunction",
    "ValueNetwork",
]

VARIANTS = ("deepreach", "bc", "bc+sym", "exact")
INPUT_SCALINGS = ("unit", "raw")


@dataclass(frozen=True)
class NetworkSettings:
    """Shape of the SIREN value network.

    ``hidden_layers`` counts width×width sine layers after the first sine layer (DeepReach's
    ``num_hidden_layers``): "3×256" is ``width=256, hidden_layers=3``, i.e. 4 sine layers plus a
    linear output.
    """

    width: int = 128
    hidden_layers: int = 3
    omega0: float = 30.0
    input_scaling: str = "unit"

    def __post_init__(self) -> None:
        if self.width < 1:
            raise InvalidValueError("width", "must be >= 1", self.width)
        if self.hidden_layers < 0:
            raise InvalidValueError("hidden_layers", "must be >= 0", self.hidden_layers)
        if not self.omega0 > 0:
            raise InvalidValueError("omega0", "must be > 0", self.omega0)
        if self.input_scaling not in INPUT_SCALINGS:
            raise UnknownNameError("input scaling", self.input_scaling, INPUT_SCALINGS)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def check_variant(variant: str) -> str:
    """Return ``variant`` or raise :class:`UnknownNameError` listing the valid ones."""
    if variant not in VARIANTS:
        raise UnknownNameError("variant", variant, VARIANTS)
    return variant


class Siren(nn.Module):
    """``sin(ω0·(W z + b))`` layers with a linear output, SIREN initialization.

    First layer weights ``U(−1/n_in, 1/n_in)``; every later layer (output included)
    ``U(±√(6/n_in)/ω0)``; biases keep PyTorch's default ``U(±1/√n_in)``.
    """

    def __init__(
        self,
        in_features: int,
        settings: NetworkSettings,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        self.omega0 = settings.omega0
        sizes = [in_features] + [settings.width] * (settings.hidden_layers + 1)
        self.hidden = nn.ModuleList(nn.Linear(a, b) for a, b in itertools.pairwise(sizes))
        self.output = nn.Linear(settings.width, 1)
        self._initialize(generator)

    @torch.no_grad()
    def _initialize(self, generator: torch.Generator | None) -> None:
        layers = [*self.hidden, self.output]
        for index, layer in enumerate(layers):
            fan_in = layer.in_features
            bound = 1.0 / fan_in if index == 0 else math.sqrt(6.0 / fan_in) / self.omega0
            layer.weight.uniform_(-bound, bound, generator=generator)
            layer.bias.uniform_(
                -1.0 / math.sqrt(fan_in), 1.0 / math.sqrt(fan_in), generator=generator
            )

    def forward(self, z: Tensor) -> Tensor:
        """``(B, in_features) -> (B,)``."""
        h = z
        for layer in self.hidden:
            h = torch.sin(self.omega0 * layer(h))
        return self.output(h)[:, 0]


class ValueNetwork(nn.Module):
    """The trainable value in normalized units, ``W(τ, x)``, for one system and variant.

    ``forward`` does *not* apply the symmetry fold (training samples are already in
    ``X_train``); :class:`ValueFunction` does. The system (and its boundary function) is held as a
    plain attribute, so its parameters are neither trained nor saved with the network.
    """

    _center: Tensor  # (n,) middle of the state domain
    _half_width: Tensor  # (n,)

    def __init__(
        self,
        system: HJISystem,
        variant: str,
        settings: NetworkSettings | None = None,
        generator: torch.Generator | None = None,
    ) -> None:
        super().__init__()
        self.system = system
        self.variant = check_variant(variant)
        self.settings = settings or NetworkSettings()
        self.siren = Siren(system.state_dim + 1, self.settings, generator)
        # Evaluate ``bc``/``bc+sym`` as ``l̂ + min(W − l̂, 0)``: an avoid value function never
        # exceeds its boundary, so capping the residual at 0 only brings a network that
        # overshoots l closer to the true V. Set on loading for models whose card asks for it
        # (the pairs of ``nehmo pair build``); never during training.
        self.cap_residual = False
        lower = torch.as_tensor(system.lower, dtype=torch.float32)
        upper = torch.as_tensor(system.upper, dtype=torch.float32)
        self.register_buffer("_center", (upper + lower) / 2, persistent=False)
        self.register_buffer("_half_width", (upper - lower) / 2, persistent=False)

    @property
    def uses_symmetry(self) -> bool:
        return self.variant == "bc+sym"

    def network_input(self, tau: Tensor, x: Tensor) -> Tensor:
        """``(τ (B,), x (B, n)) -> (B, n+1)`` network input, scaled per ``input_scaling``."""
        if self.settings.input_scaling == "raw":
            return torch.cat([tau[:, None], x], dim=1)
        tau_hat = 2.0 * tau / self.system.horizon - 1.0
        x_hat = (x - self._center) / self._half_width
        return torch.cat([tau_hat[:, None], x_hat], dim=1)

    def boundary_normalized(self, x: Tensor) -> Tensor:
        """``l̂(x) = (l(x) − value_mean)·value_scale``, ``(B,)``."""
        return (self.system.boundary(x) - self.system.value_mean) * self.system.value_scale

    def forward(self, tau: Tensor, x: Tensor) -> Tensor:
        """``W(τ, x)`` for ``τ (B,)`` [s] and ``x (B, n)``, ``(B,)``."""
        return self.forward_with_residual(tau, x)[0]

    def forward_with_residual(self, tau: Tensor, x: Tensor) -> tuple[Tensor, Tensor]:
        """``(W, W − l̂)``, both ``(B,)``; the second is the Dirichlet residual at ``τ = 0``."""
        nn_out = self.siren(self.network_input(tau, x))
        if self.variant == "deepreach":
            return nn_out, nn_out - self.boundary_normalized(x)
        if self.variant == "exact":
            residual = tau * nn_out
            return self.boundary_normalized(x) + residual, residual
        if self.cap_residual:
            return self.boundary_normalized(x) + torch.clamp(nn_out, max=0.0), nn_out
        return self.boundary_normalized(x) + nn_out, nn_out  # bc, bc+sym


ArrayLike = Tensor | np.ndarray | float


class ValueFunction:
    """A trained value function ``V(τ, x)`` in physical units, symmetry applied.

    ``value`` and ``gradient`` take ``tau`` as a scalar or ``(B,)`` [s] and ``x`` as ``(B, n)``
    (or ``(n,)`` for one state); numpy in gives numpy out (float64), torch in gives torch out.
    """

    def __init__(self, network: ValueNetwork, chunk_size: int = 65536) -> None:
        self.network = network.eval()
        self.system = network.system
        self.variant = network.variant
        self.chunk_size = chunk_size
        self.card: dict[str, Any] = {}  # the model card (set when loaded from a file)

    @property
    def dtype(self) -> torch.dtype:
        """Floating-point type of the network (float32 unless converted with ``.double()``)."""
        return next(self.network.parameters()).dtype

    # -- torch core -----------------------------------------------------------------------------
    def value_torch(self, tau: Tensor, x: Tensor) -> Tensor:
        """Differentiable ``V(τ, x)``: ``τ (B,)``, ``x (B, n)`` float32 -> ``(B,)``."""
        if self.network.uses_symmetry:
            x = self.system.fold(x)
        w = self.network(tau, x)
        return w / self.system.value_scale + self.system.value_mean

    def _prepare(self, tau: ArrayLike, x: ArrayLike) -> tuple[Tensor, Tensor, bool, bool]:
        is_numpy = not isinstance(x, Tensor)
        dtype = self.dtype
        xt = torch.as_tensor(np.asarray(x) if is_numpy else x, dtype=dtype)
        single = xt.ndim == 1
        if single:
            xt = xt[None, :]
        self.system.check_states(xt)
        tt = torch.as_tensor(tau, dtype=dtype).reshape(-1)
        if tt.shape[0] == 1:
            tt = tt.expand(xt.shape[0])
        if tt.shape[0] != xt.shape[0]:
            raise InvalidValueError(
                "tau", f"must be a scalar or have {xt.shape[0]} entries", tuple(tt.shape)
            )
        if torch.any(tt < 0) or torch.any(tt > self.system.horizon + 1e-6):
            raise InvalidValueError(
                "tau", f"must lie in [0, {self.system.horizon}]", (float(tt.min()), float(tt.max()))
            )
        return tt, xt, is_numpy, single

    @staticmethod
    def _finish(result: Tensor, is_numpy: bool, single: bool) -> Any:
        out = result[0] if single else result
        if not is_numpy:
            return out
        array = out.numpy().astype(np.float64)
        return array[()] if array.ndim == 0 else array  # np.float64 for a single value

    # -- public ---------------------------------------------------------------------------------
    def value(self, tau: ArrayLike, x: ArrayLike) -> Any:
        """``V(τ, x)``, shape ``(B,)`` (or a scalar for one state)."""
        tt, xt, is_numpy, single = self._prepare(tau, x)
        with torch.no_grad():
            parts = [
                self.value_torch(tt[i : i + self.chunk_size], xt[i : i + self.chunk_size])
                for i in range(0, xt.shape[0], self.chunk_size)
            ]
        return self._finish(torch.cat(parts), is_numpy, single)

    def value_and_gradient(self, tau: ArrayLike, x: ArrayLike) -> tuple[Any, Any]:
        """``(V (B,), ∇ₓV (B, n))``; the gradient includes the symmetry chain rule."""
        tt, xt, is_numpy, single = self._prepare(tau, x)
        values, grads = [], []
        for i in range(0, xt.shape[0], self.chunk_size):
            xc = xt[i : i + self.chunk_size].detach().requires_grad_(True)
            with torch.enable_grad():
                v = self.value_torch(tt[i : i + self.chunk_size], xc)
                (g,) = torch.autograd.grad(v.sum(), xc)
            values.append(v.detach())
            grads.append(g)
        return (
            self._finish(torch.cat(values), is_numpy, single),
            self._finish(torch.cat(grads), is_numpy, single),
        )

    def gradient(self, tau: ArrayLike, x: ArrayLike) -> Any:
        """``∇ₓV(τ, x)``, shape ``(B, n)``; time is never mapped by the symmetry."""
        return self.value_and_gradient(tau, x)[1]
