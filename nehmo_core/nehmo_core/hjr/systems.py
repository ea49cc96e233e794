"""HJI systems: dynamics, box-bounded inputs, closed-form Hamiltonian, boundary, symmetry.

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
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nehmo_core.errors import InvalidValueError, UnknownNameError

__all__ = [
    "Air3D",
    "ArmPairSystem",
    "HJISystem",
    "JointInterval",
    "TwoLinkDistance",
    "TwoLinkPair",
    "make_system",
    "register_system",
    "system_names",
    "wrap_to_pi",
]


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


# ------------------------------------------------------------------------------------------------
# Air3D
# ------------------------------------------------------------------------------------------------


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


# ------------------------------------------------------------------------------------------------
# Velocity-controlled arm pairs
# ------------------------------------------------------------------------------------------------


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

    State ``x = (q¹ ∈ R^{n1}, q² ∈ R^{n2})`` [rad] in ``[−π, π]^{n1+n2}``. The Hamiltonian is the
    L1 form ``H = ū‖∇_{q¹}V‖₁ − d̄‖∇_{q²}V‖₁`` (exact for box inputs).

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

    def __post_init__(self) -> None:
        for name in ("n1", "n2"):
            if int(getattr(self, name)) < 1:
                raise InvalidValueError(name, "must be >= 1", getattr(self, name))
        for name in ("u_max", "d_max", "horizon"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        n = self.n1 + self.n2
        sign = _as_vector(self.symmetry_sign, n, "symmetry_sign")
        if not np.all(np.abs(sign) == 1.0):
            raise InvalidValueError("symmetry_sign", "entries must be +1 or -1", sign.tolist())
        object.__setattr__(self, "symmetry_sign", sign)
        offset = _as_vector(self.symmetry_offset, n, "symmetry_offset")
        object.__setattr__(self, "symmetry_offset", offset)
        if self.train_region.joint >= n:
            raise InvalidValueError("train_region.joint", f"must be < {n}", self.train_region.joint)
        if self.joint_periodic is None:
            object.__setattr__(self, "joint_periodic", (True,) * n)
        elif len(self.joint_periodic) != n:
            raise InvalidValueError("joint_periodic", f"must have {n} entries", self.joint_periodic)
        if isinstance(self.boundary_fn, nn.Module):
            self.boundary_fn.requires_grad_(False)

    @property
    def name(self) -> str:
        return self.system_name

    @property
    def lower(self) -> np.ndarray:
        return -np.pi * np.ones(self.n1 + self.n2)

    @property
    def upper(self) -> np.ndarray:
        return np.pi * np.ones(self.n1 + self.n2)

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
        return {
            "n1": self.n1,
            "n2": self.n2,
            "u_max": self.u_max,
            "d_max": self.d_max,
            "horizon": self.horizon,
            "symmetry_sign": np.asarray(self.symmetry_sign).tolist(),
            "symmetry_offset": np.asarray(self.symmetry_offset).tolist(),
            "train_region": {"joint": region.joint, "low": region.low, "high": region.high},
            "joint_periodic": list(self.periodic),
        }

    def boundary(self, x: Tensor) -> Tensor:
        return self.boundary_fn(x)

    def dynamics(self, x: Tensor, u: Tensor, d: Tensor) -> Tensor:
        return torch.cat([u, d], dim=1)

    def hamiltonian(self, x: Tensor, p: Tensor) -> Tensor:
        p1, p2 = p[:, : self.n1], p[:, self.n1 :]
        return self.u_max * p1.abs().sum(dim=1) - self.d_max * p2.abs().sum(dim=1)

    def optimal_control(self, x: Tensor, p: Tensor) -> Tensor:
        return self.u_max * torch.sign(p[:, : self.n1])

    def worst_disturbance(self, x: Tensor, p: Tensor) -> Tensor:
        return -self.d_max * torch.sign(p[:, self.n1 :])

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


# ------------------------------------------------------------------------------------------------
# Two planar 2-link arms
# ------------------------------------------------------------------------------------------------


def _point_segment_distance(p: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """Distance from points ``p`` to segments ``[a, b]`` (all ``(B, 2)``), ``(B,)``."""
    ab = b - a
    t = ((p - a) * ab).sum(dim=1) / (ab * ab).sum(dim=1)
    closest = a + t.clamp(0.0, 1.0)[:, None] * ab
    squared = ((p - closest) ** 2).sum(dim=1)
    return torch.sqrt(squared.clamp_min(1e-18))  # clamp keeps the gradient finite on contact


def _cross(u: Tensor, v: Tensor) -> Tensor:
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def segment_distance(a: Tensor, b: Tensor, c: Tensor, d: Tensor) -> Tensor:
    """Exact distance between planar segments ``[a, b]`` and ``[c, d]`` (each ``(B, 2)``) [m].

    In the plane the distance is 0 if the segments cross, else the smallest of the four
    endpoint-to-segment distances. Differentiable almost everywhere.
    """
    endpoint = torch.stack(
        [
            _point_segment_distance(a, c, d),
            _point_segment_distance(b, c, d),
            _point_segment_distance(c, a, b),
            _point_segment_distance(d, a, b),
        ],
        dim=1,
    ).amin(dim=1)
    # a proper crossing: each segment's ends strictly on both sides of the other's line. Touching
    # (an end on the other segment) and collinear overlap show in the endpoint distances, so the
    # zero cases stay out (two collinear segments apart would otherwise count as crossing).
    s1 = _cross(b - a, c - a) * _cross(b - a, d - a)
    s2 = _cross(d - c, a - c) * _cross(d - c, b - c)
    crossing = (s1 < 0.0) & (s2 < 0.0)
    return torch.where(crossing, torch.zeros_like(endpoint), endpoint)


class TwoLinkDistance(nn.Module):
    """``l(q) = min segment-segment distance − margin`` for two planar 2-link arms [m].

    Arm 1 is based at the origin with yaw 0, arm 2 at ``base2`` with yaw ``yaw2``. Each link is a
    segment; the four link pairs across the arms are checked (links of one arm are not).
    Input ``(B, 4) = (q¹₁, q¹₂, q²₁, q²₂)`` [rad], output ``(B,)``.
    """

    def __init__(
        self,
        link_lengths: tuple[float, float] = (0.5, 0.5),
        base2: tuple[float, float] = (1.4, 0.0),
        yaw2: float = math.pi,
        margin: float = 0.1,
    ) -> None:
        super().__init__()
        self.link_lengths = (float(link_lengths[0]), float(link_lengths[1]))
        self.base2 = (float(base2[0]), float(base2[1]))
        self.yaw2 = float(yaw2)
        self.margin = float(margin)

    def arm_points(self, q: Tensor, base: tuple[float, float], yaw: float) -> list[Tensor]:
        """Base, elbow and tip of one arm, each ``(B, 2)`` [m], for joint angles ``q (B, 2)``."""
        l1, l2 = self.link_lengths
        a1 = q[:, 0] + yaw
        a2 = a1 + q[:, 1]
        origin = q.new_tensor(base).expand(q.shape[0], 2)
        elbow = origin + l1 * torch.stack([torch.cos(a1), torch.sin(a1)], dim=1)
        tip = elbow + l2 * torch.stack([torch.cos(a2), torch.sin(a2)], dim=1)
        return [origin, elbow, tip]

    def forward(self, x: Tensor) -> Tensor:
        p = self.arm_points(x[:, :2], (0.0, 0.0), 0.0)
        r = self.arm_points(x[:, 2:4], self.base2, self.yaw2)
        pairs = [
            segment_distance(p[i], p[i + 1], r[j], r[j + 1]) for i in range(2) for j in range(2)
        ]
        return torch.stack(pairs, dim=1).amin(dim=1) - self.margin


@dataclass(frozen=True, eq=False)
class TwoLinkPair(ArmPairSystem):
    """The paper's "simple arm" pair: two planar 2-link arms, the authors' setting.

    Links 0.5 + 0.5 m, second base at (1.4, 0) with yaw π, ``q ∈ [−π, π]⁴``, ``T = 0.6`` s,
    ``ū = d̄ = 0.5`` rad/s, ``l = min segment distance − 0.1`` m. Symmetry ``q -> −q`` (the mirror
    across the line through both bases), ``X_train = {q²₂ ≥ 0}``.
    """

    boundary_fn: Callable[[Tensor], Tensor] = field(default_factory=TwoLinkDistance)
    n1: int = 2
    n2: int = 2
    symmetry_sign: Any = field(default_factory=lambda: -np.ones(4))
    symmetry_offset: Any = field(default_factory=lambda: np.zeros(4))
    train_region: JointInterval = field(default_factory=lambda: JointInterval(3, 0.0, math.pi))
    system_name: str = "two_link"


# ------------------------------------------------------------------------------------------------
# Registry
# ------------------------------------------------------------------------------------------------

_REGISTRY: dict[str, Callable[[], HJISystem]] = {"air3d": Air3D, "two_link": TwoLinkPair}


def register_system(name: str, factory: Callable[[], HJISystem]) -> None:
    """Make ``make_system(name)`` build systems with ``factory`` (e.g. the UR5 pairs)."""
    _REGISTRY[name] = factory


def system_names() -> list[str]:
    """Names accepted by :func:`make_system`."""
    return sorted(_REGISTRY)


def make_system(name: str) -> HJISystem:
    """Build a registered system by name; unknown names raise :class:`UnknownNameError`."""
    if name not in _REGISTRY:
        raise UnknownNameError("system", name, _REGISTRY)
    return _REGISTRY[name]()
