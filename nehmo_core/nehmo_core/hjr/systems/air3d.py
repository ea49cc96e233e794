"""Air3D: two Dubins cars in relative coordinates (DeepReach's normalized benchmark)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor

from nehmo_core.errors import InvalidValueError
from nehmo_core.hjr.systems.base import HJISystem

__all__ = ["Air3D"]


@dataclass(frozen=True, eq=False)
class Air3D(HJISystem):
    """Two Dubins cars in relative coordinates, in DeepReach's normalized setting.

    State ``x = (x1, x2, x3) ∈ [−1, 1]³``: relative position ``(x1, x2)`` [m] and scaled relative
    heading ``x3 = θ / angle_scale`` (``θ = 1.2π·x3`` [rad], so the domain spans 1.2 turns and is
    *not* wrapped). Control: evader turn rate ``ω_e``, disturbance: pursuer turn rate ``ω_p``,
    both in ``[−ω_max, ω_max]`` [rad/s]::

        ẋ1 = −v + v cos θ + ω_e x2,   ẋ2 = v sin θ − ω_e x1,   ẋ3 = (ω_p − ω_e) / angle_scale

    ``l(x) = ‖(x1, x2)‖ − collision_radius``.

    Value normalization, as DeepReach trains it: the network represents
    ``W = (V − 0.25) · 0.02 / 0.5`` (``value_mean = 0.25``, ``value_scale = 0.04``), i.e.
    ``W(0, x) = (l(x) − 0.25)·0.04``. Only the value is rescaled (positions are already in
    ``[−1, 1]``; heading via ``angle_scale``); the PDE for ``W`` is the PDE for ``V`` because ``H``
    is 1-homogeneous in ``p``. Note the zero level set of ``V`` is ``W = −0.01``, not ``W = 0``:
    always decide safety on the de-normalized ``V`` (``ValueFunction`` returns ``V``).
    """

    velocity: float = 0.75  # v [m/s], both cars
    omega_max: float = 3.0  # ω̄ [rad/s], both cars
    angle_scale: float = 1.2 * math.pi  # θ = angle_scale · x3
    collision_radius: float = 0.25  # [m]
    horizon: float = 1.1  # T [s]
    value_mean: float = 0.25
    value_scale: float = 0.02 / 0.5

    def __post_init__(self) -> None:
        for name in ("velocity", "omega_max", "angle_scale", "horizon", "value_scale"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))

    @property
    def name(self) -> str:
        return "air3d"

    @property
    def lower(self) -> np.ndarray:
        return -np.ones(3)

    @property
    def upper(self) -> np.ndarray:
        return np.ones(3)

    @property
    def periodic(self) -> tuple[bool, ...]:
        return (False, False, False)

    @property
    def control_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array([-self.omega_max]), np.array([self.omega_max])

    @property
    def disturbance_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return np.array([-self.omega_max]), np.array([self.omega_max])

    def parameters(self) -> dict[str, Any]:
        return {
            "velocity": self.velocity,
            "omega_max": self.omega_max,
            "angle_scale": self.angle_scale,
            "collision_radius": self.collision_radius,
            "horizon": self.horizon,
            "value_mean": self.value_mean,
            "value_scale": self.value_scale,
        }

    def boundary(self, x: Tensor) -> Tensor:
        return torch.linalg.vector_norm(x[:, :2], dim=1) - self.collision_radius

    def dynamics(self, x: Tensor, u: Tensor, d: Tensor) -> Tensor:
        theta = self.angle_scale * x[:, 2]
        v, w_e, w_p = self.velocity, u[:, 0], d[:, 0]
        dx1 = -v + v * torch.cos(theta) + w_e * x[:, 1]
        dx2 = v * torch.sin(theta) - w_e * x[:, 0]
        dx3 = (w_p - w_e) / self.angle_scale
        return torch.stack([dx1, dx2, dx3], dim=1)

    def _control_switch(self, x: Tensor, p: Tensor) -> Tensor:
        """``∂<p, g>/∂ω_e``, the coefficient of the control in ``<p, g>``, ``(B,)``."""
        return p[:, 0] * x[:, 1] - p[:, 1] * x[:, 0] - p[:, 2] / self.angle_scale

    def hamiltonian(self, x: Tensor, p: Tensor) -> Tensor:
        theta = self.angle_scale * x[:, 2]
        v, w = self.velocity, self.omega_max
        drift = v * (torch.cos(theta) - 1.0) * p[:, 0] + v * torch.sin(theta) * p[:, 1]
        control = w * torch.abs(self._control_switch(x, p))
        disturbance = -w * torch.abs(p[:, 2] / self.angle_scale)
        return drift + control + disturbance

    def optimal_control(self, x: Tensor, p: Tensor) -> Tensor:
        return (self.omega_max * torch.sign(self._control_switch(x, p)))[:, None]

    def worst_disturbance(self, x: Tensor, p: Tensor) -> Tensor:
        return (-self.omega_max * torch.sign(p[:, 2]))[:, None]

    def symmetry(self, x: Tensor) -> Tensor:
        return x * x.new_tensor([1.0, -1.0, -1.0])

    def symmetry_inverse(self, x: Tensor) -> Tensor:
        return self.symmetry(x)

    def symmetry_jacobian(self, x: Tensor) -> Tensor:
        jac = torch.diag(x.new_tensor([1.0, -1.0, -1.0]))
        return jac.expand(x.shape[0], 3, 3)

    def in_train(self, x: Tensor) -> Tensor:
        return x[:, 2] >= 0.0
