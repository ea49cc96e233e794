"""How a simulated arm carries out velocity commands: ideal, or like a real arm.

The paper's model is ``q̇ = u``: a command takes effect at once. A real arm tracks a velocity
command under joint acceleration limits, gets it after a transport and controller delay, and its
joint states are read with noise. :class:`ActuatorModel` states all three; :class:`ArmTracker`
carries one arm's commands out under it.

* ``accel`` [rad/s²] per joint: the velocity moves toward the command at most this fast
  (rate-limited first-order tracking); ``None``: at once.
* ``latency`` [s]: a command takes effect this long after it is sent (on top of the one control
  period a batch episode already waits between a plan and its command).
* ``noise`` [rad]: standard deviation of the Gaussian noise on each joint state the planners
  read (the simulator keeps the true state; collisions and metrics use it).

Named models (:data:`ACTUATOR_MODELS`): ``ideal`` is today's simulator exactly (the paper's
tables keep it); ``realistic`` takes each joint's acceleration limit from the robot's
description (``facts.accel_limits``, with the source stated there), :data:`REALISTIC_LATENCY`
and :data:`REALISTIC_NOISE`; ``limits`` has the same acceleration limits and neither latency nor
noise (the part of ``realistic`` that changes outcomes; a deterministic closed loop).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.robots.model import Cell, RobotModel

__all__ = [
    "ACTUATOR_MODELS",
    "REALISTIC_LATENCY",
    "REALISTIC_NOISE",
    "ActuatorModel",
    "ArmTracker",
    "actuator_model",
    "cell_actuators",
    "certificate_actuators",
]

ACTUATOR_MODELS = ("ideal", "realistic", "limits")
REALISTIC_LATENCY = 0.012
"""[s] Command latency of the ``realistic`` model: a few control cycles of a UR controller
(125–500 Hz) plus a DDS hop."""
REALISTIC_NOISE = 2e-4
"""[rad] Joint-state noise (standard deviation) of the ``realistic`` model, about ten encoder
counts of a 17-bit joint encoder."""
INTEGRATION_STEP = 0.001
"""[s] Step at which non-ideal tracking is integrated (latency resolves to it)."""


@dataclass(frozen=True)
class ActuatorModel:
    """Acceleration limits, command latency and state noise of one arm (see the module)."""

    name: str = "ideal"
    accel: tuple[float, ...] | None = None
    latency: float = 0.0
    noise: float = 0.0

    def __post_init__(self) -> None:
        if self.accel is not None and not all(a > 0 and math.isfinite(a) for a in self.accel):
            rule = "must be > 0 and finite per joint [rad/s²]"
            raise InvalidValueError("accel", rule, self.accel)
        if not 0.0 <= self.latency < math.inf:
            raise InvalidValueError("latency", "must be >= 0 and finite [s]", self.latency)
        if not 0.0 <= self.noise < math.inf:
            raise InvalidValueError("noise", "must be >= 0 and finite [rad]", self.noise)

    @property
    def ideal(self) -> bool:
        """No limit, no delay, no noise: ``q̇ = u``."""
        return self.accel is None and self.latency == 0.0 and self.noise == 0.0

    def describe(self) -> dict[str, object]:
        """The model as plain data (episode metadata, certificates)."""
        return {
            "name": self.name,
            "accel": None if self.accel is None else list(self.accel),
            "latency": self.latency,
            "noise": self.noise,
        }


def actuator_model(name: str, robot: RobotModel) -> ActuatorModel:
    """The named model (:data:`ACTUATOR_MODELS`) for ``robot``; ``realistic`` and ``limits``
    need the robot's acceleration limits in its description."""
    if name == "ideal":
        return ActuatorModel()
    if name not in ACTUATOR_MODELS:
        raise UnknownNameError("actuator model", name, ACTUATOR_MODELS)
    accel = robot.facts.accel_limits
    if accel is None:
        raise InvalidValueError(
            "actuators",
            f"{name!r} needs facts.accel_limits in the description of robot {robot.name!r}",
            name,
        )
    if len(accel) != robot.dof:
        raise InvalidValueError(
            f"{robot.name}: facts.accel_limits", f"must give all {robot.dof} joints", accel
        )
    if name == "limits":
        return ActuatorModel("limits", tuple(accel))
    return ActuatorModel("realistic", tuple(accel), REALISTIC_LATENCY, REALISTIC_NOISE)


def certificate_actuators(certificate: Mapping[str, Any]) -> str:
    """The name of the actuator model a model card's certificate holds for (``nehmo verify
    --actuators``; a certificate that names none was made with ideal tracking)."""
    return str((certificate.get("actuators") or {}).get("name", "ideal"))


def cell_actuators(cell: Cell, name: str) -> dict[str, ActuatorModel]:
    """The named model for every arm of ``cell``."""
    return {a.arm_id: actuator_model(name, a.robot) for a in cell.arms}


class ArmTracker:
    """One arm's actuator state: the joint velocity it moves at and the commands in flight."""

    def __init__(self, model: ActuatorModel, dof: int, seed: int = 0) -> None:
        if model.accel is not None and len(model.accel) != dof:
            raise InvalidValueError("accel", f"must give all {dof} joints", model.accel)
        self.model = model
        self.dof = dof
        self.seed = seed
        self.accel = None if model.accel is None else np.asarray(model.accel, dtype=float)
        self.reset()

    def reset(self, seed: int | None = None) -> None:
        """At rest, nothing in flight, the noise stream from the start of ``seed`` (default:
        the tracker's)."""
        if seed is not None:
            self.seed = seed
        self.velocity = np.zeros(self.dof)
        self.active = np.zeros(self.dof)  # the command being tracked
        self.flight: deque[tuple[float, np.ndarray]] = deque()  # (takes effect at [s], u)
        self.rng = np.random.default_rng(self.seed)

    def send(self, time: float, u: np.ndarray) -> None:
        """A command sent at ``time`` [s]; it takes effect ``latency`` later."""
        self.flight.append((time + self.model.latency, np.array(u, dtype=float)))

    def advance(self, q: np.ndarray, time: float, dt: float) -> np.ndarray:
        """Joint positions after ``dt`` [s] from ``q`` at ``time`` [s] (not clamped)."""
        n = max(1, math.ceil(dt / INTEGRATION_STEP - 1e-9))
        h = dt / n
        q = q.copy()
        for i in range(n):
            now = time + i * h
            while self.flight and self.flight[0][0] <= now + 1e-12:
                self.active = self.flight.popleft()[1]
            before = self.velocity
            if self.accel is None:  # a step change at the boundary: this velocity throughout
                after = self.active.copy()
                q += after * h
            else:  # a ramp: the mean of its two ends
                after = before + np.clip(self.active - before, -self.accel * h, self.accel * h)
                q += 0.5 * (before + after) * h
            self.velocity = after
        return q

    def observe(self, q: np.ndarray) -> np.ndarray:
        """The joint state a planner reads: ``q`` with the model's noise."""
        if self.model.noise == 0.0:
            return q.copy()
        return q + self.rng.normal(0.0, self.model.noise, self.dof)
