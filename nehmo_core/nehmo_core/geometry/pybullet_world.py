"""A PyBullet world of one cell: exact signed distances and collision checks.

Each :class:`CellWorld` owns its own PyBullet client (``DIRECT``, no GUI), so several can live
in one process (e.g. one per worker). Collision geometry is what the URDFs declare: the UR5's
meshes (PyBullet uses their convex hulls) and the Kinova's primitive shapes. Distances are in
[m]; negative values are penetration depths.
"""

from __future__ import annotations

import itertools
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import pybullet as pb
from numpy.typing import ArrayLike

from nehmo_core.errors import ModelFileError
from nehmo_core.robots.model import ArmSpec, Cell, Pose

DEFAULT_CUTOFF = 3.0
"""Distances beyond this [m] are not resolved: the query reports the cutoff instead."""


@dataclass(frozen=True)
class Collision:
    """One collision found by :meth:`CellWorld.collisions`."""

    arm_a: str
    link_a: str
    arm_b: str
    link_b: str
    distance: float  # [m], <= 0


class CellWorld:
    """PyBullet bodies for every arm of a cell, posed by :meth:`set_joint_positions`."""

    def __init__(self, cell: Cell) -> None:
        self.cell = cell
        self.client = pb.connect(pb.DIRECT)
        self._body: dict[str, int] = {}
        self._joint_index: dict[str, list[int]] = {}
        self._link_index: dict[str, dict[str, int]] = {}
        for arm in cell.arms:
            self._load(arm)
        self._q = {a.arm_id: np.zeros(a.robot.dof) for a in cell.arms}

    def _load(self, arm: ArmSpec) -> None:
        quat = pb.getQuaternionFromEuler(arm.base.rpy)
        try:
            body = pb.loadURDF(
                str(arm.robot.urdf_path),
                basePosition=arm.base.xyz,
                baseOrientation=quat,
                useFixedBase=True,
                # exact cylinders (the Kinova's primitives) instead of polygon approximations
                flags=pb.URDF_USE_IMPLICIT_CYLINDER,
                physicsClientId=self.client,
            )
        except pb.error as exc:
            raise ModelFileError(f"PyBullet could not load {arm.robot.urdf_path}: {exc}") from exc
        links = {pb.getBodyInfo(body, physicsClientId=self.client)[0].decode(): -1}
        joints: dict[str, int] = {}
        for j in range(pb.getNumJoints(body, physicsClientId=self.client)):
            info = pb.getJointInfo(body, j, physicsClientId=self.client)
            joints[info[1].decode()] = j
            links[info[12].decode()] = j
        self._body[arm.arm_id] = body
        self._joint_index[arm.arm_id] = [joints[n] for n in arm.robot.joint_names]
        self._link_index[arm.arm_id] = links

    def close(self) -> None:
        if self.client >= 0 and pb.isConnected(self.client):
            pb.disconnect(self.client)
        self.client = -1

    def __enter__(self) -> CellWorld:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def body(self, arm_id: str) -> int:
        self.cell.arm(arm_id)  # raises with the valid ids
        return self._body[arm_id]

    def link_index(self, arm_id: str, link: str) -> int:
        return self._link_index[arm_id][link]

    def joint_indices(self, arm_id: str) -> list[int]:
        """PyBullet joint index of each of the arm's joints, in the robot's joint order."""
        return list(self._joint_index[self.cell.arm(arm_id).arm_id])

    def set_joint_positions(self, arm_id: str, q: ArrayLike) -> None:
        """Pose one arm; ``q`` [rad] in the robot's joint order."""
        arm = self.cell.arm(arm_id)
        qv = arm.robot.check_q(q, f"q[{arm_id}]")
        targets = [[v] for v in qv.tolist()]  # one call for every joint (each has one DoF)
        pb.resetJointStatesMultiDof(
            self._body[arm_id], self._joint_index[arm_id], targets, physicsClientId=self.client
        )
        self._q[arm_id] = qv.copy()

    def _inertial(self, body: int) -> tuple[tuple[float, ...], tuple[float, ...]]:
        """The base link's inertial frame in its link frame: PyBullet poses bases by it (the
        Kinova's sits 8.4 cm above its link frame; the UR5's is the link frame)."""
        local = pb.getDynamicsInfo(body, -1, physicsClientId=self.client)[3:5]
        return local[0], local[1]

    def set_base_pose(self, arm_id: str, pose: Pose) -> None:
        """Move one arm's base link frame (the URDF frame, as the cell declares base poses) to
        ``pose`` (world frame); the cell keeps its declared pose."""
        body = self.body(arm_id)
        quat = pb.getQuaternionFromEuler(pose.rpy)
        com_pos, com_orn = pb.multiplyTransforms(pose.xyz, quat, *self._inertial(body))
        pb.resetBasePositionAndOrientation(body, com_pos, com_orn, physicsClientId=self.client)

    def base_link_frame(self, arm_id: str) -> np.ndarray:
        """Where the arm's base link frame (URDF frame) is now in the world (4, 4)."""
        body = self.body(arm_id)
        com_pos, com_orn = pb.getBasePositionAndOrientation(body, physicsClientId=self.client)
        inverse = pb.invertTransform(*self._inertial(body))
        pos, orn = pb.multiplyTransforms(com_pos, com_orn, *inverse)
        T = np.eye(4)
        T[:3, :3] = np.reshape(pb.getMatrixFromQuaternion(orn), (3, 3))
        T[:3, 3] = pos
        return T

    def links(self, arm_id: str) -> dict[str, int]:
        """PyBullet link index of each of the arm's links by name (the base: -1)."""
        return dict(self._link_index[self.cell.arm(arm_id).arm_id])

    def set_configuration(self, q: Mapping[str, ArrayLike]) -> None:
        """Pose several arms at once: ``{arm_id: q}``."""
        for arm_id, qa in q.items():
            self.set_joint_positions(arm_id, qa)

    def joint_positions(self, arm_id: str) -> np.ndarray:
        return self._q[self.cell.arm(arm_id).arm_id].copy()

    def link_world_positions(self, arm_id: str) -> dict[str, np.ndarray]:
        """World position of every link frame (URDF link frame, not the inertial frame)."""
        body = self.body(arm_id)
        out = {}
        for name, idx in self._link_index[arm_id].items():
            if idx < 0:  # PyBullet reports the base's inertial frame
                pos = self.base_link_frame(arm_id)[:3, 3]
            else:
                st = pb.getLinkState(
                    body, idx, computeForwardKinematics=True, physicsClientId=self.client
                )
                pos = st[4]
            out[name] = np.array(pos)
        return out

    def distance(self, arm_a: str, arm_b: str, cutoff: float = DEFAULT_CUTOFF) -> float:
        """Signed distance [m] between two arms' collision geometry (negative in penetration).

        Returns ``cutoff`` when the arms are farther apart than ``cutoff``.
        """
        pts = pb.getClosestPoints(
            self.body(arm_a), self.body(arm_b), cutoff, physicsClientId=self.client
        )
        if not pts:
            return float(cutoff)
        return float(min(p[8] for p in pts))

    def self_collisions(self, arm_id: str, margin: float = 0.0) -> list[Collision]:
        """The collisions of arm ``arm_id`` with itself (its checked link pairs within
        ``margin`` [m]) in the current configuration."""
        return self._self_collisions(self.cell.arm(arm_id), margin)

    def _self_collisions(self, arm: ArmSpec, margin: float) -> list[Collision]:
        body = self._body[arm.arm_id]
        idx = self._link_index[arm.arm_id]
        out = []
        for a, b in arm.robot.self_collision_pairs():
            pts = pb.getClosestPoints(
                body, body, margin, idx[a], idx[b], physicsClientId=self.client
            )
            d = min((p[8] for p in pts), default=np.inf)
            if d <= margin:
                out.append(Collision(arm.arm_id, a, arm.arm_id, b, float(d)))
        return out

    def collisions(self, margin: float = 0.0, self_collision: bool = True) -> list[Collision]:
        """Every collision in the current configuration: all arm pairs, then self-collisions.

        A pair collides when its signed distance is ``<= margin`` [m].
        """
        out: list[Collision] = []
        names = {
            arm_id: {v: k for k, v in links.items()} for arm_id, links in self._link_index.items()
        }
        for a, b in itertools.combinations(self.cell.arm_ids, 2):
            pts = pb.getClosestPoints(
                self._body[a], self._body[b], margin, physicsClientId=self.client
            )
            hits = [p for p in pts if p[8] <= margin]
            if hits:
                p = min(hits, key=lambda h: h[8])
                out.append(Collision(a, names[a][p[3]], b, names[b][p[4]], float(p[8])))
        if self_collision:
            for arm in self.cell.arms:
                out.extend(self._self_collisions(arm, margin))
        return out

    def in_collision(self, margin: float = 0.0, self_collision: bool = True) -> bool:
        return bool(self.collisions(margin, self_collision))
