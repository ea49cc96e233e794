"""How far an arm's collision geometry reaches from its base axis: one rule for which pairs of
arms can touch, used both by the planner (which peers it constrains) and by ``nehmo pair build``
(which base distances a pair's models cover).

Two arms whose bases stand upright (base z axis vertical, any height) can touch only if their
base axes are at most ``reach₁ + reach₂`` apart horizontally, where ``reach`` is the largest
horizontal distance of any point of an arm's collision geometry from its base's vertical axis
over its joint space (a reach measured with every joint free, joint limits included). It is
measured on PyBullet's collision shapes: meshes by their vertices, other shapes by their
world-frame axis-aligned boxes, which contain them (a box can only overstate the reach, the safe
side for "which pairs can touch").
Random configurations can miss the very largest reach, so the rule compares the base distance
with :func:`base_range`'s upper end, the sum rounded *up* to :data:`RANGE_STEP`: the planner
constrains a peer exactly when a pair model must cover it (:func:`can_touch`).

A robot's description may state its reach (``facts.reach_m``, written by ``nehmo robot add``
and checked against a fresh measurement by the tests); otherwise it is measured once per process.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from nehmo_core.errors import InvalidValueError
from nehmo_core.robots.model import ArmSpec, Cell, Pose, RobotModel

__all__ = [
    "REACH_SAMPLES",
    "arm_reach",
    "base_gap",
    "base_range",
    "can_touch",
    "checked_range",
    "horizontal_reach",
]

REACH_SAMPLES = 4000
"""Random configurations per reach measurement (plus every joint at its limits' midpoints)."""
CLIMB_STEPS = 2000
"""Local-search steps after the random draws (spread over :data:`CLIMB_STARTS` starts)."""
CLIMB_STARTS = 8
RANGE_STEP = 0.05
"""[m] A pair's base range is rounded outward to this step."""
MIN_BASE_DISTANCE = 0.25
"""[m] The nearest bases a pair model covers (Ha et al.'s protocol keeps bases >= 0.3 m apart)."""


def horizontal_reach(
    robot: RobotModel, samples: int = REACH_SAMPLES, seed: int = 0, climb: int = CLIMB_STEPS
) -> float:
    """[m] The largest horizontal distance of the arm's collision geometry from its base axis:
    the best of ``samples`` random configurations, then ``climb`` steps of a random local search
    from the best few (random draws alone miss the fully stretched poses by millimetres)."""
    import pybullet as pb

    from nehmo_core.geometry.pybullet_world import CellWorld

    world = CellWorld(Cell(f"reach_{robot.name}", (ArmSpec("arm", robot, Pose()),)))
    try:
        body, client = world.body("arm"), world.client
        links = [-1, *range(pb.getNumJoints(body, physicsClientId=client))]
        rng = np.random.default_rng(seed)
        lo, hi = np.maximum(robot.lower, -math.pi), np.minimum(robot.upper, math.pi)

        # Mesh shapes by their vertices (in the link's inertial frame, as PyBullet keeps them;
        # the largest horizontal distance over a mesh's hull is at a vertex), other shapes by
        # their world-frame boxes (which contain them).
        vertices = {}
        for link in links[1:]:  # the base does not move: its box
            count, points = pb.getMeshData(body, link, physicsClientId=client)
            if count:
                vertices[link] = np.asarray(points, dtype=float)

        def reach(q: np.ndarray) -> float:
            world.set_joint_positions("arm", q)
            best = 0.0
            for link in links:
                if link in vertices:
                    state = pb.getLinkState(
                        body, link, computeForwardKinematics=True, physicsClientId=client
                    )
                    R = np.reshape(pb.getMatrixFromQuaternion(state[1]), (3, 3))
                    xy = vertices[link] @ R[:2].T + np.asarray(state[0][:2])
                    best = max(best, float(np.hypot(xy[:, 0], xy[:, 1]).max()))
                    continue
                a, b = pb.getAABB(body, link, physicsClientId=client)
                best = max(best, math.hypot(max(abs(a[0]), abs(b[0])), max(abs(a[1]), abs(b[1]))))
            return best

        draws = rng.uniform(lo, hi, size=(samples, robot.dof))
        values = np.array([reach(q) for q in draws])
        best = float(values.max())
        for start in np.argsort(values)[-CLIMB_STARTS:]:
            q, value, step = draws[start], values[start], 0.2
            for _ in range(climb // CLIMB_STARTS):
                trial = np.clip(q + rng.normal(0.0, step, robot.dof), lo, hi)
                if (v := reach(trial)) > value:
                    q, value = trial, v
                else:
                    step = max(0.98 * step, 1e-3)
            best = max(best, float(value))
        return best
    finally:
        world.close()


def checked_range(base_range: tuple[float, float] | None, tag: str) -> tuple[float, float] | None:
    """A pair build's ``--base-range`` and ``--tag``, checked: a part of the distances needs a
    tag of its own (the pair is then ``A_B_<tag>``)."""
    if not (tag.isidentifier() and tag.islower()):
        raise InvalidValueError("--tag", "must be a lower-case word (letters, digits, _)", tag)
    if base_range is None:
        return None
    low, high = float(base_range[0]), float(base_range[1])
    if not MIN_BASE_DISTANCE <= low < high:
        rule = f"must be LOW HIGH [m] with {MIN_BASE_DISTANCE} <= LOW < HIGH"
        raise InvalidValueError("--base-range", rule, list(base_range))
    if tag == "any":
        rule = "covers a part of the base distances, so it needs a --tag (e.g. far)"
        raise InvalidValueError("--base-range", rule, list(base_range))
    return low, high


def base_range(reach_1: float, reach_2: float) -> tuple[float, float]:
    """[m] Base distances at which two arms of these reaches can touch, rounded outward."""
    high = math.ceil((reach_1 + reach_2) / RANGE_STEP) * RANGE_STEP
    return MIN_BASE_DISTANCE, round(high, 3)


@functools.cache
def arm_reach(robot: RobotModel) -> float:
    """[m] The robot's horizontal reach: its description's ``facts.reach_m`` when stated, else
    :func:`horizontal_reach` (:data:`REACH_SAMPLES`, seed 0) measured once per process."""
    if robot.facts.reach_m is not None:
        return robot.facts.reach_m
    return horizontal_reach(robot)


def _upright(pose: Pose) -> bool:
    return abs(abs(pose.matrix()[2, 2]) - 1.0) < 1e-9


def base_gap(a: ArmSpec, b: ArmSpec) -> float:
    """[m] Horizontal distance between two arms' base axes."""
    return float(np.hypot(*np.subtract(b.base.xyz, a.base.xyz)[:2]))


def can_touch(a: ArmSpec, b: ArmSpec, margin: float = 0.0) -> bool:
    """Whether two arms' collision geometry can meet: their base axes are at most
    ``base_range(reach_a, reach_b)[1] + margin`` apart. Arms whose bases do not stand upright
    are always taken to touch (the horizontal rule does not hold for them)."""
    if not (_upright(a.base) and _upright(b.base)):
        return True
    return base_gap(a, b) <= base_range(arm_reach(a.robot), arm_reach(b.robot))[1] + margin
