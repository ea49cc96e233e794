"""Overloaded planner processes in the batch runner: ticks that run late, and what arms then do.

On a loaded machine a planner process can stall (the interpreter lock, the scheduler): its
timer ticks run late, so for a while it publishes no command, then catches up. What the arm does
meanwhile is the actuator side's rule, and what the late tick publishes is the planner's:

* the bridge (or a real controller) keeps applying the last command it received for
  ``hold_ticks`` periods after it arrived, then holds the arm still. The planner certified that
  command for **one** period, so holding it longer moves the arm on a command nobody checked.
  The default, 1, is the bridge's ``command_validity`` (0.06 s: one period plus jitter); 5 is
  a controller with only the 0.2 s watchdog (the bridge before ``command_validity``);
* the late tick has the solve it had started before the stall, planned from an observation
  several periods old; with ``expire_stale`` (the default, as ``arm_planner``'s ``late_plan``
  rule) it publishes zero instead of a command planned more than one period before, without it
  it publishes that command.

:class:`Stalls` states the model: each tick every planner process that is not stalled starts a
stall with probability ``rate``, lasting 1 to ``max_ticks`` periods (uniform), during which its
arms publish and plan nothing. Arms are spread over ``processes`` processes round robin (0: one
per arm), as ``orchestrate`` groups them. The default (``rate`` 0) is no stall at all, so the
episode is exactly the paper's loop.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from nehmo_core.errors import InvalidValueError

__all__ = ["SYNTAX", "StallSchedule", "Stalls", "parse_stalls"]


@dataclass(frozen=True)
class Stalls:
    """Stall rate and length, process count, and the late-command rules (see the module)."""

    rate: float = 0.0  # chance per tick and process that a stall starts
    max_ticks: int = 5  # a stall lasts 1..max_ticks periods
    processes: int = 0  # planner processes the arms are spread over (0: one per arm)
    hold_ticks: int = 1  # periods a command drives its arm after it arrives (5: 0.2 s)
    expire_stale: bool = True  # a command planned > 1 period before it is published: zero

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate <= 1.0:
            raise InvalidValueError("stalls.rate", "must be in [0, 1] per tick", self.rate)
        if self.max_ticks < 1:
            raise InvalidValueError("stalls.max_ticks", "must be >= 1", self.max_ticks)
        if self.processes < 0:
            raise InvalidValueError(
                "stalls.processes", "must be >= 0 (0: one per arm)", self.processes
            )
        if self.hold_ticks < 1:
            raise InvalidValueError("stalls.hold_ticks", "must be >= 1 period", self.hold_ticks)

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


SYNTAX = "RATE[,MAX_TICKS[,PROCESSES[,HOLD_TICKS[,expire|send]]]]"


def parse_stalls(text: str) -> Stalls:
    """:data:`SYNTAX`, e.g. ``0.05,5,2,1``; ``send``: a late tick sends its stale plan."""
    parts = [p.strip() for p in text.split(",")]
    expire = parts[-1] != "send"
    if parts[-1] in ("expire", "send"):
        parts = parts[:-1]
    if not 1 <= len(parts) <= 4:
        raise InvalidValueError("--stalls", f"must be {SYNTAX}", text)
    try:
        rate = float(parts[0])
        ints = [int(p) for p in parts[1:]]
    except ValueError:
        rule = "must be a rate then integers (and 'expire' or 'send' last)"
        raise InvalidValueError("--stalls", rule, text) from None
    names = ("max_ticks", "processes", "hold_ticks")
    return Stalls(rate, expire_stale=expire, **dict(zip(names, ints, strict=False)))


class StallSchedule:
    """Which arms' processes are stalled at each tick of one episode (seeded)."""

    def __init__(self, stalls: Stalls, arm_ids: Sequence[str], seed: int) -> None:
        self.stalls = stalls
        n = stalls.processes or len(arm_ids)
        self.process = {a: i % n for i, a in enumerate(arm_ids)}
        self._until = [0] * n  # a process is stalled at ticks < its entry
        self._rng = np.random.default_rng(seed)
        self.stalled_ticks = dict.fromkeys(arm_ids, 0)

    def at(self, tick: int) -> frozenset[str]:
        """The arms whose process is stalled at ``tick`` (call once per tick, in order)."""
        s = self.stalls
        if s.rate > 0.0:
            for p, until in enumerate(self._until):
                if tick >= until and self._rng.random() < s.rate:
                    self._until[p] = tick + int(self._rng.integers(1, s.max_ticks + 1))
        out = frozenset(a for a, p in self.process.items() if tick < self._until[p])
        for a in out:
            self.stalled_ticks[a] += 1
        return out
