"""Map a pair of arms of a cell into the frame of a trained pair model.

A pair model is trained with the controlled arm (robot 1) at the origin and the other arm
(robot 2) at a fixed relative pose ``M = T_1_2``. In a cell, the relative pose of a peer seen
from the planning arm is ``T_own⁻¹·T_peer``. When it equals ``Rz(φ)·M·Rz(ψ)`` (the same base
distance and height, turned about the own base by ``φ`` and about the peer base by ``ψ``), the
cell pair is the model pair with the own arm turned by ``−φ`` and the peer turned by ``ψ``
about their vertical base axes. For an arm whose first joint turns about its base's z axis
through the base origin (UR5, Kinova Gen3), that is a shift of the first joint:
``q¹₁ → q¹₁ − s¹·φ``, ``q²₁ → q²₁ + s²·ψ`` (``s = ±1``: the joint axis along ±z). Distances,
and so values, are unchanged by the rigid motion; gradients are unchanged by a shift. E.g. in
the three- and five-UR5 cells the centre arm's shift is 0, π or ±π/2 (as in the paper).

A model whose controlled arm is the *second* arm of a learned distance (``kinova_ur5``: the
Kinova at the origin, the UR5 at ``(0.6, 0, 0)`` facing it) has ``M = T_2_1``, the inverse of
the distance's base offset (:func:`inverse_pose`); in the UR5-Kinova cell both arms' pairs then
map with zero shifts.

A *conditioned* model (a fourth entry ``(r_low, r_high)``) serves every base distance ``r`` in
that range: its frame has robot 2 at ``base2`` moved by ``(r, 0, 0)``, and the mapping appends
``r`` to the pair state (:attr:`PairMapping.condition`). One model then serves any layout of
arms at the same mounting height.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.robots.model import ArmSpec, Cell, Pose, RobotModel, wrap_angle

__all__ = [
    "ModelGeometry",
    "PairMapping",
    "base_yaw_joint",
    "constrained_pairs",
    "inverse_pose",
    "match_pair",
    "pose_from_matrix",
    "relative_pose",
]

POSITION_TOL = 1e-6  # [m]
ANGLE_TOL = 1e-6  # [rad]


@dataclass(frozen=True)
class PairMapping:
    """How one (own arm, peer) pair of a cell maps into model ``model_index``'s frame."""

    model_index: int
    own_shift: np.ndarray  # (n1,) added to the own joint vector [rad]
    peer_shift: np.ndarray  # (n2,) added to the peer joint vector [rad]
    condition: np.ndarray = field(default_factory=lambda: np.zeros(0))  # appended (r [m])

    def state(self, q_own: np.ndarray, q_peer: np.ndarray) -> np.ndarray:
        """The pair state ``x`` (n1 + n2 [+ 1],) in the model frame."""
        return np.concatenate([q_own + self.own_shift, q_peer + self.peer_shift, self.condition])


def relative_pose(own: Pose, peer: Pose) -> np.ndarray:
    """``T_own_peer = T_world_own⁻¹ · T_world_peer`` (4, 4)."""
    return np.linalg.inv(own.matrix()) @ peer.matrix()


def pose_from_matrix(T: np.ndarray) -> Pose:
    """The :class:`Pose` (xyz, fixed-axis rpy) of a homogeneous transform ``T`` (4, 4)."""
    R = T[:3, :3]
    cos_pitch = math.hypot(R[0, 0], R[1, 0])
    pitch = math.atan2(-R[2, 0], cos_pitch)
    if cos_pitch > 1e-9:
        roll, yaw = math.atan2(R[2, 1], R[2, 2]), math.atan2(R[1, 0], R[0, 0])
    else:  # gimbal lock: only roll ∓ yaw is defined; put it all in yaw
        roll, yaw = 0.0, math.atan2(-R[0, 1], R[1, 1])
    xyz = (float(T[0, 3]), float(T[1, 3]), float(T[2, 3]))
    return Pose(xyz, (roll, pitch, yaw))


def inverse_pose(pose: Pose) -> Pose:
    """``T⁻¹`` of ``pose``: where the origin frame sits seen from ``pose``'s frame."""
    return pose_from_matrix(np.linalg.inv(pose.matrix()))


@functools.cache
def base_yaw_joint(robot: RobotModel) -> float | None:
    """``s`` if the first joint turns the arm about its base z axis by ``s·q₁`` (s = ±1), else None.

    Read from the robot's URDF chain (once per robot and process): the fixed transforms before
    the first joint must keep its axis on the base's z axis through the origin.
    """
    kin = ArmKinematics(robot)
    T = np.eye(4)
    for step in kin._steps:
        T = T @ step.T_parent_joint.double().numpy()
        if step.axis is None:
            continue
        if step.q_index != 0:
            return None
        axis = T[:3, :3] @ step.axis.double().numpy()
        if np.linalg.norm(T[:2, 3]) > POSITION_TOL or np.linalg.norm(axis[:2]) > ANGLE_TOL:
            return None
        return float(np.sign(axis[2]))
    return None


def _yaw_only(T: np.ndarray) -> float | None:
    """The yaw of ``T`` if its rotation is a pure rotation about z, else None."""
    R = T[:3, :3]
    if abs(R[2, 2] - 1.0) > ANGLE_TOL:
        return None
    return math.atan2(R[1, 0], R[0, 0])


def _shift(robot: RobotModel, sign: float, angle: float) -> np.ndarray:
    out = np.zeros(robot.dof)
    out[0] = sign * angle
    return out


ModelGeometry = tuple[str, str, Pose] | tuple[str, str, Pose, tuple[float, float] | None]
"""``(robot1, robot2, base2[, (r_low, r_high)])`` of a pair model; see the module docstring."""


def match_pair(own: ArmSpec, peer: ArmSpec, models: Sequence[ModelGeometry]) -> PairMapping | None:
    """The first model ``(robot1, robot2, base2[, range])`` the cell pair maps onto, or None."""
    T = relative_pose(own.base, peer.base)
    yaw = _yaw_only(T)
    s_own, s_peer = base_yaw_joint(own.robot), base_yaw_joint(peer.robot)
    for index, entry in enumerate(models):
        robot1, robot2, base2 = entry[:3]
        base_range = entry[3] if len(entry) > 3 else None
        if (robot1, robot2) != (own.robot.name, peer.robot.name):
            continue
        M = base2.matrix()
        condition = np.zeros(0)
        if base_range is not None:
            r_cell = float(np.linalg.norm(T[:2, 3]))
            if not base_range[0] <= r_cell <= base_range[1]:
                continue
            M = Pose((r_cell, 0.0, 0.0)).matrix() @ M
            condition = np.array([r_cell])
        yaw_m = _yaw_only(M)
        if np.allclose(T, M, atol=POSITION_TOL):
            return PairMapping(index, np.zeros(own.robot.dof), np.zeros(peer.robot.dof), condition)
        if yaw is None or yaw_m is None or s_own is None or s_peer is None:
            continue
        r, r_m = np.linalg.norm(T[:2, 3]), np.linalg.norm(M[:2, 3])
        if abs(r - r_m) > POSITION_TOL or abs(T[2, 3] - M[2, 3]) > POSITION_TOL:
            continue
        phi = math.atan2(T[1, 3], T[0, 3]) - math.atan2(M[1, 3], M[0, 3]) if r > 0 else 0.0
        psi = float(wrap_angle(yaw - yaw_m - phi))
        own_shift = _shift(own.robot, s_own, float(wrap_angle(-phi)))
        return PairMapping(index, own_shift, _shift(peer.robot, s_peer, psi), condition)
    return None


def constrained_pairs(
    cell: Cell, arm_id: str, models: Sequence[ModelGeometry], reach_margin: float
) -> tuple[dict[str, PairMapping], tuple[str, ...], tuple[str, ...]]:
    """``arm_id``'s peers sorted three ways: ``(pairs, skipped, unmodelled)``, the peers in reach
    with the mapping into the frame of a model that fits them, the peers that cannot touch the
    arm (:func:`~nehmo_core.pairs.reach.can_touch`, with ``reach_margin`` [m] added), and the
    peers in reach that no model fits."""
    from nehmo_core.pairs.reach import can_touch

    own = cell.arm(arm_id)
    pairs: dict[str, PairMapping] = {}
    skipped, unmodelled = [], []
    for peer in cell.arms:
        if peer.arm_id == arm_id:
            continue
        if not can_touch(own, peer, reach_margin):
            skipped.append(peer.arm_id)
            continue
        mapping = match_pair(own, peer, models)
        if mapping is None:
            unmodelled.append(peer.arm_id)
        else:
            pairs[peer.arm_id] = mapping
    return pairs, tuple(skipped), tuple(unmodelled)
