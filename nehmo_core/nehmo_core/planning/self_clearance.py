"""Self-collision avoidance for one arm: velocity-damper constraints on the planning step.

Problem Opt of the paper keeps an arm away from the *other* arms only; an arm driven at full
speed (the fail-safe ``ū·sign(∂V/∂q)`` moves every joint) can fold into itself. This module adds
the classic velocity damper (Faverjon and Tournassoud, 1987; Kanehiro et al., 2008) for every
self-collision link pair of the arm (the robot's SRDF rules) that is closer than the influence
distance ``d_i``::

    ∇d(q)·y ≥ −ξ·max(d(q) − d_s, 0)

with ``d`` the exact signed distance of the pair's collision shapes (PyBullet, the geometry the
simulator checks), ``∇d = nᵀ(J_a(p_a) − J_b(p_b))`` from the closest points ``p_a, p_b`` and
the unit normal ``n`` from ``p_b`` to ``p_a``, ``y = t_plan·u`` the planned step, ``d_s`` the
safety distance and ``ξ ∈ (0, 1]`` the share of the remaining margin a step may use. ``y = 0``
always satisfies the rows, so they never make Opt infeasible by themselves; a pair already
inside ``d_s`` may not get closer.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.model import ArmSpec, Cell, Pose, RobotModel

__all__ = ["SelfClearance", "SelfClearanceRows", "project_step"]


@dataclass(frozen=True)
class SelfClearanceRows:
    """Linear constraints ``A·y ≥ b`` on the step, one per near link pair, and their pairs."""

    A: np.ndarray  # (k, n) ∇d [m/rad]
    b: np.ndarray  # (k,) −ξ·max(d − d_s, 0) [m], ≤ 0
    distances: np.ndarray  # (k,) d [m]
    pairs: tuple[tuple[str, str], ...]

    @property
    def count(self) -> int:
        return len(self.b)

    def satisfied(self, y: np.ndarray, tol: float = 1e-9) -> bool:
        return bool(np.all(self.A @ y >= self.b - tol))


MIN_GRADIENT = 1e-4
"""Rows whose ``|∂d/∂q|`` is below this [m/rad] in every joint are left out."""

_WITNESS_ORDER: dict[str, dict[tuple[str, str], bool]] = {}
"""Per robot: :meth:`SelfClearance._witness_order` (found once per process)."""


def project_step(target: np.ndarray, rows: SelfClearanceRows, y_max: float) -> np.ndarray:
    """The step closest to ``target`` that satisfies ``rows`` within the box ``|y_j| ≤ y_max``.

    ``y = 0`` is always feasible, so this returns zero only if the QP solver fails.
    """
    target = np.clip(target, -y_max, y_max)
    if rows.count == 0 or rows.satisfied(target):
        return target
    from nehmo_core.planning.sqp import qp_step

    n = len(target)
    step = qp_step(
        2.0 * np.eye(n), -2.0 * target, -rows.b, rows.A, np.full(n, -y_max), np.full(n, y_max)
    )
    return step.p if step.feasible else np.zeros(n)


def _empty_rows(n: int) -> SelfClearanceRows:
    return SelfClearanceRows(np.zeros((0, n)), np.zeros(0), np.zeros(0), ())


class SelfClearance:
    """Builds the damper rows of ``robot`` at a joint vector (own PyBullet client)."""

    def __init__(
        self,
        robot: RobotModel,
        influence: float = 0.10,
        safety: float = 0.005,
        gain: float = 0.5,
    ) -> None:
        if not influence > safety >= 0.0:
            raise InvalidValueError(
                "self_influence", f"must be > self_safety ({safety}) >= 0", influence
            )
        if not 0.0 < gain <= 1.0:
            raise InvalidValueError("self_gain", "must lie in (0, 1]", gain)
        self.robot = robot
        self.influence, self.safety, self.gain = influence, safety, gain
        arm = ArmSpec("self", robot, Pose())
        self._world = CellWorld(Cell(f"self_{robot.name}", (arm,)))
        self._client = self._world.client
        self._body = self._world.body("self")
        self._pairs = [
            (a, b, self._world.link_index("self", a), self._world.link_index("self", b))
            for a, b in robot.self_collision_pairs()
        ]
        # PyBullet's Jacobian columns follow its movable joints; map them onto our joint order
        movable = [
            j
            for j in range(pb.getNumJoints(self._body, physicsClientId=self._client))
            if pb.getJointInfo(self._body, j, physicsClientId=self._client)[2] != pb.JOINT_FIXED
        ]
        ours = self._world.joint_indices("self")
        self._movable = movable
        self._columns = [movable.index(j) for j in ours]
        self._extra = [j for j in movable if j not in ours]

        self._last: tuple[np.ndarray, SelfClearanceRows] | None = None
        self._swapped = {(a, b): False for a, b, _, _ in self._pairs}
        if robot.name not in _WITNESS_ORDER:
            _WITNESS_ORDER[robot.name] = self._witness_order()
        self._swapped = _WITNESS_ORDER[robot.name]
        self._last = None  # rows computed while the order was being found

    def _witness_order(self, samples: int = 60, seed: int = 0) -> dict[tuple[str, str], bool]:
        """Per link pair: whether PyBullet reports its witness points in swapped order.

        For some shape combinations (e.g. a mesh against a compound shape) the query returns
        the point on link B as "position on A" (the normal still points from the second point
        to the first). The order is fixed per pair, so it is found once: on random
        configurations, the gradient from the assumed order must predict the change of the
        distance along itself; a majority vote per pair decides.
        """
        rng = np.random.default_rng(seed)
        votes = {pair: 0 for pair in self._swapped}
        lo = np.maximum(self.robot.lower, -np.pi)
        hi = np.minimum(self.robot.upper, np.pi)
        for _ in range(samples):
            q = rng.uniform(lo, hi)
            rows = self.rows(q)
            for grad, d, pair in zip(rows.A, rows.distances, rows.pairs, strict=True):
                norm = float(np.linalg.norm(grad))
                if d < 0.005 or norm < 1e-3:
                    continue
                dq = 1e-3 * grad / norm
                ahead = self.distances(q + dq).get(pair)
                behind = self.distances(q - dq).get(pair)
                if ahead is None or behind is None:
                    continue
                change, predicted = (ahead - behind) / 2.0, float(grad @ dq)
                votes[pair] += 1 if change * predicted > 0 else -1
        return {pair: vote < 0 for pair, vote in votes.items()}

    def close(self) -> None:
        self._world.close()

    def _jacobian(self, link: int, point: np.ndarray, q_all: list[float]) -> np.ndarray:
        """Positional Jacobian (3, n) of a world point fixed to ``link`` (zero on the base)."""
        n = self.robot.dof
        if link < 0:
            return np.zeros((3, n))
        # calculateJacobian takes the point in the URDF link frame (state entries 4 and 5)
        state = pb.getLinkState(
            self._body, link, computeForwardKinematics=True, physicsClientId=self._client
        )
        inv_pos, inv_orn = pb.invertTransform(state[4], state[5])
        local = pb.multiplyTransforms(inv_pos, inv_orn, point.tolist(), (0, 0, 0, 1))[0]
        zeros = [0.0] * len(q_all)
        linear, _ = pb.calculateJacobian(
            self._body, link, local, q_all, zeros, zeros, physicsClientId=self._client
        )
        return np.asarray(linear, dtype=np.float64)[:, self._columns]

    def distances(self, q: np.ndarray) -> dict[tuple[str, str], float]:
        """Signed distance [m] of every self-collision link pair within ``influence``."""
        self._world.set_joint_positions("self", q)
        out = {}
        for a, b, la, lb in self._pairs:
            pts = pb.getClosestPoints(
                self._body, self._body, self.influence, la, lb, physicsClientId=self._client
            )
            if pts:
                out[(a, b)] = float(min(p[8] for p in pts))
        return out

    def rows(self, q: np.ndarray) -> SelfClearanceRows:
        """The damper rows at joint vector ``q`` (pairs closer than the influence distance).

        The last answer is kept: asking again at the same ``q`` (a node computes the fail-safe
        ahead of each solve from the same state) costs nothing."""
        if self._last is not None and np.array_equal(self._last[0], q):
            return self._last[1]
        rows = self._rows(q)
        self._last = (np.array(q, dtype=np.float64), rows)
        return rows

    def _rows(self, q: np.ndarray) -> SelfClearanceRows:
        n = self.robot.dof
        self._world.set_joint_positions("self", q)
        q_all: list[float] | None = None
        A, b, d_all, names = [], [], [], []
        for a, b_link, la, lb in self._pairs:
            pts = pb.getClosestPoints(
                self._body, self._body, self.influence, la, lb, physicsClientId=self._client
            )
            if not pts:
                continue
            p = min(pts, key=lambda h: h[8])
            d = float(p[8])
            p_a, p_b = np.asarray(p[5]), np.asarray(p[6])
            normal = np.asarray(p[7])  # contact normal on B, pointing towards A
            if self._swapped[(a, b_link)]:
                p_a, p_b, normal = p_b, p_a, -normal
            if q_all is None:
                q_all = [
                    pb.getJointState(self._body, j, physicsClientId=self._client)[0]
                    for j in self._movable
                ]
            grad = normal @ (self._jacobian(la, p_a, q_all) - self._jacobian(lb, p_b, q_all))
            if float(np.abs(grad).max()) < MIN_GRADIENT:
                continue  # no step changes this distance (to first order): nothing to constrain
            A.append(grad)
            b.append(-self.gain * max(d - self.safety, 0.0))
            d_all.append(d)
            names.append((a, b_link))
        if not A:
            return _empty_rows(n)
        return SelfClearanceRows(np.array(A), np.array(b), np.array(d_all), tuple(names))
