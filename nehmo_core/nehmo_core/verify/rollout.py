"""Closed-loop HJI rollouts: learned safe control against an adversary, judged by exact geometry.

From each state ``x₀`` the controlled agent applies ``u = argmax_u <∇V(τ − t, x), g>`` (for arms
``ū·sign(∂V/∂q¹)``), re-evaluated every step ``dt``, while the adversary plays its strategy; the
state is integrated by explicit Euler with periodic coordinates wrapped to ``(−π, π]``. The result
is the smallest exact margin met on the way (time 0 included); a rollout violates when it is
``≤ 0``. The control is held for ``dt`` (default 10 ms), 4× finer than the planner's 40 ms tick.

Under an actuator model (:class:`~nehmo_core.sim.actuators.ActuatorModel`: acceleration limits,
latency, state noise) the controlled agent does not move at its control: its velocity moves toward
the control at most at its acceleration limits, the control takes effect ``latency`` after it is
chosen, and it is chosen from the state read with Gaussian noise on the joints. Each rollout
starts in the worst case for a fail-safe: moving at full speed against its first control (the
reversal), with that opposite command also in flight for the latency. The adversary stays ideal.
"""

from __future__ import annotations

import math
from collections import deque
from typing import Any, Protocol

import numpy as np
import torch
from torch import Tensor

from nehmo_core.errors import InvalidValueError
from nehmo_core.hjr.systems import HJISystem, wrap_to_pi
from nehmo_core.sim.actuators import ActuatorModel
from nehmo_core.verify.adversaries import Adversary
from nehmo_core.verify.truth import ExactMargin


class ValueModel(Protocol):
    """What a rollout needs of a value function (``ValueFunction`` and test doubles)."""

    system: HJISystem

    def value_and_gradient(self, tau: Any, x: Any) -> tuple[Any, Any]: ...


def _wrap(system: HJISystem, x: Tensor) -> Tensor:
    mask = torch.as_tensor(system.periodic, dtype=torch.bool)
    return torch.where(mask, wrap_to_pi(x), x) if bool(mask.any()) else x


def rollout_margins(
    value: ValueModel,
    margin: ExactMargin,
    x0: np.ndarray,
    tau: float,
    adversary: Adversary,
    dt: float = 0.01,
    contact_cutoff: float = 0.05,
    actuator: ActuatorModel | None = None,
    noise_seed: int = 0,
) -> np.ndarray:
    """Smallest exact margin [m] over ``[0, tau]`` of each rollout from ``x0 (B, n)``, ``(B,)``.

    Margins above ``contact_cutoff`` [m] may be reported as the cutoff (only contact matters).
    ``actuator``: how the controlled agent follows its control (None or ideal: at once);
    ``noise_seed`` seeds its state noise.
    """
    if not tau > 0:
        raise InvalidValueError("tau", "must be > 0", tau)
    if not dt > 0:
        raise InvalidValueError("dt", "must be > 0", dt)
    system = value.system
    steps = max(1, math.ceil(tau / dt - 1e-9))
    h = tau / steps
    x = torch.as_tensor(np.asarray(x0), dtype=torch.float32)
    smallest = margin(x.double().numpy(), contact_cutoff)
    joints = getattr(system, "n1", 0) + getattr(system, "n2", 0) or x.shape[1]
    track = (
        None if actuator is None or actuator.ideal else _Tracking(actuator, h, joints, noise_seed)
    )
    for s in range(steps):
        read = x if track is None else track.read(x)
        _, grad = value.value_and_gradient(tau - s * h, read)
        grad = torch.as_tensor(grad, dtype=x.dtype)
        u = system.optimal_control(read, grad)
        if track is not None:
            u = track.follow(u)
        d = adversary.disturbance(s, x, grad).to(x.dtype)
        x = _wrap(system, x + h * system.dynamics(x, u, d))
        smallest = np.minimum(smallest, margin(x.double().numpy(), contact_cutoff))
    return smallest


class _Tracking:
    """The controlled agent's actuator state in a batch of rollouts (module docstring)."""

    def __init__(self, model: ActuatorModel, h: float, joints: int, seed: int) -> None:
        self.model, self.h = model, h
        self.lag = round(model.latency / h)  # whole rollout steps
        self.joints = joints  # the first coordinates: both agents' joints (not the conditions)
        self.rng = torch.Generator().manual_seed(seed)
        self.velocity: Tensor | None = None  # set from the first control (the reversal)
        self.pending: deque[Tensor] = deque()

    def read(self, x: Tensor) -> Tensor:
        """The state the controller reads."""
        if self.model.noise == 0.0:
            return x
        noise = x.new_zeros(x.shape)
        shape = (x.shape[0], self.joints)
        noise[:, : self.joints] = torch.randn(shape, generator=self.rng, dtype=torch.float64)
        return x + self.model.noise * noise

    def follow(self, u: Tensor) -> Tensor:
        """The velocity the agent moves at this step, given its control ``u`` now."""
        if self.velocity is None:
            self.velocity = -u  # moving at full speed against its first control
            self.pending.extend(-u for _ in range(self.lag))
        self.pending.append(u)
        target = self.pending.popleft()
        if self.model.accel is None:
            self.velocity = target
        else:
            reach = self.h * torch.as_tensor(self.model.accel, dtype=u.dtype)
            self.velocity = self.velocity + torch.clamp(target - self.velocity, -reach, reach)
        return self.velocity


def rollout_worst(
    value: ValueModel,
    margin: ExactMargin,
    x0: np.ndarray,
    tau: float,
    adversaries: list[Adversary],
    dt: float = 0.01,
    actuator: ActuatorModel | None = None,
    noise_seed: int = 0,
) -> tuple[np.ndarray, list[str]]:
    """The smallest margin over every adversary, ``(B,)``, and the name of the one that got it
    (``actuator``, ``noise_seed``: as :func:`rollout_margins`)."""
    margins = np.stack(
        [
            rollout_margins(value, margin, x0, tau, a, dt, actuator=actuator, noise_seed=noise_seed)
            for a in adversaries
        ]
    )
    worst = margins.argmin(axis=0)
    return margins.min(axis=0), [adversaries[i].name for i in worst]
