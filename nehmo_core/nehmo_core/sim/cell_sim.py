"""Kinematic simulation of a cell: velocity commands integrated, collisions checked exactly.

Arms are velocity controlled (``q̇ = u``). :meth:`CellSimulator.step` integrates every arm's
command over ``dt`` [s] and checks every arm pair and every arm's self-collision at
``substeps`` evenly spaced instants inside the step, so a fast pass through another arm is
not missed. The same class serves the batch episode runner and the ROS simulation bridge.
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

    def __init__(self, cell: Cell, substeps: int = 10, self_collision: bool = True) -> None:
        if not substeps >= 1 or int(substeps) != substeps:  # not 0, 2.5 or NaN
            raise InvalidValueError("substeps", "must be an int >= 1", substeps)
        self.cell = cell
        self.substeps = int(substeps)
        self.self_collision = self_collision
        self.world = CellWorld(cell)
        self.time = 0.0
        self.q: dict[str, np.ndarray] = {a.arm_id: np.zeros(a.robot.dof) for a in cell.arms}

    def close(self) -> None:
        self.world.close()

    def __enter__(self) -> CellSimulator:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def reset(self, q: Mapping[str, ArrayLike], time: float = 0.0) -> None:
        """Set every arm's joint positions [rad] (all arms must be given)."""
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

    def collisions(self) -> list[Collision]:
        """Collisions in the current configuration."""
        self.world.set_configuration(self.q)
        return self.world.collisions(self_collision=self.self_collision)

    def step(self, commands: Mapping[str, ArrayLike], dt: float) -> StepResult:
        """Integrate joint velocities ``commands`` [rad/s] over ``dt`` [s].

        Arms without a command hold still; a command for an arm the cell does not have, or
        faster than a joint's velocity limit, is an error. Joint positions are clamped to the
        joint limits.
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
        for k in range(1, self.substeps + 1):
            s = dt * k / self.substeps
            for arm in self.cell.arms:
                q = start[arm.arm_id] + s * vel[arm.arm_id]
                self.q[arm.arm_id] = np.clip(q, arm.robot.lower, arm.robot.upper)
            if not result.collisions:
                result.collisions = self.collisions()
        self.time += dt
        result.time = self.time
        return result

    def positions(self) -> dict[str, np.ndarray]:
        return {k: v.copy() for k, v in self.q.items()}
