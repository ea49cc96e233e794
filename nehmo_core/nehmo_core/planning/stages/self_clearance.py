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

A command runs from the pose the command in flight reaches (``self_clearance.ahead``), so the
rows are built there. They are linear, and a pair's distance can have a ridge in a joint (a
UR5's wrist against its upper arm, in wrist 2): a step up one side of it ends down the other.
As a command filter the stage therefore checks, with the exact geometry, the end of the step
(one ``opt.tick`` of it) for the pairs closer than ``self_clearance.check``: none may end below
``min(d, d_s − slack)``. A step that would is shortened (½, ¼), else turned to the command
nearest it whose rows open those pairs by ``opening`` (checked the same way), else the arm stays
still. The ``slack`` (1 mm) is the closing the rows cannot see: at ``d = d_s`` a row allows none
to first order, the distance's curvature closes it by µm along almost any step, and without the
slack every step of an arm resting there failed the check, so it never moved again.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as pb

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.geometry.world_pool import WORLDS
from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.problem import LinearRows, project_step
from nehmo_core.planning.opt.tick import PeerValues, Tick
from nehmo_core.planning.settings import SelfClearanceSettings
from nehmo_core.planning.stages.self_clearance_setup import distance_slopes, witness_order
from nehmo_core.robots.model import ArmSpec, Cell, Pose, RobotModel

__all__ = ["SelfClearance", "SelfClearanceRows", "project_step"]


@dataclass(frozen=True)
class SelfClearanceRows(LinearRows):
    """The damper rows ``A·y ≥ b`` (``A``: ∇d [m/rad]; ``b = −ξ·max(d − d_s, 0)`` [m], ≤ 0),
    one per near link pair, with the pairs' distances ``d`` [m] and names."""

    distances: np.ndarray  # (k,) d [m]
    pairs: tuple[tuple[str, str], ...]


MIN_GRADIENT = 1e-4
"""Rows whose ``|∂d/∂q|`` is below this [m/rad] in every joint are left out."""


def _self_world(robot: RobotModel) -> CellWorld:
    return CellWorld(Cell(f"self_{robot.name}", (ArmSpec("self", robot, Pose()),)))


def _empty_rows(n: int) -> SelfClearanceRows:
    return SelfClearanceRows(np.zeros((0, n)), np.zeros(0), np.zeros(0), ())


class SelfClearance:
    """Builds the damper rows of ``robot`` at a joint vector (own PyBullet client): the
    ``self_clearance`` row provider of a planner (settings group ``self_clearance``). It adds
    rows; the V rows stay."""

    name = "self_clearance"

    def reset(self) -> None:
        """The rows depend on the joint vector only (a cache of the last one is kept)."""
        self.shortened = 0

    def __init__(
        self,
        robot: RobotModel,
        settings: SelfClearanceSettings | None = None,
        host: Host | None = None,
    ) -> None:
        s = settings or SelfClearanceSettings()
        self.robot = robot
        self.host = host  # the planner whose commands it checks (a command filter only with it)
        self.check = s.check
        self.shortened = 0
        self.influence, self.safety, self.gain = s.influence, s.safety, s.gain
        self.slack, self.opening = s.slack, s.opening
        self.query_reach = s.query_reach
        self._lease = WORLDS.lease(("self", robot), lambda: _self_world(robot), self)
        self._world = self._lease.world
        self._client = self._world.client
        self._body = self._world.body("self")
        self._pairs = [
            (a, b, self._world.link_index("self", a), self._world.link_index("self", b))
            for a, b in robot.self_collision_pairs()
        ]
        self._links = {(a, b): (la, lb) for a, b, la, lb in self._pairs}
        ours = self._world.joint_indices("self")
        # for the Jacobian: each of our joints' axis (in its child link's URDF frame) and kind,
        # and per link the columns of the joints that move it (the link's own and its ancestors')
        self._joints = ours
        self._axes = np.empty((len(ours), 3))
        self._prismatic = np.zeros(len(ours), dtype=bool)
        parent = {}
        for j in range(pb.getNumJoints(self._body, physicsClientId=self._client)):
            info = pb.getJointInfo(self._body, j, physicsClientId=self._client)
            parent[j] = info[16]
            if j in ours:
                k = ours.index(j)
                self._axes[k] = info[13]
                self._prismatic[k] = info[2] == pb.JOINT_PRISMATIC
        self._axis_lists = self._axes.tolist()
        self._moves: dict[int, np.ndarray] = {}  # per link: which of our joints move it
        for _, _, la, lb in self._pairs:
            for link in (la, lb):
                moves, j = np.zeros(len(ours), dtype=bool), link
                while j >= 0:
                    if j in ours:
                        moves[ours.index(j)] = True
                    j = parent[j]
                self._moves[link] = moves

        self._last: tuple[np.ndarray, SelfClearanceRows] | None = None
        # per pair: a bound on |∂d/∂q_j| everywhere, and the last query's joints and distance
        self._slope = distance_slopes(self, parent)
        self._ref_q = np.full((len(self._pairs), len(ours)), np.nan)
        self._ref_d = np.zeros(len(self._pairs))
        self.queries = 0  # pair queries made (a pair skipped by its bound costs none)
        self._swapped = {(a, b): False for a, b, _, _ in self._pairs}
        facts = self._lease.facts  # the witness order, found once per world
        if "witness_order" not in facts:
            facts["witness_order"] = witness_order(self)
        self._swapped = facts["witness_order"]
        self._last = None  # rows computed while the order was being found

    def close(self) -> None:
        """Release the shared world (closed with its last user; twice is harmless)."""
        self._lease.release()

    def _gradients(
        self,
        normal: np.ndarray,
        p_a: np.ndarray,
        p_b: np.ndarray,
        link_a: list[int],
        link_b: list[int],
    ) -> np.ndarray:
        """Row ``i``: ``nᵢᵀ(J_a(p_a,ᵢ) − J_b(p_b,ᵢ))`` (r, n) at the posed ``q``, for world points
        ``p_a``, ``p_b`` (r, 3) fixed to links ``link_a``, ``link_b`` and unit normals (r, 3).

        A revolute joint ``j`` (world origin ``oⱼ``, axis ``zⱼ``) moves a point ``p`` of a link
        it drives by ``zⱼ × (p − oⱼ)`` per radian, whose component along ``n`` is
        ``(n × zⱼ)·(p − oⱼ)``; a prismatic joint moves it by ``zⱼ``. (Written for the few
        rows of a step: a handful of array operations in all, not a Jacobian per row.)"""
        states = pb.getLinkStates(
            self._body, self._joints, computeForwardKinematics=True, physicsClientId=self._client
        )
        origins = np.array([s[4] for s in states])  # the joints' child link frames
        axes = np.array(
            [pb.rotateVector(s[5], a) for s, a in zip(states, self._axis_lists, strict=True)]
        )
        moves_a = np.array([self._moves[k] for k in link_a], dtype=np.float64)  # (r, n) 0/1
        moves_b = np.array([self._moves[k] for k in link_b], dtype=np.float64)
        # the point each joint sees, its lever arm weighted by which side it moves (r, n, 3)
        lever = moves_a[:, :, None] * (p_a[:, None, :] - origins)
        lever -= moves_b[:, :, None] * (p_b[:, None, :] - origins)
        # (n × z)·lever = n·(z × lever)
        z = axes[None, :, :]
        turn = np.empty_like(lever)
        turn[..., 0] = z[..., 1] * lever[..., 2] - z[..., 2] * lever[..., 1]
        turn[..., 1] = z[..., 2] * lever[..., 0] - z[..., 0] * lever[..., 2]
        turn[..., 2] = z[..., 0] * lever[..., 1] - z[..., 1] * lever[..., 0]
        grad = np.einsum("rjk,rk->rj", turn, normal)
        if self._prismatic.any():
            slide = normal @ axes[self._prismatic].T
            grad[:, self._prismatic] = slide * (
                moves_a[:, self._prismatic] - moves_b[:, self._prismatic]
            )
        return grad

    def distances(self, q: np.ndarray) -> dict[tuple[str, str], float]:
        """Signed distance [m] of every self-collision link pair within ``influence``."""
        self._world.set_joint_positions("self", q)
        out = {}
        for a, b, la, lb in self._pairs:
            d = self._pair_distance(la, lb)
            if d is not None:
                out[(a, b)] = d
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
        # pairs whose distance cannot have come within the influence distance since their
        # last query need no new one
        since = np.abs(np.asarray(q, dtype=np.float64) - self._ref_q)
        lower = self._ref_d - np.sum(self._slope * since, axis=1)  # NaN (never asked): ask
        ask = np.flatnonzero(~(lower > self.influence))
        if len(ask) == 0:
            return _empty_rows(n)
        self._world.set_joint_positions("self", q)
        near = []  # (pair, d, p_a, p_b, normal from p_b to p_a) of the pairs within influence
        reach = self.influence + self.query_reach
        self.queries += len(ask)
        for i in ask:
            a, b_link, la, lb = self._pairs[i]
            pts = pb.getClosestPoints(
                self._body, self._body, reach, la, lb, physicsClientId=self._client
            )
            p = min(pts, key=lambda h: h[8], default=None)  # the closest point pair
            self._ref_q[i] = q
            self._ref_d[i] = reach if p is None else p[8]
            if p is None or p[8] > self.influence:
                continue
            if self._swapped[(a, b_link)]:
                near.append(((a, b_link, la, lb), p[8], p[6], p[5], [-v for v in p[7]]))
            else:
                near.append(((a, b_link, la, lb), p[8], p[5], p[6], p[7]))
        if not near:
            return _empty_rows(n)
        pairs, dist, p_a, p_b, normal = zip(*near, strict=True)
        A = self._gradients(
            np.array(normal),
            np.array(p_a),
            np.array(p_b),
            [x[2] for x in pairs],
            [x[3] for x in pairs],
        )
        d = np.array(dist, dtype=np.float64)
        # rows no step changes (to first order) constrain nothing
        moving = np.abs(A).max(axis=1) >= MIN_GRADIENT
        if not moving.any():
            return _empty_rows(n)
        return SelfClearanceRows(
            A[moving],
            -self.gain * np.maximum(d[moving] - self.safety, 0.0),
            d[moving],
            tuple((x[0], x[1]) for x, keep in zip(pairs, moving, strict=True) if keep),
        )

    def filter(self, tick: Tick, now: PeerValues, u: np.ndarray) -> np.ndarray:
        """``u``, or the share of it (½, ¼) whose step of one ``opt.tick`` from where the
        command starts leaves no pair closer than ``check`` below ``min(d, safety − slack)``
        (``slack``: the closing a row at ``d = safety`` cannot see, its distance's curvature);
        else the command nearest ``u`` whose rows open those pairs by ``opening``; else 0."""
        if self.host is None or self.check <= 0.0:
            return u
        q = self.host.ahead(tick.q)
        rows = self.rows(q)
        near = np.flatnonzero(rows.distances < self.check)
        if not len(near):
            return u
        links = [self._links[rows.pairs[i]] for i in near]
        d = rows.distances[near]
        floors = np.minimum(d, max(self.safety - self.slack, 0.0)) - 1e-6
        dt = self.host.settings.opt.tick
        for scale in (1.0, 0.5, 0.25):
            if self._fits(q, scale * dt * u, links, floors):
                self.shortened += scale < 1.0
                return u * scale
        self.shortened += 1
        y_max = dt * self.host.settings.opt.u_max * tick.cap
        openings = (self.opening, 3 * self.opening) if self.opening > 0 else ()
        for opening in openings:  # the curvature closed every share: open the pairs instead
            step = project_step(dt * u, LinearRows(rows.A[near], floors - d + opening), y_max)
            if self._fits(q, step, links, floors):
                return step / dt
        return np.zeros_like(u)

    def _fits(self, q: np.ndarray, step: np.ndarray, links: list, floors: np.ndarray) -> bool:
        """Whether no pair of ``links`` ends below its floor after ``step`` from ``q``."""
        self._world.set_joint_positions("self", q + step)
        ends = [self._pair_distance(la, lb) for la, lb in links]
        return all(e is None or e >= f for e, f in zip(ends, floors, strict=True))

    def _pair_distance(self, link_a: int, link_b: int) -> float | None:
        """The posed links' signed distance [m] (None if farther than ``influence``)."""
        pts = pb.getClosestPoints(
            self._body, self._body, self.influence, link_a, link_b, physicsClientId=self._client
        )
        return float(min(p[8] for p in pts)) if pts else None
