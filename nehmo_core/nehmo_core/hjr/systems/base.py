"""The HJI system interface: dynamics, box-bounded inputs, Hamiltonian, boundary, symmetry.

Conventions (used by every module of :mod:`nehmo_core.hjr`):

- Time is *time-to-go* ``τ ∈ [0, T]`` [s]. The avoid value function satisfies ``V(0, x) = l(x)``
  and the backward-reachable-tube HJI PDE ``∂V/∂τ − min(0, H(x, ∇ₓV)) = 0``, so ``V`` is
  non-increasing in ``τ``. ``{x | V(τ, x) ≤ 0}`` is the set of states from which the
  disturbance can force ``l ≤ 0`` within ``τ`` seconds.
- ``H(x, p) = max_u min_d <p, g(x, u, d)>``: the control *maximizes* (avoids), the disturbance
  (the other agent) *minimizes*.
- States are torch tensors of shape ``(B, n)``; scalar fields are ``(B,)``.
- Symmetry: a bijection ``f`` with ``l(f(x)) = l(x)`` and ``H(x, p) = H(f(x), Df⁻ᵀ p)``.
  ``X_train`` is the set where :meth:`HJISystem.in_train` holds and ``X_sym = f(X_train)``;
  :meth:`HJISystem.fold` maps any state into ``X_train`` (``x`` itself or ``f⁻¹(x)``).
  ``f`` never touches time.
"""

from __future__ import annotations

import abc
import math
from typing import Any

import numpy as np
import torch
from torch import Tensor

from nehmo_core.errors import InvalidValueError

__all__ = ["HJISystem", "wrap_to_pi"]


def wrap_to_pi(angle: Tensor) -> Tensor:
    """Wrap angles [rad] to ``(−π, π]`` (derivative 1 almost everywhere)."""
    return math.pi - torch.remainder(math.pi - angle, 2.0 * math.pi)


def _box_corners(lower: np.ndarray, upper: np.ndarray) -> np.ndarray:
    """All ``2^m`` corners of a box, shape ``(2^m, m)``."""
    m = lower.shape[0]
    bits = (np.arange(2**m)[:, None] >> np.arange(m)[None, :]) & 1
    return np.where(bits == 1, upper[None, :], lower[None, :])


class HJISystem(abc.ABC):
    """Base of every HJI system: a two-player game ``ẋ = g(x, u, d)`` with box inputs.

    Subclasses are frozen dataclasses. The value may be trained in normalized units
    ``W = (V − value_mean) · value_scale`` (``value_scale > 0``); the PDE is unchanged by such a
    positive affine map because ``H`` is positively 1-homogeneous in ``p``.
    """

    horizon: float  # T [s]
    value_mean: float = 0.0
    value_scale: float = 1.0

    # -- description -----------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def name(self) -> str:
        """Registry name of the system (e.g. ``"air3d"``)."""

    @property
    @abc.abstractmethod
    def lower(self) -> np.ndarray:
        """Lower corner of the state domain, shape ``(n,)``."""

    @property
    @abc.abstractmethod
    def upper(self) -> np.ndarray:
        """Upper corner of the state domain, shape ``(n,)``."""

    @property
    @abc.abstractmethod
    def periodic(self) -> tuple[bool, ...]:
        """Per state dimension: is ``[lower, upper]`` exactly one period (wrap-around)?"""

    @property
    @abc.abstractmethod
    def control_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` of the control box, each ``(m,)``."""

    @property
    @abc.abstractmethod
    def disturbance_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """``(lower, upper)`` of the disturbance box, each ``(k,)``."""

    @abc.abstractmethod
    def parameters(self) -> dict[str, Any]:
        """JSON-serializable parameters that define the system (for model sidecars)."""

    @property
    def state_dim(self) -> int:
        """Number of state dimensions ``n``."""
        return int(self.lower.shape[0])

    def describe(self) -> dict[str, Any]:
        """Name and parameters, as stored next to trained models."""
        return {"name": self.name, "parameters": self.parameters()}

    # -- the game -------------------------------------------------------------------------------
    @abc.abstractmethod
    def boundary(self, x: Tensor) -> Tensor:
        """``l(x)`` in physical units, ``(B, n) -> (B,)``; ``l ≤ 0`` is the failure set."""

    @abc.abstractmethod
    def dynamics(self, x: Tensor, u: Tensor, d: Tensor) -> Tensor:
        """``g(x, u, d)``: ``(B, n), (B, m), (B, k) -> (B, n)``."""

    @abc.abstractmethod
    def hamiltonian(self, x: Tensor, p: Tensor) -> Tensor:
        """Closed-form ``max_u min_d <p, g(x, u, d)>``: ``(B, n), (B, n) -> (B,)``."""

    @abc.abstractmethod
    def optimal_control(self, x: Tensor, p: Tensor) -> Tensor:
        """The maximizing control, ``(B, m)``."""

    @abc.abstractmethod
    def worst_disturbance(self, x: Tensor, p: Tensor) -> Tensor:
        """The minimizing disturbance, ``(B, k)``."""

    # -- symmetry -------------------------------------------------------------------------------
    @abc.abstractmethod
    def symmetry(self, x: Tensor) -> Tensor:
        """``f(x)``, mapping ``X_train`` onto ``X_sym``: ``(B, n) -> (B, n)``."""

    @abc.abstractmethod
    def symmetry_inverse(self, x: Tensor) -> Tensor:
        """``f⁻¹(x)``: ``(B, n) -> (B, n)``."""

    @abc.abstractmethod
    def symmetry_jacobian(self, x: Tensor) -> Tensor:
        """``Df(x)``, shape ``(B, n, n)``."""

    @abc.abstractmethod
    def in_train(self, x: Tensor) -> Tensor:
        """Boolean mask ``(B,)`` of states in ``X_train``."""

    def fold(self, x: Tensor) -> Tensor:
        """Map every state into ``X_train``: ``x`` if ``x ∈ X_train`` else ``f⁻¹(x)``."""
        keep = self.in_train(x)[:, None]
        return torch.where(keep, x, self.symmetry_inverse(x))

    # -- helpers --------------------------------------------------------------------------------
    def sample_states(self, count: int, generator: torch.Generator) -> Tensor:
        """``count`` states uniform in the domain, float32 ``(count, n)``."""
        lo = torch.as_tensor(self.lower, dtype=torch.float32)
        hi = torch.as_tensor(self.upper, dtype=torch.float32)
        return lo + (hi - lo) * torch.rand(count, self.state_dim, generator=generator)

    def check_states(self, x: Tensor, parameter: str = "x") -> None:
        """Raise :class:`InvalidValueError` unless ``x`` has shape ``(B, n)``."""
        if x.ndim != 2 or x.shape[1] != self.state_dim:
            raise InvalidValueError(
                parameter, f"must have shape (B, {self.state_dim})", tuple(x.shape)
            )

    def brute_force_hamiltonian(self, x: Tensor, p: Tensor) -> Tensor:
        """Slow reference: ``max_u min_d <p, g>`` over the corners of both boxes, ``(B,)``."""
        u_all = torch.as_tensor(_box_corners(*self.control_bounds), dtype=x.dtype)
        d_all = torch.as_tensor(_box_corners(*self.disturbance_bounds), dtype=x.dtype)
        batch = x.shape[0]
        best = torch.full((batch,), -math.inf, dtype=x.dtype)
        for u in u_all:
            worst = torch.full((batch,), math.inf, dtype=x.dtype)
            for d in d_all:
                g = self.dynamics(x, u.expand(batch, -1), d.expand(batch, -1))
                worst = torch.minimum(worst, (p * g).sum(dim=1))
            best = torch.maximum(best, worst)
        return best
