"""The exact failure margin a rollout is judged by: true geometry, never the learned ``l``.

For an arm pair it is the signed distance between the two arms' collision geometry in PyBullet
(negative in penetration), posed in the pair's own cell; for the low-dimensional systems
(Air3D, two planar 2-link arms) the analytic boundary ``l(x)`` is already exact.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pybullet as pb
import torch

from nehmo_core.errors import NehmoError, UnknownNameError
from nehmo_core.geometry.distance_data import (
    CONDITIONED_PAIRS,
    PAIRS,
    SWAPPED_PAIRS,
    system_pair_cell,
)
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.hjr.systems import ArmPairSystem, HJISystem
from nehmo_core.robots.model import Cell, Pose

ExactMargin = Callable[[np.ndarray, float], np.ndarray]
"""``margin(x (B, n) [rad or m], cutoff [m]) -> (B,)`` [m]; values above ``cutoff`` may be
reported as ``cutoff``."""


def pair_arms(name: str) -> tuple[Cell, str, str]:
    """The cell of a shipped pair system and its arms in the system's order (arm 1, arm 2).

    ``kinova_ur5`` is the UR5-Kinova cell seen from the Kinova's base: the arms swap; so do
    they in ``kinova_ur5_any``, whose cell has the Kinova at the origin and the UR5 facing it
    (moved to ``(r, 0, 0)`` per state). See
    :func:`~nehmo_core.geometry.distance_data.system_pair_cell`.
    """
    return system_pair_cell(name)


class SphereCover:
    """Balls that cover one arm's collision geometry, fixed in its link frames.

    Built from PyBullet itself: with the arm at ``q = 0`` each colliding link's world AABB
    (collision margin included) is cut along its longest side into near-cubes, and each piece's
    circumscribed ball is carried into the link frame. The balls only ever over-cover, so the
    distance between two covers is a lower bound on the exact distance of arms that are apart,
    which makes :meth:`PairDistance.lower_bound` a sound prefilter: a state whose covers are
    apart is not in contact. (In penetration both are negative, and the covers' overlap need not
    bound PyBullet's penetration depth.)
    """

    def __init__(self, world: CellWorld, arm_id: str, pieces: int = 4) -> None:
        arm = world.cell.arm(arm_id)
        self.kinematics = ArmKinematics(arm.robot)  # in the arm's own base frame
        body = world.body(arm_id)
        world.set_joint_positions(arm_id, np.zeros(arm.robot.dof))
        base_pose = world.base_link_frame(arm_id)
        at_zero = self.kinematics.link_transforms(
            torch.zeros(1, arm.robot.dof, dtype=torch.float64)
        )
        centres: dict[str, list[np.ndarray]] = {}  # per link, in chain order
        radii: list[float] = []
        for name, index in world.links(arm_id).items():
            if not pb.getCollisionShapeData(body, index, physicsClientId=world.client):
                continue  # no collision geometry
            name = _on_chain(world, body, index, name, at_zero, arm_id)
            lo, hi = (np.array(v) for v in pb.getAABB(body, index, physicsClientId=world.client))
            side = hi - lo
            axis = int(np.argmax(side))
            count = int(min(pieces, max(1, np.ceil(side[axis] / max(np.median(side), 1e-6)))))
            step = side[axis] / count
            piece = side.copy()
            piece[axis] = step
            T_world_link = base_pose @ at_zero[name][0].numpy()
            T_link_world = np.linalg.inv(T_world_link)
            for k in range(count):
                centre = lo + 0.5 * piece
                centre[axis] = lo[axis] + (k + 0.5) * step
                centres.setdefault(name, []).append(
                    T_link_world[:3, :3] @ centre + T_link_world[:3, 3]
                )
                radii.append(0.5 * float(np.linalg.norm(piece)))
        # ball centres (in their link frame) per link, in the order world() returns them
        self._by_link = [(n, torch.as_tensor(np.array(c))) for n, c in centres.items()]
        self.radii = np.array(radii)  # (S,) [m]

    def world(self, q: np.ndarray, base: np.ndarray) -> torch.Tensor:
        """Ball centres (B, S, 3) for joint angles ``q (B, dof)`` and base poses ``(B, 4, 4)``."""
        tf = self.kinematics.link_transforms(torch.as_tensor(q, dtype=torch.float64))
        base_t = torch.from_numpy(np.array(base, dtype=np.float64))
        parts = []
        for name, centres in self._by_link:
            T = base_t @ tf[name]
            parts.append(T[:, None, :3, :3] @ centres[None, :, :, None])
            parts[-1] = parts[-1][..., 0] + T[:, None, :3, 3]
        return torch.cat(parts, dim=1)


def _on_chain(world: CellWorld, body: int, index: int, name: str, chain: Any, arm_id: str) -> str:
    """The link whose frame carries link ``name``'s balls: itself when on the chain, else its
    nearest ancestor on it (a link off the chain, such as a gripper finger held at its zero, is
    rigid relative to that ancestor)."""
    links = {i: n for n, i in world.links(arm_id).items()}
    while name not in chain:
        if index < 0:
            raise NehmoError(f"link {name!r} of {arm_id} collides but hangs off no chain link")
        index = pb.getJointInfo(body, index, physicsClientId=world.client)[16]
        name = links[index]
    return name


class PairDistance:
    """Exact signed distance [m] of a shipped arm pair, ``x = (q¹, q²)`` in the system's order.

    For a pose-conditioned pair, ``x = (q¹, q², r)``: arm 2 stands at ``(r, 0, 0)`` facing arm 1,
    the canonical frame of the conditioned models, moved for each state.
    """

    def __init__(self, system: ArmPairSystem) -> None:
        cell, self.arm_a, self.arm_b = pair_arms(system.name)
        self.n1, self.n2 = system.n1, system.n2
        self.conditioned = bool(system.conditions)
        self.world = CellWorld(cell)
        self._r: float | None = None
        self._covers: tuple[SphereCover, SphereCover] | None = None
        self._fixed: tuple[np.ndarray, np.ndarray] = (np.eye(4), np.eye(4))

    def _place(self, r: float) -> None:
        if r != self._r:
            self.world.set_base_pose(self.arm_b, Pose((r, 0.0, 0.0), (0.0, 0.0, math.pi)))
            self._r = r

    def __call__(self, x: np.ndarray, cutoff: float = 1.0) -> np.ndarray:
        out = np.empty(x.shape[0])
        n1, n2 = self.n1, self.n2
        for i, state in enumerate(np.asarray(x, dtype=np.float64)):
            if self.conditioned:
                self._place(float(state[n1 + n2]))
            self.world.set_joint_positions(self.arm_a, state[:n1])
            self.world.set_joint_positions(self.arm_b, state[n1 : n1 + n2])
            out[i] = self.world.distance(self.arm_a, self.arm_b, cutoff)
        return out

    def lower_bound(self, x: np.ndarray) -> np.ndarray:
        """From the arms' ball covers (:class:`SphereCover`), cheap and batched: a value (B,) [m]
        that is positive only where :meth:`__call__` is, and then no larger."""
        if self._covers is None:
            self._covers = (
                SphereCover(self.world, self.arm_a),
                SphereCover(self.world, self.arm_b),
            )
            self._fixed = (
                self.world.base_link_frame(self.arm_a),
                self.world.base_link_frame(self.arm_b),
            )
        x = np.asarray(x, dtype=np.float64)
        n1, n2, batch = self.n1, self.n2, x.shape[0]
        base_a = np.broadcast_to(self._fixed[0], (batch, 4, 4))
        if self.conditioned:  # as _place poses it: the base link frame at (r, 0, 0), facing
            placed = Pose((0.0, 0.0, 0.0), (0.0, 0.0, math.pi)).matrix()
            base_b = np.repeat(placed[None], batch, axis=0)
            base_b[:, 0, 3] += x[:, n1 + n2]
        else:
            base_b = np.broadcast_to(self._fixed[1], (batch, 4, 4))
        a, b = self._covers
        ca = a.world(x[:, :n1], base_a)
        cb = b.world(x[:, n1 : n1 + n2], base_b)
        gap = torch.cdist(ca, cb) - torch.as_tensor(a.radii[:, None] + b.radii[None, :])
        return gap.amin(dim=(1, 2)).numpy()

    def close(self) -> None:
        self.world.close()


class AnalyticBoundary:
    """``l(x)`` of a system whose boundary is exact geometry (Air3D, the two-link pair)."""

    def __init__(self, system: HJISystem) -> None:
        self.system = system

    def __call__(self, x: np.ndarray, cutoff: float = np.inf) -> np.ndarray:
        with torch.no_grad():
            margin = self.system.boundary(torch.as_tensor(x, dtype=torch.float64))
        return np.minimum(margin.numpy(), cutoff)

    def close(self) -> None:
        """Nothing to release."""


def exact_margin(system: HJISystem) -> PairDistance | AnalyticBoundary:
    """The exact margin of a system: PyBullet for shipped arm pairs, ``l`` otherwise."""
    shipped = (*PAIRS, *CONDITIONED_PAIRS, *SWAPPED_PAIRS)
    if isinstance(system, ArmPairSystem):
        if system.name not in shipped:
            raise UnknownNameError("arm pair (exact geometry)", system.name, shipped)
        return PairDistance(system)
    return AnalyticBoundary(system)
