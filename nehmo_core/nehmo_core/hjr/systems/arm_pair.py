"""ArmPairSystem: two velocity-controlled arms, the generic 12-D (or 4-D) pair game."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nehmo_core.errors import InvalidValueError
from nehmo_core.hjr.systems.base import HJISystem, wrap_to_pi

__all__ = ["ArmPairSystem", "JointInterval"]


@dataclass(frozen=True)
class JointInterval:
    """Train predicate "joint ``joint`` of the stacked state lies in ``[low, high]``" [rad].

    ``joint`` indexes the pair state ``(q¹, q²)``; e.g. joint 1 of arm 2 in a 2+2 pair is 3.
    On periodic joints the coordinate is wrapped to ``(−π, π]`` before the test.
    """

    joint: int
    low: float
    high: float

    def __post_init__(self) -> None:
        if self.joint < 0:
            raise InvalidValueError("joint", "must be >= 0", self.joint)
        if not self.low <= self.high:
            raise InvalidValueError("high", f"must be >= low ({self.low})", self.high)

    def contains(self, x: Tensor, periodic: bool) -> Tensor:
        """Mask ``(B,)`` of states whose joint lies in the interval."""
        q = x[:, self.joint]
        if periodic:
            q = wrap_to_pi(q)
        return (q >= self.low) & (q <= self.high)


def _as_vector(values: Any, size: int, parameter: str) -> np.ndarray:
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    if array.shape[0] != size:
        raise InvalidValueError(parameter, f"must have {size} entries", array.tolist())
    return array


@dataclass(frozen=True, eq=False)
class ArmPairSystem(HJISystem):
    """Two velocity-controlled arms: ``q̇¹ = u``, ``q̇² = d``, ``|uⱼ| ≤ ū``, ``|dⱼ| ≤ d̄`` [rad/s].

    State ``x = (q¹ ∈ R^{n1}, q² ∈ R^{n2})`` [rad] in ``[−π, π]^{n1+n2}``, followed by one
    constant coordinate per entry of ``conditions`` (e.g. the base distance ``r`` [m] of a
    pose-conditioned pair, in its ``(low, high)`` range; ``ṙ = 0``, never wrapped, unchanged by
    the symmetry). The Hamiltonian is the L1 form ``H = ū‖∇_{q¹}V‖₁ − d̄‖∇_{q²}V‖₁`` (exact for
    box inputs).

    ``boundary_fn`` maps ``(B, n1+n2) -> (B,)`` (e.g. a frozen distance network); its parameters
    are frozen (``requires_grad_(False)``) when it is a module. Symmetry ``f(q) = sign·q + offset``
    per joint, wrapped to ``(−π, π]`` on periodic joints; ``train_region`` defines ``X_train``.
    """

    boundary_fn: Callable[[Tensor], Tensor]
    n1: int
    n2: int
    symmetry_sign: Any  # (n1+n2,) entries ±1
    symmetry_offset: Any  # (n1+n2,) [rad]
    train_region: JointInterval
    u_max: float = 0.5  # ū [rad/s]
    d_max: float = 0.5  # d̄ [rad/s]
    horizon: float = 0.6  # T [s]
    system_name: str = "arm_pair"
    joint_periodic: tuple[bool, ...] | None = None  # default: every joint periodic
    conditions: tuple[tuple[float, float], ...] = ()  # constant coordinates' (low, high)
    joint_box: tuple[tuple[float, float], ...] | None = None  # per joint (low, high); None: ±π

    def __post_init__(self) -> None:
        for name in ("n1", "n2"):
            if int(getattr(self, name)) < 1:
                raise InvalidValueError(name, "must be >= 1", getattr(self, name))
        for name in ("u_max", "d_max", "horizon"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        for low, high in self.conditions:
            if not low < high:
                raise InvalidValueError(
                    "conditions", "each (low, high) needs low < high", (low, high)
                )
        n = self.n1 + self.n2
        m = len(self.conditions)
        sign = _as_vector(self.symmetry_sign, n, "symmetry_sign")
        if not np.all(np.abs(sign) == 1.0):
            raise InvalidValueError("symmetry_sign", "entries must be +1 or -1", sign.tolist())
        object.__setattr__(self, "symmetry_sign", np.concatenate([sign, np.ones(m)]))
        offset = _as_vector(self.symmetry_offset, n, "symmetry_offset")
        object.__setattr__(self, "symmetry_offset", np.concatenate([offset, np.zeros(m)]))
        if self.train_region.joint >= n:
            raise InvalidValueError("train_region.joint", f"must be < {n}", self.train_region.joint)
        if self.joint_periodic is None:
            object.__setattr__(self, "joint_periodic", (True,) * n + (False,) * m)
        elif len(self.joint_periodic) != n:
            raise InvalidValueError("joint_periodic", f"must have {n} entries", self.joint_periodic)
        else:
            object.__setattr__(self, "joint_periodic", tuple(self.joint_periodic) + (False,) * m)
        if self.joint_box is not None:
            if len(self.joint_box) != n or any(not lo < hi for lo, hi in self.joint_box):
                raise InvalidValueError(
                    "joint_box", f"must be {n} pairs (low, high) with low < high", self.joint_box
                )
            object.__setattr__(
                self, "joint_box", tuple((float(lo), float(hi)) for lo, hi in self.joint_box)
            )
        if isinstance(self.boundary_fn, nn.Module):
            self.boundary_fn.requires_grad_(False)

    @property
    def name(self) -> str:
        return self.system_name

    @property
    def lower(self) -> np.ndarray:
        low = [c[0] for c in self.conditions]
        if self.joint_box is not None:
            return np.array([b[0] for b in self.joint_box] + low)
        return np.concatenate([-np.pi * np.ones(self.n1 + self.n2), low])

    @property
    def upper(self) -> np.ndarray:
        high = [c[1] for c in self.conditions]
        if self.joint_box is not None:
            return np.array([b[1] for b in self.joint_box] + high)
        return np.concatenate([np.pi * np.ones(self.n1 + self.n2), high])

    @property
    def periodic(self) -> tuple[bool, ...]:
        assert self.joint_periodic is not None  # set in __post_init__
        return self.joint_periodic

    @property
    def control_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return -self.u_max * np.ones(self.n1), self.u_max * np.ones(self.n1)

    @property
    def disturbance_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        return -self.d_max * np.ones(self.n2), self.d_max * np.ones(self.n2)

    def parameters(self) -> dict[str, Any]:
        region = self.train_region
        n = self.n1 + self.n2
        conditions = {"conditions": [list(c) for c in self.conditions]} if self.conditions else {}
        return {
            **conditions,
            "n1": self.n1,
            "n2": self.n2,
            "u_max": self.u_max,
            "d_max": self.d_max,
            "horizon": self.horizon,
            "symmetry_sign": np.asarray(self.symmetry_sign)[:n].tolist(),
            "symmetry_offset": np.asarray(self.symmetry_offset)[:n].tolist(),
            "train_region": {"joint": region.joint, "low": region.low, "high": region.high},
            "joint_periodic": list(self.periodic)[:n],
            **({"joint_box": [list(b) for b in self.joint_box]} if self.joint_box else {}),
        }

    def boundary(self, x: Tensor) -> Tensor:
        return self.boundary_fn(x)

    def dynamics(self, x: Tensor, u: Tensor, d: Tensor) -> Tensor:
        still = x.new_zeros(x.shape[0], len(self.conditions))
        return torch.cat([u, d, still], dim=1)

    def hamiltonian(self, x: Tensor, p: Tensor) -> Tensor:
        p1, p2 = p[:, : self.n1], p[:, self.n1 : self.n1 + self.n2]
        return self.u_max * p1.abs().sum(dim=1) - self.d_max * p2.abs().sum(dim=1)

    def optimal_control(self, x: Tensor, p: Tensor) -> Tensor:
        return self.u_max * torch.sign(p[:, : self.n1])

    def worst_disturbance(self, x: Tensor, p: Tensor) -> Tensor:
        return -self.d_max * torch.sign(p[:, self.n1 : self.n1 + self.n2])

    def _wrap_periodic(self, x: Tensor) -> Tensor:
        mask = torch.as_tensor(self.periodic, dtype=torch.bool)
        return torch.where(mask, wrap_to_pi(x), x)

    def symmetry(self, x: Tensor) -> Tensor:
        sign = x.new_tensor(self.symmetry_sign)
        return self._wrap_periodic(sign * x + x.new_tensor(self.symmetry_offset))

    def symmetry_inverse(self, x: Tensor) -> Tensor:
        sign = x.new_tensor(self.symmetry_sign)
        return self._wrap_periodic(sign * (x - x.new_tensor(self.symmetry_offset)))

    def symmetry_jacobian(self, x: Tensor) -> Tensor:
        n = self.state_dim
        return torch.diag(x.new_tensor(self.symmetry_sign)).expand(x.shape[0], n, n)

    def in_train(self, x: Tensor) -> Tensor:
        return self.train_region.contains(x, self.periodic[self.train_region.joint])
