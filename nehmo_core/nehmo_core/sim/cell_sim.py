"""Kinematic simulation of a cell: velocity commands integrated, collisions checked exactly.

Arms are velocity controlled. :meth:`CellSimulator.step` integrates every arm's command over
``dt`` [s] and checks every arm pair and every arm's self-collision at ``substeps`` evenly
spaced instants inside the step, so a fast pass through another arm is not missed. The same
class serves the batch episode runner and the ROS simulation bridge.

How an arm carries a command out is its actuator model (:mod:`nehmo_core.sim.actuators`):
``ideal`` (the default, the paper's ``q̇ = u``) or ``realistic`` (acceleration-limited tracking,
command latency, noisy joint states from :meth:`CellSimulator.observed`).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.pybullet_world import CellWorld, Collision
from nehmo_core.robots.model import Cell
from nehmo_core.sim.actuators import ActuatorModel, ArmTracker, cell_actuators


@dataclass
class StepResult:
    """What happened during one :meth:`CellSimulator.step`."""

    collisions: list[Collision] = field(default_factory=list)
    time: float = 0.0  # simulated time at the end of the step [s]

    @property
    def collided(self) -> bool:
        return bool(self.collisions)


class CellSimulator:
    """Joint positions of every arm of ``cell``, advanced by velocity commands."""

    def __init__(
        self,
        cell: Cell,
        substeps: int = 10,
        self_collision: bool = True,
        actuators: str | Mapping[str, ActuatorModel] = "ideal",
        seed: int = 0,
    ) -> None:
        if not substeps >= 1 or int(substeps) != substeps:  # not 0, 2.5 or NaN
            raise InvalidValueError("substeps", "must be an int >= 1", substeps)
        models = cell_actuators(cell, actuators) if isinstance(actuators, str) else actuators
        missing = sorted(set(cell.arm_ids) - set(models))
        if missing:
            raise InvalidValueError("actuators", f"must give every arm (missing {missing})", models)
        self.cell = cell
        self.substeps = int(substeps)
        self.self_collision = self_collision
        self.actuators = dict(models)
        # each arm's noise stream from the seed and its place in the cell
        self.trackers = {
            a.arm_id: ArmTracker(self.actuators[a.arm_id], a.robot.dof, seed=seed * 1000 + i)
            for i, a in enumerate(cell.arms)
        }
        self.ideal = all(m.ideal for m in self.actuators.values())
        self.world = CellWorld(cell)
        self.time = 0.0
        self.q: dict[str, np.ndarray] = {a.arm_id: np.zeros(a.robot.dof) for a in cell.arms}

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> CellSimulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reset(self, q: Mapping[str, ArrayLike], time: float = 0.0, seed: int | None = None) -> None:
        """Set every arm's joint positions [rad] (all arms must be given), at rest; ``seed``
        restarts the sensor noise streams from a new seed (default: the simulator's)."""
        missing = set(self.cell.arm_ids) - set(q)
        if missing:
            raise InvalidValueError(
                "q", f"must give every arm (missing {sorted(missing)})", list(q)
            )
        for arm_id, qa in q.items():
            robot = self.cell.arm(arm_id).robot
            self.q[arm_id] = robot.check_within_limits(qa, f"q[{arm_id}]").copy()
        self.world.set_configuration(self.q)
        self.time = time
        for i, tracker in enumerate(self.trackers.values()):
            tracker.reset(None if seed is None else seed * 1000 + i)

    def collisions(self) -> list[Collision]:
        """Collisions in the current configuration."""
        self.world.set_configuration(self.q)
        return self.world.collisions(self_collision=self.self_collision)

    def step(self, commands: Mapping[str, ArrayLike], dt: float) -> StepResult:
        """Integrate joint velocities ``commands`` [rad/s] over ``dt`` [s].

        Arms without a command hold still (are commanded zero); a command for an arm the cell
        does not have, or faster than a joint's velocity limit, is an error. An ideal arm moves
        at its command throughout; any other is carried by its actuator model from the command
        sent at the step's start. Joint positions are clamped to the joint limits.
        Collisions are checked at ``substeps`` instants; the first colliding instant ends the
        check (the configuration is still advanced over the whole step).
        """
        if not 0 < dt < math.inf:
            raise InvalidValueError("dt", "must be > 0 and finite [s]", dt)
        unknown = sorted(set(commands) - set(self.cell.arm_ids))
        if unknown:
            raise InvalidValueError(
                "commands",
                f"must name arms of cell {self.cell.name!r} {list(self.cell.arm_ids)}",
                unknown,
            )
        start = {k: v.copy() for k, v in self.q.items()}
        vel = {}
        for arm in self.cell.arms:
            u = commands.get(arm.arm_id)
            if u is None:
                vel[arm.arm_id] = np.zeros(arm.robot.dof)
                continue
            v = arm.robot.check_q(u, f"command[{arm.arm_id}]")
            limit = np.array([j.velocity for j in arm.robot.joints])
            if np.any(np.abs(v) > limit + 1e-9):
                raise InvalidValueError(
                    f"command[{arm.arm_id}]",
                    f"must respect the joint velocity limits {limit.tolist()} [rad/s]",
                    v.tolist(),
                )
            vel[arm.arm_id] = v
        result = StepResult()
        if not self.ideal:
            for arm in self.cell.arms:
                self.trackers[arm.arm_id].send(self.time, vel[arm.arm_id])
        for k in range(1, self.substeps + 1):
            s = dt * k / self.substeps
            for arm in self.cell.arms:
                if self.ideal:
                    q = start[arm.arm_id] + s * vel[arm.arm_id]
                else:  # the tracker carries the arm over one sub-step
                    h, t0 = dt / self.substeps, self.time + dt * (k - 1) / self.substeps
                    q = self.trackers[arm.arm_id].advance(self.q[arm.arm_id], t0, h)
                self.q[arm.arm_id] = np.clip(q, arm.robot.lower, arm.robot.upper)
            if not result.collisions:
                result.collisions = self.collisions()
        self.time += dt
        result.time = self.time
        return result

    def positions(self) -> dict[str, np.ndarray]:
        """Every arm's true joint positions [rad]."""
        return {k: v.copy() for k, v in self.q.items()}

    def velocities(self, commands: Mapping[str, np.ndarray]) -> dict[str, np.ndarray]:
        """The joint velocity [rad/s] each arm moves at after the last step: ``commands`` (what
        was applied) for an ideal cell, each tracker's velocity otherwise."""
        if self.ideal:
            return dict(commands)
        return {a: self.trackers[a].velocity.copy() for a in commands}

    def observed(self) -> dict[str, np.ndarray]:
        """Every arm's joint positions as its sensors read them (the actuator model's noise;
        the true positions for an ideal arm)."""
        return {k: self.trackers[k].observe(v) for k, v in self.q.items()}
