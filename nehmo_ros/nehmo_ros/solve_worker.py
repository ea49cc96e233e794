"""The solve worker of one arm: plans on its own thread, one observation at a time.

:class:`Observation` is what a tick hands to the worker; :class:`Decision` is what the
controller publishes for a tick (command, status, timing).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np

from nehmo_core.planning.opt.interface import Telemetry

__all__ = ["WAITING", "Decision", "Observation", "SolveWorker"]

#: Statuses of a controller that cannot plan yet (nothing to command).
WAITING = ("starting", "no_own_state", "no_goal", "waiting_for_peers")


@dataclass(frozen=True)
class Observation:
    """What one tick saw: own and peer states [rad], their ages [s], the goal [rad]."""

    tick: int
    stamp_ns: int  # ROS time [ns] of the tick (simulated time under use_sim_time)
    q_self: np.ndarray | None  # None: own state missing or stale
    peers: Mapping[str, np.ndarray]  # last known state of every peer heard from
    ages: Mapping[str, float]  # [s] age of every arm's state (inf: never received)
    stale: tuple[str, ...]  # peers whose last state is older than peer_timeout
    missing: tuple[str, ...]  # peers never heard from
    goal: np.ndarray | None
    untrusted: tuple[str, ...] = ()  # peers with rejected or jumping states lately
    own_untrusted: bool = False  # the own arm's states were rejected or jumped lately
    #: the command [rad/s] sent at this tick: it runs while this observation's solve does
    in_flight: np.ndarray | None = None


@dataclass(frozen=True)
class Decision:
    """A command (dof,) [rad/s] and why it was chosen."""

    velocity: np.ndarray
    status: str
    fail_safe: bool = False
    hold: bool = False
    tick: int = -1  # the observation tick it was computed from
    observation_ns: int = 0  # ROS time [ns] of that observation
    #: [s] plan() time when the planner ran, else the worker's job time; NaN when no solve
    #: finished in time (``deadline_missed``)
    solve_time: float = 0.0
    telemetry: Telemetry | None = None  # the planner's own report, when it ran
    stale: tuple[str, ...] = ()
    missing: tuple[str, ...] = ()
    untrusted: tuple[str, ...] = ()
    ages: Mapping[str, float] = field(default_factory=dict)  # [s] state ages at that observation
    error: str = ""
    #: [s] solve time of an abandoned (late) solve that finished since the previous command,
    #: and the tick it solved; NaN and -1 when there is none
    late_solve_time: float = math.nan
    late_tick: int = -1

    @property
    def planned(self) -> bool:
        """True when the planner itself produced this command (plan() ran on time)."""
        return self.telemetry is not None

    @property
    def ready(self) -> bool:
        """False while the arm waits for its own state, its goal or a first peer state."""
        return self.status not in WAITING


def zeros(dof: int) -> np.ndarray:
    """A zero command for ``dof`` joints [rad/s]."""
    return np.zeros(dof)


# ----------------------------------------------------------------------------- the worker
class SolveWorker:
    """A background thread that runs one job at a time; the tick thread never waits on it."""

    def __init__(self, solve: Callable[[Observation], Decision], name: str = "solve") -> None:
        self._solve = solve
        self._cond = threading.Condition()
        self._job: Observation | None = None
        self._result: Decision | None = None
        self._busy = False
        self._stopped = False
        self._thread = threading.Thread(target=self._loop, name=name, daemon=True)
        self._thread.start()

    def submit(self, obs: Observation) -> bool:
        """Start solving ``obs``; False (nothing started) while the previous job still runs."""
        with self._cond:
            if self._busy or self._stopped:
                return False
            self._job, self._result, self._busy = obs, None, True
            self._cond.notify_all()
            return True

    def take(self) -> Decision | None:
        """The finished result, once (None while running or when nothing was submitted)."""
        with self._cond:
            result, self._result = self._result, None
            return result

    @property
    def busy(self) -> bool:
        with self._cond:
            return self._busy

    def wait_idle(self, timeout: float) -> bool:
        """Wait up to ``timeout`` [s] until no job runs; True if idle."""
        with self._cond:
            return self._cond.wait_for(lambda: not self._busy, timeout)

    def stop(self, timeout: float = 1.0) -> None:
        """Stop the thread (a job in flight is allowed to finish within ``timeout``)."""
        with self._cond:
            self._stopped = True
            self._cond.notify_all()
        self._thread.join(timeout)

    def _loop(self) -> None:
        while True:
            with self._cond:
                while self._job is None and not self._stopped:
                    self._cond.wait()
                if self._stopped:
                    return
                job, self._job = self._job, None
            assert job is not None
            result = self._solve(job)
            with self._cond:
                self._result, self._busy = result, False
                self._cond.notify_all()
