"""Keypoints placed in the bulk of each link's collision geometry, from the URDF alone.

A learned distance reads pairwise distances between keypoints of the two arms
(:mod:`nehmo_core.geometry.distance_model`). Link-frame origins serve arms whose links are
cylinders about the joint axes (the UR5); for an arm with offset housings and a wide hand (the
Panda) they leave whole parts of the geometry between keypoints. :func:`collision_points`
places points where the geometry is instead:

1. For each link with collision geometry (links off the arm's chain too, such as a gripper's
   fingers, which then count as part of the chain link they hang from), probe a grid (``grid``
   [m] spacing) over the link's bounding box in PyBullet and keep the probes inside the
   geometry (what PyBullet collides: convex hulls of meshes, exact primitives).
2. Cluster the inside probes with k-means (seeded), ``k = ceil(extent / spacing)`` clusters for
   a link whose inside probes span ``extent`` [m] at their widest; each centre is a keypoint,
   fixed in the link's frame.

The points depend on the geometry and the two settings only; a model stores them in its card,
so a later change here never changes a shipped model.
"""

from __future__ import annotations

import math

import numpy as np
import pybullet as pb
from scipy.cluster.vq import kmeans2

from nehmo_core.errors import InvalidValueError, ModelFileError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.model import ArmSpec, Cell, LinkPoint, Pose, RobotModel

__all__ = ["POINT_SPACING", "collision_points"]

POINT_SPACING = 0.08
"""[m] A link gets one keypoint per this much of its geometry's extent (at least one)."""


def _link_frame(world: CellWorld, body: int, index: int) -> tuple[np.ndarray, np.ndarray]:
    """World position (3,) and rotation (3, 3) of a link's URDF frame."""
    c = world.client
    if index >= 0:
        state = pb.getLinkState(body, index, computeForwardKinematics=True, physicsClientId=c)
        pos, orn = state[4], state[5]
    else:
        pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=c)
    return np.array(pos), np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)


def _inside(world: CellWorld, body: int, index: int, probe: int, pts: np.ndarray) -> np.ndarray:
    """Mask (N,) of the points ``pts`` (N, 3) [m] that lie inside the link's geometry."""
    c = world.client
    mask = np.zeros(len(pts), dtype=bool)
    for i, p in enumerate(pts):
        pb.resetBasePositionAndOrientation(probe, p.tolist(), (0, 0, 0, 1), physicsClientId=c)
        hits = pb.getClosestPoints(probe, body, 0.0, linkIndexB=index, physicsClientId=c)
        mask[i] = bool(hits) and min(h[8] for h in hits) < 0.0
    return mask


def collision_points(
    robot: RobotModel, spacing: float = POINT_SPACING, grid: float = 0.015, seed: int = 0
) -> tuple[LinkPoint, ...]:
    """Keypoints ``(link, x, y, z)`` in the bulk of every collision link of ``robot``, root to
    tip, rounded to 0.1 mm (see the module docstring)."""
    for name, value in (("spacing", spacing), ("grid", grid)):
        if not value > 0:
            raise InvalidValueError(name, "must be > 0 m", value)
    world = CellWorld(Cell(robot.name, (ArmSpec("arm", robot, Pose()),)))
    try:
        c = world.client
        body = world.body("arm")
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=1e-3, physicsClientId=c)
        probe = pb.createMultiBody(0, shape, basePosition=(50.0, 50.0, 50.0), physicsClientId=c)
        out: list[LinkPoint] = []
        links = world.links("arm")
        names = {index: link for link, index in links.items()}
        for index in links.values():
            owner = index  # the chain link the points are fixed in
            while names[owner] not in robot.links and owner >= 0:
                owner = pb.getJointInfo(body, owner, physicsClientId=c)[16]
            if names[owner] not in robot.links:
                continue
            if not pb.getCollisionShapeData(body, index, physicsClientId=c):
                continue
            lo, hi = (np.array(v) for v in pb.getAABB(body, index, physicsClientId=c))
            axes = [np.arange(lo[i] + grid / 2, hi[i], grid) for i in range(3)]
            pts = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
            inside = pts[_inside(world, body, index, probe, pts)]
            if not len(inside):
                continue  # thinner than the grid: its neighbours' points cover it
            k = max(1, math.ceil(float((inside.max(0) - inside.min(0)).max()) / spacing))
            if k == 1 or len(inside) <= k:
                centres = inside.mean(0, keepdims=True)
            else:
                centres, _ = kmeans2(inside, k, seed=seed, minit="++")
            pos, rot = _link_frame(world, body, owner)
            for centre in centres:
                x, y, z = (round(float(v), 4) for v in rot.T @ (centre - pos))
                out.append((names[owner], x, y, z))
    finally:
        world.close()
    if not out:
        raise ModelFileError(f"robot {robot.name!r}: no collision geometry to place keypoints in")
    return tuple(out)
