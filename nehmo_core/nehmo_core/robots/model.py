"""Typed robot and cell descriptions.

Joint vectors are ordered as the robot's ``joint_names`` (root to tip), in [rad]. Base poses are
given in the world frame: position [m] and roll/pitch/yaw [rad] (URDF convention, fixed axes).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from nehmo_core.errors import InvalidValueError, UnknownNameError

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class JointSpec:
    """One actuated joint: position limits [rad], velocity limit [rad/s], wrap-around flag.

    ``continuous`` is true for URDF ``continuous`` joints and for revolute joints whose range
    spans a full turn or more (the UR5's ±2π joints): their angles may be wrapped to (−π, π].
    """

    name: str
    lower: float
    upper: float
    velocity: float
    continuous: bool


LinkPoint = tuple[str, float, float, float]
"""``(link, x, y, z)``: a point fixed in a link's frame [m] (keypoints of learned distances)."""


@dataclass(frozen=True)
class RobotFacts:
    """What NeHMO knows about a robot beyond its URDF, from the robot registry
    (:mod:`nehmo_core.robots.registry`); a robot the registry does not know has none of them."""

    keypoints: tuple[str, ...] = ()
    """Links whose frame origins are the learned distance's keypoints, root to tip (empty: no
    keypoint set, so no learned distance); CHOMP's sphere chains run through them too."""
    keypoint_segments: tuple[tuple[str, str, int], ...] = ()
    """``(link a, link b, k)``: ``k`` more keypoints evenly between the two links' origins."""
    keypoint_points: tuple[LinkPoint, ...] = ()
    """``(link, x, y, z)``: more keypoints fixed in a link's frame [m] (e.g. a hand's sides,
    which no link origin on the flange axis sees)."""
    sphere_radius: float = 0.08
    """[m] Radius of CHOMP's body spheres, covering each link's section."""
    sampling_ranges: tuple[tuple[float, float], ...] | None = None
    """``(low, high)`` [rad] per joint of the evaluation protocol's start/goal draws (None: the
    joint limits clipped to ±π)."""
    reach_m: float | None = None
    """[m] Horizontal reach of the collision geometry from the base axis
    (:func:`~nehmo_core.pairs.reach.horizontal_reach`; None: measured when needed)."""
    accel_limits: tuple[float, ...] | None = None
    """[rad/s²] Each joint's acceleration limit, for the ``realistic`` actuator model
    (:mod:`nehmo_core.sim.actuators`; None: not known)."""
    accel_source: str = ""
    """Where ``accel_limits`` come from (a document, a vendor library)."""


@dataclass(frozen=True)
class RobotModel:
    """A fixed-base serial arm described by one URDF (the single source of truth) and the
    registry's :class:`RobotFacts` about it."""

    name: str
    urdf_path: Path
    root_link: str
    tip_link: str
    joints: tuple[JointSpec, ...]
    links: tuple[str, ...]
    """Links with collision geometry, root to tip."""
    disabled_collision_pairs: frozenset[frozenset[str]] = field(default_factory=frozenset)
    """Link pairs excluded from self-collision checks (SRDF ``disable_collisions``)."""
    facts: RobotFacts = field(default_factory=RobotFacts)
    """Keypoints, CHOMP sphere radius and scenario sampling ranges (see :class:`RobotFacts`)."""

    @property
    def dof(self) -> int:
        return len(self.joints)

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def lower(self) -> FloatArray:
        return np.array([j.lower for j in self.joints])

    @property
    def upper(self) -> FloatArray:
        return np.array([j.upper for j in self.joints])

    @property
    def continuous(self) -> NDArray[np.bool_]:
        return np.array([j.continuous for j in self.joints])

    def self_collision_pairs(self) -> list[tuple[str, str]]:
        """Link pairs checked for self-collision.

        All pairs of collision links minus the SRDF-disabled ones and minus links adjacent in
        the chain (they touch at their joint by design).
        """
        pairs = []
        for i, a in enumerate(self.links):
            for b in self.links[i + 2 :]:
                if frozenset((a, b)) not in self.disabled_collision_pairs:
                    pairs.append((a, b))
        return pairs

    def check_q(self, q: ArrayLike, parameter: str = "q") -> FloatArray:
        """Validate a joint vector (or a batch ``(B, dof)``) and return it as float64.

        Raises :class:`InvalidValueError` naming ``parameter`` on a wrong length or a
        non-finite entry.
        """
        arr = np.asarray(q, dtype=np.float64)
        if arr.ndim == 0 or arr.shape[-1] != self.dof:
            raise InvalidValueError(
                parameter,
                f"must have {self.dof} joint values for robot '{self.name}' "
                f"(joints {list(self.joint_names)})",
                arr.shape if arr.ndim != 1 else arr.tolist(),
            )
        if not np.all(np.isfinite(arr)):
            raise InvalidValueError(parameter, "must be finite (no NaN or inf)", arr.tolist())
        return arr

    def check_within_limits(self, q: ArrayLike, parameter: str = "q") -> FloatArray:
        """Like :meth:`check_q`, and also require every joint within its position limits."""
        arr = self.check_q(q, parameter)
        bad = (arr < self.lower - 1e-9) | (arr > self.upper + 1e-9)
        if np.any(bad):
            idx = [int(i) for i in np.flatnonzero(bad.reshape(-1, self.dof).any(axis=0))]
            detail = ", ".join(
                f"{self.joints[i].name} in [{self.joints[i].lower:.4g}, {self.joints[i].upper:.4g}]"
                for i in idx
            )
            raise InvalidValueError(
                parameter, f"must respect joint limits ({detail})", arr.tolist()
            )
        return arr

    def joint_state(
        self, names: Sequence[str], position: Sequence[float], parameter: str
    ) -> FloatArray:
        """Positions of a JointState in this robot's joint order, checked: by ``names`` when
        given (each joint once, one position per name), else as they come; ``dof`` finite
        values. The rule every reader of joint states applies (the planners' state buffer,
        goals, the episode-log reader); raises :class:`InvalidValueError` naming
        ``parameter``."""
        values = np.asarray(list(position), dtype=np.float64)
        if names:
            names = list(names)
            if len(values) == len(names) and names == list(self.joint_names):
                return self.check_q(values, parameter)  # in the robot's order already
            if sorted(names) != sorted(self.joint_names) or len(values) != len(names):
                raise InvalidValueError(
                    parameter,
                    f"must name the joints of robot '{self.name}' {list(self.joint_names)} "
                    "once each, with one position per name",
                    {"name": names, "position": values.tolist()},
                )
            values = values[[names.index(j) for j in self.joint_names]]
        return self.check_q(values, parameter)

    def wrap(self, q: ArrayLike) -> FloatArray:
        """Wrap continuous joints to (−π, π]; other joints unchanged."""
        arr = np.array(q, dtype=np.float64)
        c = self.continuous
        arr[..., c] = wrap_angle(arr[..., c])
        return arr


def wrap_angle(a: ArrayLike) -> FloatArray:
    """Wrap angles [rad] to (−π, π]."""
    x = np.asarray(a, dtype=np.float64)
    return np.pi - np.mod(np.pi - x, 2.0 * np.pi)


@dataclass(frozen=True)
class Pose:
    """A rigid pose in the world frame: ``xyz`` [m] and fixed-axis ``rpy`` [rad]."""

    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)

    @property
    def yaw(self) -> float:
        return self.rpy[2]

    def matrix(self) -> FloatArray:
        """Homogeneous transform ``T_world_base`` (4, 4)."""
        r, p, y = self.rpy
        cr, sr, cp, sp, cy, sy = (
            math.cos(r),
            math.sin(r),
            math.cos(p),
            math.sin(p),
            math.cos(y),
            math.sin(y),
        )
        rot = np.array(
            [
                [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                [-sp, cp * sr, cp * cr],
            ]
        )
        out = np.eye(4)
        out[:3, :3] = rot
        out[:3, 3] = self.xyz
        return out


@dataclass(frozen=True)
class ArmSpec:
    """One arm of a cell: its id (ROS namespace), robot model and base pose."""

    arm_id: str
    robot: RobotModel
    base: Pose


@dataclass(frozen=True)
class Cell:
    """A work cell: several arms sharing a workspace."""

    name: str
    arms: tuple[ArmSpec, ...]

    @property
    def arm_ids(self) -> tuple[str, ...]:
        return tuple(a.arm_id for a in self.arms)

    def arm(self, arm_id: str) -> ArmSpec:
        for a in self.arms:
            if a.arm_id == arm_id:
                return a
        raise UnknownNameError("arm", arm_id, self.arm_ids)

    def index(self, arm_id: str) -> int:
        return self.arm_ids.index(self.arm(arm_id).arm_id)

    def pairs(self) -> list[tuple[str, str]]:
        """Every unordered pair of arm ids (collisions are checked among all of them)."""
        ids = self.arm_ids
        return [(a, b) for i, a in enumerate(ids) for b in ids[i + 1 :]]


def as_pose(xyz: Sequence[float], rpy: Sequence[float]) -> Pose:
    """Build a :class:`Pose` from sequences, checking their lengths."""
    if len(xyz) != 3:
        raise InvalidValueError("xyz", "must have 3 values [m]", list(xyz))
    if len(rpy) != 3:
        raise InvalidValueError("rpy", "must have 3 values [rad]", list(rpy))
    return Pose(
        (float(xyz[0]), float(xyz[1]), float(xyz[2])), (float(rpy[0]), float(rpy[1]), float(rpy[2]))
    )
