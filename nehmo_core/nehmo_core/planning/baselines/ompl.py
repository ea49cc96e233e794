"""OMPL RRT-Connect over the composite joint space of all arms: a centralized sampling peer.

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
from nehmo_core.robots.model import Cell

__all__ = ["OmplResult", "OmplSettings", "plan_rrt_connect"]


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


def _ompl() -> tuple[Any, Any, Any]:
    try:
        from ompl import base, geometric, util
    except ImportError as exc:  # optional dependency
        raise NehmoError(
            "the OMPL baseline needs the PyPI package 'ompl' (pip install ompl==2.0.1)"
        ) from exc
    return base, geometric, util


def plan_rrt_connect(
    cell: Cell,
    start: Mapping[str, np.ndarray],
    goal: Mapping[str, np.ndarray],
    settings: OmplSettings | None = None,
    world: CellWorld | None = None,
) -> OmplResult:
    """Plan all arms jointly from ``start`` to ``goal`` with RRT-Connect."""
    s = settings or OmplSettings()
    ob, og, ou = _ompl()
    ou.setLogLevel(ou.LogLevel.LOG_ERROR)
    if s.seed is not None:
        ou.RNG.setSeed(s.seed)
    lows, highs, sizes = [], [], []
    for arm in cell.arms:  # the joint limits (continuous joints: one turn either way)
        lows.append(np.maximum(arm.robot.lower, -2.0 * np.pi))
        highs.append(np.minimum(arm.robot.upper, 2.0 * np.pi))
        sizes.append(arm.robot.dof)
    low, high = np.concatenate(lows), np.concatenate(highs)
    n = len(low)
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(low[i]))
        bounds.setHigh(i, float(high[i]))
    space.setBounds(bounds)
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
            state = space.allocState()
            for i in range(n):
                state[i] = float(q[i])
            endpoints.append(state)
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
            rows = np.array(
                [[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())]
            )
            waypoints = {a: r.T for a, r in configuration(rows.T).items()}  # (W, dof) each
        return OmplResult(waypoints, time.perf_counter() - t0, solved, checks[0], clearance)
    finally:
        if own_world:
            w.close()
