"""A conservative broad phase in front of the bridge's exact collision checks.

:class:`BroadPhaseSimulator` is a :class:`~nehmo_core.sim.cell_sim.CellSimulator` whose
:meth:`~BroadPhaseSimulator.collisions` returns exactly what
:meth:`nehmo_core.geometry.pybullet_world.CellWorld.collisions` returns (same pairs in the same
order, same links, same distances) but skips the exact PyBullet query of every pair that
cannot touch. Every link is covered by a few spheres fixed in its link frame; a pair whose
spheres are all more than :data:`SKIP_GAP` apart is separated, because the spheres contain the
collision geometry, collision margins included. Every other pair gets the same
``getClosestPoints`` query as in ``CellWorld``, so every collision is still found at the same
physics step and reported the same way.

The spheres come from each robot model's collision bounding boxes, measured once in a private
PyBullet client: the broad phase never steps or changes the simulated world.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import pybullet as pb
from numpy.typing import NDArray

from nehmo_core.geometry.pybullet_world import CellWorld, Collision
from nehmo_core.robots.model import Cell, RobotModel
from nehmo_core.sim.cell_sim import CellSimulator

FloatArray = NDArray[np.float64]

#: Pairs whose bounding spheres are more than this apart [m] skip the exact query; the slack
#: covers rounding in the sphere bounds and in PyBullet's distances.
SKIP_GAP = 0.01
#: Most spheres per link (a long link is split along its longest side).
MAX_SPHERES_PER_LINK = 6
#: PyBullet's index of a body's base link.
BASE = -1


@dataclass(frozen=True)
class LinkSpheres:
    """Spheres covering one link's collision geometry, in that link's frame [m].

    The frame is the URDF link frame (``getLinkState`` items 4 and 5), for the base link the
    pose ``getBasePositionAndOrientation`` reports.
    """

    link: int  # PyBullet link index (BASE for the base)
    centers: FloatArray  # (n, 3)
    radii: FloatArray  # (n,)


def _quaternion_terms() -> FloatArray:
    """``K`` (16, 3, 3) with ``R(q) = I + Σ_ab q_a q_b K[4a + b]`` for unit quaternions ``q`` in
    PyBullet's (x, y, z, w) order."""
    x, y, z, w = range(4)
    k = np.zeros((4, 4, 3, 3))
    for (i, j), terms in {
        (0, 0): [(y, y, -2), (z, z, -2)],
        (0, 1): [(x, y, 2), (z, w, -2)],
        (0, 2): [(x, z, 2), (y, w, 2)],
        (1, 0): [(x, y, 2), (z, w, 2)],
        (1, 1): [(x, x, -2), (z, z, -2)],
        (1, 2): [(y, z, 2), (x, w, -2)],
        (2, 0): [(x, z, 2), (y, w, -2)],
        (2, 1): [(y, z, 2), (x, w, 2)],
        (2, 2): [(x, x, -2), (y, y, -2)],
    }.items():
        for a, b, factor in terms:
            k[a, b, i, j] += factor
    return k.reshape(16, 3, 3)


#: See :func:`_quaternion_terms`.
QUATERNION_TERMS = _quaternion_terms()


def rotations(quaternions: FloatArray) -> FloatArray:
    """Rotation matrices (n, 3, 3) of unit quaternions (n, 4) in PyBullet's (x, y, z, w) order."""
    products = (quaternions[:, :, None] * quaternions[:, None, :]).reshape(-1, 16)
    return np.eye(3) + np.einsum("nk,kij->nij", products, QUATERNION_TERMS)


def box_spheres(lower: FloatArray, upper: FloatArray) -> tuple[FloatArray, FloatArray]:
    """A row of equal spheres covering the box [lower, upper], split along its longest side."""
    extent = upper - lower
    axis = int(np.argmax(extent))
    widest_other = float(np.delete(extent, axis).max())
    count = min(MAX_SPHERES_PER_LINK, max(1, math.ceil(extent[axis] / max(widest_other, 1e-3))))
    piece = extent.copy()
    piece[axis] = extent[axis] / count
    centers = np.repeat(((lower + upper) / 2)[None, :], count, axis=0)
    centers[:, axis] = lower[axis] + piece[axis] * (np.arange(count) + 0.5)
    return centers, np.full(count, 0.5 * float(np.linalg.norm(piece)))


def link_spheres(robot: RobotModel) -> list[LinkSpheres]:
    """Spheres covering every link of ``robot`` (those without collision geometry get the
    small box PyBullet reports for them: harmless, and nothing is left out).

    Measured in a private DIRECT client: the robot is loaded as ``CellWorld`` loads it (fixed
    base, implicit cylinders), its collision bounding boxes (which include PyBullet's collision
    margins) are brought up to date, and each world box is covered in its link's frame.
    """
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(
            str(robot.urdf_path),
            useFixedBase=True,
            flags=pb.URDF_USE_IMPLICIT_CYLINDER,
            physicsClientId=client,
        )
        pb.performCollisionDetection(physicsClientId=client)  # bounding boxes of this pose
        out = []
        for link in range(BASE, pb.getNumJoints(body, physicsClientId=client)):
            if link == BASE:
                position, orientation = pb.getBasePositionAndOrientation(
                    body, physicsClientId=client
                )
            else:
                state = pb.getLinkState(
                    body, link, computeForwardKinematics=True, physicsClientId=client
                )
                position, orientation = state[4], state[5]
            lower, upper = pb.getAABB(body, link, physicsClientId=client)
            corners = np.array(list(itertools.product(*zip(lower, upper, strict=True))))
            rotation = rotations(np.asarray([orientation], dtype=np.float64))[0]
            local = (corners - np.asarray(position)) @ rotation  # Rᵀ (corner − p), row-wise
            centers, radii = box_spheres(local.min(axis=0), local.max(axis=0))
            out.append(LinkSpheres(link, centers, radii))
        return out
    finally:
        pb.disconnect(physicsClientId=client)


@dataclass(frozen=True)
class _Check:
    """One exact query of ``CellWorld.collisions``: an arm pair, or (``links``: names and
    PyBullet indices) a self-collision link pair of ``arm_a``. ``group`` is its entry in
    :meth:`BroadPhase.bounds` (-1: none, always query)."""

    arm_a: str
    arm_b: str
    group: int
    links: tuple[str, str, int, int] | None = None


class BroadPhase:
    """The collisions of a :class:`CellWorld`'s current pose, skipping separated pairs."""

    def __init__(self, world: CellWorld, spheres: dict[str, list[LinkSpheres]]) -> None:
        self.client = world.client
        cell: Cell = world.cell
        self.arm_ids = list(cell.arm_ids)
        self.bodies = {a: world.body(a) for a in self.arm_ids}
        self.link_names = {a: self._link_names(self.bodies[a]) for a in self.arm_ids}
        # Sphere frames per arm: the base's (if it has spheres), then the moving links'.
        ordered = {a: sorted(spheres[a], key=lambda s: s.link) for a in self.arm_ids}
        self.has_base = {a: bool(ordered[a]) and ordered[a][0].link == BASE for a in self.arm_ids}
        self.moving_links = {
            a: [x.link for x in ordered[a] if x.link != BASE] for a in self.arm_ids
        }
        # All spheres stacked; ``rows[(arm, link)]`` are a link's rows, ``frame_of`` its frame.
        centers: list[FloatArray] = []
        radii: list[FloatArray] = []
        frame_of: list[int] = []
        rows: dict[tuple[str, int], list[int]] = {}
        for a in self.arm_ids:
            for s in ordered[a]:
                start = sum(len(r) for r in radii)
                rows[(a, s.link)] = list(range(start, start + len(s.radii)))
                frame_of += [len(centers)] * len(s.radii)
                centers.append(s.centers)
                radii.append(s.radii)
        self.frame_of = np.asarray(frame_of, dtype=np.intp)
        local = np.concatenate(centers)
        self.radii = np.concatenate(radii)
        # centre = p + R(q) c = p + c + Σ_k q_a q_b (K_k c): the K_k c are fixed per sphere.
        self.local_centers = local
        self.local_terms = np.einsum("kij,nj->nki", QUATERNION_TERMS, local)
        # The exact queries of CellWorld.collisions, in its order, with their sphere groups.
        pair_i: list[int] = []
        pair_j: list[int] = []
        starts: list[int] = []
        self.checks: list[_Check] = []

        def group(rows_a: list[int], rows_b: list[int]) -> int:
            if not rows_a or not rows_b:
                return -1  # no geometry on one side: leave the pair to the exact query
            starts.append(len(pair_i))
            for i in rows_a:
                pair_i.extend([i] * len(rows_b))
                pair_j.extend(rows_b)
            return len(starts) - 1

        def arm_rows(a: str) -> list[int]:
            return [i for (arm, _), r in rows.items() if arm == a for i in r]

        for a, b in itertools.combinations(self.arm_ids, 2):
            g = group(arm_rows(a), arm_rows(b))
            self.checks.append(_Check(a, b, g))
        for arm in cell.arms:
            a = arm.arm_id
            for x, y in arm.robot.self_collision_pairs():
                ia, ib = world.link_index(a, x), world.link_index(a, y)
                g = group(rows.get((a, ia), []), rows.get((a, ib), []))
                self.checks.append(_Check(a, a, g, (x, y, ia, ib)))
        pair_rows, pair_cols = np.asarray(pair_i, dtype=np.intp), np.asarray(pair_j, dtype=np.intp)
        self.pairs = pair_rows * len(self.radii) + pair_cols  # into the flat (n, n) matrix
        self.pair_radii = self.radii[pair_rows] + self.radii[pair_cols]
        self.starts = np.asarray(starts, dtype=np.intp)

    def _link_names(self, body: int) -> dict[int, str]:
        names = {BASE: pb.getBodyInfo(body, physicsClientId=self.client)[0].decode()}
        for j in range(pb.getNumJoints(body, physicsClientId=self.client)):
            names[j] = pb.getJointInfo(body, j, physicsClientId=self.client)[12].decode()
        return names

    def centers(self) -> FloatArray:
        """Sphere centres (n, 3) [m] in the world, at the world's current pose."""
        positions: list[Sequence[float]] = []
        orientations: list[Sequence[float]] = []
        for a in self.arm_ids:
            body = self.bodies[a]
            if self.has_base[a]:
                position, orientation = pb.getBasePositionAndOrientation(
                    body, physicsClientId=self.client
                )
                positions.append(position)
                orientations.append(orientation)
            if self.moving_links[a]:
                states = pb.getLinkStates(
                    body,
                    self.moving_links[a],
                    computeForwardKinematics=True,
                    physicsClientId=self.client,
                )
                positions += [s[4] for s in states]
                orientations += [s[5] for s in states]
        q = np.asarray(orientations, dtype=np.float64)
        products = (q[:, :, None] * q[:, None, :]).reshape(-1, 16)[self.frame_of]
        rotated = self.local_centers + (products[:, None, :] @ self.local_terms)[:, 0, :]
        return rotated + np.asarray(positions, dtype=np.float64)[self.frame_of]

    def bounds(self) -> FloatArray:
        """Per sphere group (one per check that has one): a lower bound [m] of the distance
        between the two sides' collision geometry."""
        centers = self.centers()
        norms = np.einsum("ni,ni->n", centers, centers)
        squared = norms[:, None] + norms[None, :] - 2.0 * (centers @ centers.T)
        distance = np.sqrt(np.maximum(squared, 0.0)).ravel().take(self.pairs)
        gaps = distance - self.pair_radii
        return np.minimum.reduceat(gaps, self.starts) if self.starts.size else gaps

    def collisions(self, self_collision: bool = True) -> list[Collision]:
        """What ``CellWorld.collisions(0.0, self_collision)`` returns for the current pose."""
        margin = 0.0
        separated = self.bounds() > SKIP_GAP
        out: list[Collision] = []
        for c in self.checks:
            if c.group >= 0 and separated[c.group]:
                continue
            if c.links is None:
                pts = pb.getClosestPoints(
                    self.bodies[c.arm_a], self.bodies[c.arm_b], margin, physicsClientId=self.client
                )
                hits = [p for p in pts if p[8] <= margin]
                if hits:
                    p = min(hits, key=lambda h: h[8])
                    out.append(
                        Collision(
                            c.arm_a,
                            self.link_names[c.arm_a][p[3]],
                            c.arm_b,
                            self.link_names[c.arm_b][p[4]],
                            float(p[8]),
                        )
                    )
            elif self_collision:
                x, y, ia, ib = c.links
                body = self.bodies[c.arm_a]
                pts = pb.getClosestPoints(body, body, margin, ia, ib, physicsClientId=self.client)
                d = min((p[8] for p in pts), default=np.inf)
                if d <= margin:
                    out.append(Collision(c.arm_a, x, c.arm_a, y, float(d)))
        return out


class BroadPhaseSimulator(CellSimulator):
    """A :class:`CellSimulator` whose collision checks go through a :class:`BroadPhase`.

    The results are those of ``CellSimulator`` (every step, every collision, same reports);
    only pairs that provably do not touch skip their exact query.
    """

    def __init__(
        self, cell: Cell, substeps: int = 10, self_collision: bool = True, actuators: str = "ideal"
    ) -> None:
        super().__init__(
            cell, substeps=substeps, self_collision=self_collision, actuators=actuators
        )
        by_robot: dict[str, list[LinkSpheres]] = {}
        for arm in cell.arms:
            key = str(arm.robot.urdf_path)
            if key not in by_robot:
                by_robot[key] = link_spheres(arm.robot)
        spheres = {arm.arm_id: by_robot[str(arm.robot.urdf_path)] for arm in cell.arms}
        self.broad_phase = BroadPhase(self.world, spheres)

    def collisions(self) -> list[Collision]:
        """Collisions in the current configuration (as ``CellSimulator.collisions``)."""
        self.world.set_configuration(self.q)
        return self.broad_phase.collisions(self_collision=self.self_collision)
