"""OMPL RRT-Connect over the composite joint space of all arms: a centralized sampling peer
(:func:`plan_rrt_connect`), and over one arm's joints with the others frozen
(:func:`plan_arm_alone`, a diagnostic of what a standing peer leaves free).

The state is every arm's joint vector stacked in the cell's arm order, bounded per joint by
the joint limits (continuous joints: one turn either way); start and goal are used as given.
A PyBullet :class:`~nehmo_core.geometry.pybullet_world.CellWorld` checks each state exactly
(arm-arm and self collisions). Settings follow the expert planner of Ha et al.: 0.1 rad steps,
shortcutting, a time limit instead of an iteration count.

A state is valid only with ``clearance`` [m] to spare. Shortcutting pulls a path tight against
the obstacles it passes, and the arms then follow it only approximately (a tracker cuts the
corners between control ticks, and the motion between two validity checks is not checked), so
a path planned at zero clearance grazes in execution: with ``clearance = 0`` and 0.05 rad
checks, 15 of 100 dual-UR5 episodes touched the other arm by fractions of a millimetre.
The Python validity callback is the bottleneck (a few thousand checks per second).

OMPL's random generator is process-wide and takes its seed only before its first use, so only
the first plan of a process is reproducible from ``seed``; later plans in the same process
depend on what the process planned before.

Needs the PyPI ``ompl`` package (2.0.1); it is imported on first use.
"""

from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.model import Cell, RobotModel

__all__ = ["ArmPath", "OmplResult", "OmplSettings", "plan_arm_alone", "plan_rrt_connect"]


@dataclass(frozen=True)
class OmplSettings:
    time_limit: float = 30.0  # [s]
    step: float = 0.1  # RRT-Connect range [rad]
    check_step: float = 0.02  # motion validity checked every this many rad (L2 in joint space)
    clearance: float = 0.01  # [m] a state closer than this to a collision is invalid
    simplify: bool = True  # shortcutting and smoothing of the solution path
    seed: int | None = 0

    def __post_init__(self) -> None:
        for name in ("time_limit", "step", "check_step"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        if not self.clearance >= 0:
            raise InvalidValueError("clearance", "must be >= 0 [m]", self.clearance)


@dataclass(frozen=True)
class OmplResult:
    waypoints: Mapping[str, np.ndarray]  # (W, dof) per arm; empty when not solved
    plan_time: float
    solved: bool
    checks: int  # validity checks made
    clearance: float = 0.0  # [m] the clearance the plan kept (below the setting near an endpoint)


@dataclass(frozen=True)
class ArmPath:
    """One arm's path with every other arm frozen (:func:`plan_arm_alone`)."""

    waypoints: np.ndarray  # (W, dof) after shortcutting; no rows when none was found
    plan_time: float  # [s]
    blocked: str = ""  # "start" or "goal": that end is not a valid state (nothing searched)

    @property
    def solved(self) -> bool:
        return len(self.waypoints) > 0

    @property
    def length(self) -> float:
        """[rad] summed over the segments (L2 in joint space); 0 when none was found."""
        return float(np.linalg.norm(np.diff(self.waypoints, axis=0), axis=1).sum())


def _ompl(seed: int | None) -> tuple[Any, Any]:
    """OMPL's ``base`` and ``geometric`` modules, its log quiet and its generator seeded with
    ``seed`` (unless None; process-wide, see the module notes)."""
    try:
        from ompl import base, geometric, util
    except ImportError as exc:  # optional dependency
        raise NehmoError(
            "the OMPL baseline needs the PyPI package 'ompl' (pip install ompl==2.0.1)"
        ) from exc
    util.setLogLevel(util.LogLevel.LOG_ERROR)
    if seed is not None:
        util.RNG.setSeed(seed)
    return base, geometric


def _joint_space(ob: Any, low: np.ndarray, high: np.ndarray) -> Any:
    """A real-vector state space bounded by ``low`` and ``high``."""
    space = ob.RealVectorStateSpace(len(low))
    bounds = ob.RealVectorBounds(len(low))
    for i, (lo, hi) in enumerate(zip(low, high, strict=True)):
        bounds.setLow(i, float(lo))
        bounds.setHigh(i, float(hi))
    space.setBounds(bounds)
    return space


def _limits(robot: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """Planning bounds of one arm: its joint limits, continuous joints one turn either way."""
    return np.maximum(robot.lower, -2.0 * np.pi), np.minimum(robot.upper, 2.0 * np.pi)


def _state(space: Any, q: np.ndarray) -> Any:
    state = space.allocState()
    for i, v in enumerate(q):
        state[i] = float(v)
    return state


def _path_rows(path: Any, n: int) -> np.ndarray:
    """A geometric path's states as rows (W, n)."""
    return np.array([[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())])


def plan_rrt_connect(
    cell: Cell,
    start: Mapping[str, np.ndarray],
    goal: Mapping[str, np.ndarray],
    settings: OmplSettings | None = None,
    world: CellWorld | None = None,
) -> OmplResult:
    """Plan all arms jointly from ``start`` to ``goal`` with RRT-Connect."""
    s = settings or OmplSettings()
    ob, og = _ompl(s.seed)
    limits = [_limits(arm.robot) for arm in cell.arms]
    sizes = [arm.robot.dof for arm in cell.arms]
    low, high = (np.concatenate(side) for side in zip(*limits, strict=True))
    n = len(low)
    space = _joint_space(ob, low, high)
    own_world = world is None
    w = world if world is not None else CellWorld(cell)
    checks = [0]
    splits = np.cumsum(sizes)[:-1]

    def configuration(values: np.ndarray) -> dict[str, np.ndarray]:
        parts = np.split(values, splits)
        return {a.arm_id: p for a, p in zip(cell.arms, parts, strict=True)}

    def valid(state: Any) -> bool:
        checks[0] += 1
        w.set_configuration(configuration(np.array([state[i] for i in range(n)])))
        return not w.in_collision(margin=clearance)

    clearance = s.clearance
    for values in (start, goal):  # an endpoint closer than the clearance lowers it (to half)
        w.set_configuration({a.arm_id: np.asarray(values[a.arm_id], float) for a in cell.arms})
        near = w.collisions(margin=clearance)
        if near:
            clearance = max(0.0, 0.5 * min(c.distance for c in near))

    t0 = time.perf_counter()
    try:
        ss = og.SimpleSetup(space)
        ss.setStateValidityChecker(valid)
        si = ss.getSpaceInformation()
        si.setStateValidityCheckingResolution(s.check_step / space.getMaximumExtent())
        endpoints = []
        for name, values in (("start", start), ("goal", goal)):
            # as given, not wrapped: the path must begin where the arms are and end where the
            # other planners' goals are (each tracker follows it joint by joint)
            q = np.concatenate([np.asarray(values[a.arm_id], dtype=float) for a in cell.arms])
            outside = np.flatnonzero((q < low) | (q > high))
            if len(outside):
                raise InvalidValueError(
                    name, f"joints {outside.tolist()} must lie in the planning bounds", q.tolist()
                )
            endpoints.append(_state(space, q))
        ss.setStartAndGoalStates(endpoints[0], endpoints[1])
        planner = og.RRTConnect(si)
        planner.setRange(s.step)
        ss.setPlanner(planner)
        solved = bool(ss.solve(s.time_limit)) and ss.haveExactSolutionPath()
        waypoints: dict[str, np.ndarray] = {}
        if solved:
            if s.simplify:
                ss.simplifySolution()
            path = ss.getSolutionPath()
            path.interpolate(max(2, int(np.ceil(path.length() / s.step)) + 1))
            rows = _path_rows(path, n)
            waypoints = {a: r.T for a, r in configuration(rows.T).items()}  # (W, dof) each
        return OmplResult(waypoints, time.perf_counter() - t0, solved, checks[0], clearance)
    finally:
        if own_world:
            w.close()


def plan_arm_alone(
    cell: Cell,
    arm_id: str,
    configuration: Mapping[str, np.ndarray],
    goal: np.ndarray,
    clearance: float,
    time_limit: float = 2.0,
    seed: int | None = 0,
    world: CellWorld | None = None,
) -> ArmPath:
    """RRT-Connect for arm ``arm_id`` alone from ``configuration[arm_id]`` to ``goal``, every
    other arm frozen where ``configuration`` poses it: a valid state keeps ``clearance`` [m] from
    every other arm and is free of self-collision; motions are checked every 0.02 rad. The path
    is shortcut; ``blocked`` names an end that is not valid (then nothing is searched)."""
    if not clearance >= 0:
        raise InvalidValueError("clearance", "must be >= 0 [m]", clearance)
    if not time_limit > 0:
        raise InvalidValueError("time_limit", "must be > 0 [s]", time_limit)
    ob, og = _ompl(seed)
    robot = cell.arm(arm_id).robot
    low, high = _limits(robot)
    peers = [a for a in cell.arm_ids if a != arm_id]
    own_world = world is None
    w = world if world is not None else CellWorld(cell)

    def fits(q: np.ndarray) -> bool:
        w.set_joint_positions(arm_id, q)
        far = all(w.distance(arm_id, p, clearance) >= clearance for p in peers)
        return far and not w.self_collisions(arm_id)

    t0 = time.perf_counter()
    try:
        w.set_configuration({a: np.asarray(configuration[a], float) for a in cell.arm_ids})
        start = np.asarray(configuration[arm_id], float)
        goal = np.asarray(goal, float)
        none = np.zeros((0, robot.dof))
        for name, q in (("start", start), ("goal", goal)):
            if np.any((q < low) | (q > high)) or not fits(q):
                return ArmPath(none, time.perf_counter() - t0, name)
        space = _joint_space(ob, low, high)
        ss = og.SimpleSetup(space)
        ss.setStateValidityChecker(
            lambda state: fits(np.array([state[i] for i in range(robot.dof)]))
        )
        ss.getSpaceInformation().setStateValidityCheckingResolution(0.02 / space.getMaximumExtent())
        ss.setStartAndGoalStates(_state(space, start), _state(space, goal))
        planner = og.RRTConnect(ss.getSpaceInformation())
        planner.setRange(0.1)
        ss.setPlanner(planner)
        if not (ss.solve(time_limit) and ss.haveExactSolutionPath()):
            return ArmPath(none, time.perf_counter() - t0)
        ss.simplifySolution()
        rows = _path_rows(ss.getSolutionPath(), robot.dof)
        return ArmPath(rows, time.perf_counter() - t0)
    finally:
        if own_world:
            w.close()
