"""What ``arm_planner`` reports each tick: the status message (telemetry and the node's
counters), ``/diagnostics``, and throttled WARN lines for faults."""

from __future__ import annotations

from typing import Any

from std_msgs.msg import Float64

from nehmo_core.eval.telemetry import stamp, status_message
from nehmo_core.logs import messages as log_msgs
from nehmo_ros.solve_worker import Decision

__all__ = ["DIAGNOSTICS_EVERY", "WARN_EVERY", "PlannerReports"]

#: Seconds between two WARN lines of one cause.
WARN_EVERY = 2.0
#: Ticks between two statuses on ``/diagnostics`` while all is OK (1 Hz at 25 Hz); a WARN or
#: ERROR status goes out at once.
DIAGNOSTICS_EVERY = 25


def _level(decision: Decision) -> int:
    levels = log_msgs.DiagnosticStatus
    if decision.error or decision.status in ("no_own_state", "non_finite_command"):
        return int(levels.ERROR)
    if decision.fail_safe or decision.hold or decision.stale or decision.untrusted:
        return int(levels.WARN)
    return int(levels.OK)


class PlannerReports:
    """The reporting half of :class:`~nehmo_ros.arm_planner.ArmPlannerNode` (a mixin: it uses
    the node's logger, controller, publishers and counters)."""

    arm_id: str
    kind: str
    fault: str
    controller: Any
    diagnostics_pub: Any
    bound_pub: Any
    status_pub: Any
    goals: Any
    markers: Any
    published: dict[str, int]
    _diagnostics_due: int
    _after: tuple[Decision, int] | None  # (decision, tick stamp [ns]) left for _after_tick
    _sent: tuple[float, int] | None  # (period [s], publish_wall_ns) of this tick's command
    get_logger: Any  # the node's

    def _on_after_tick(self) -> None:
        try:
            self._after_tick()
        except Exception as err:  # as in _on_tick: report, never end the node
            self.get_logger().error(
                f"tick report failed ({type(err).__name__}: {err})",
                throttle_duration_sec=WARN_EVERY,
            )

    def _after_tick(self) -> None:
        """The second half of a tick, an executor task: start the solve, publish the reports.
        The executor runs it after every timer already due, so the planner nodes of one process
        (``arm_planners``) publish their commands of a tick before any of them solves or
        reports."""
        if self._after is None:
            return
        (decision, stamp_ns), self._after = self._after, None
        self.controller.start_solve()
        self.goals.on_tick(decision)
        self.markers.on_tick(decision)
        if self._sent is None:
            return
        period, wall_ns = self._sent
        if self.controller.announces:  # a planner that announces nothing stays silent
            self.bound_pub.publish(Float64(data=self.controller.announcement))
        status = self._status(decision, period, wall_ns, stamp_ns)
        self.status_pub.publish(log_msgs.serialize(status))
        self.published["statuses"] += 1
        self._publish_diagnostics(status, stamp_ns)
        self._report(decision)

    def _publish_diagnostics(self, status: Any, stamp_ns: int) -> None:
        """The status on ``/diagnostics`` too, at most every ``DIAGNOSTICS_EVERY`` ticks."""
        self._diagnostics_due -= 1
        if self._diagnostics_due > 0 and int(status.level) == 0:
            return
        self._diagnostics_due = DIAGNOSTICS_EVERY
        array = log_msgs.DiagnosticArray(
            header=log_msgs.Header(stamp=stamp(stamp_ns)), status=[status]
        )
        self.diagnostics_pub.publish(log_msgs.serialize(array))

    def _report(self, d: Decision) -> None:
        """WARN lines for faults, at most one per cause every ``WARN_EVERY`` s."""
        log, c = self.get_logger(), self.controller.counters
        if d.error or d.status.startswith("failed"):
            log.warning(
                f"solver failed ({d.error or d.status}); commanding "
                f"{'zero velocity' if d.hold else 'the fail-safe'} ({c.solver_errors} failures "
                f"in {c.ticks} ticks)",
                throttle_duration_sec=WARN_EVERY,
            )
        elif d.status == "deadline_missed":
            log.warning(
                f"solve of tick {d.tick} missed its deadline; commanding "
                f"{'zero velocity' if d.hold else 'the fail-safe'} ({c.deadline_misses} misses "
                f"in {c.ticks} ticks)",
                throttle_duration_sec=WARN_EVERY,
            )
        elif d.status == "late_plan":
            log.warning(
                f"tick ran late: the plan of tick {d.tick} is over 1.5 periods old; holding still "
                f"({c.late_plans} late plans in {c.ticks} ticks)",
                throttle_duration_sec=WARN_EVERY,
            )
        if d.stale or d.untrusted:
            action = "zero velocity" if d.hold else "the fail-safe"
            log.warning(
                f"peers stale {list(d.stale)} / untrusted {list(d.untrusted)}: commanding {action}",
                throttle_duration_sec=WARN_EVERY,
            )
        if d.status == "own_state_untrusted":
            log.warning(
                "own joint states rejected or jumping: holding still",
                throttle_duration_sec=WARN_EVERY,
            )

    def _status(self, d: Decision, period: float, wall_ns: int, tick_ns: int = 0) -> Any:
        """The evaluation's status message (telemetry) plus the node's own counters;
        ``tick_ns`` is the node clock at the tick (simulated time under ``use_sim_time``)."""
        msg = status_message(self.arm_id, self.kind, self.controller.telemetry(d), d.observation_ns)
        c = self.controller.counters
        extra: dict[str, object] = {
            "hold": str(d.hold).lower(),
            "stale_peers": ",".join(d.stale),
            "missing_peers": ",".join(d.missing),
            "untrusted_peers": ",".join(d.untrusted),
            "error": d.error,
            "ticks": c.ticks,
            "deadline_misses": c.deadline_misses,
            "fail_safes": c.fail_safes,
            "holds": c.holds,
            "solver_errors": c.solver_errors,
            "late_plans": c.late_plans,
            "rejected_states": sum(self.controller.states.rejected.values()),
            "state_jumps": sum(self.controller.states.jumps.values()),
            "period": repr(period),
            "publish_wall_ns": wall_ns,
            "tick_ns": tick_ns,
            "command": ",".join(repr(float(u)) for u in d.velocity),
            "late_solve_time": repr(float(d.late_solve_time)),
            "late_solve_tick": d.late_tick,
        }
        if self.fault:
            extra["fault_injection"] = self.fault
        # the state ages of the observation this command was computed from
        extra.update({f"age_{a}": f"{age:.4f}" for a, age in d.ages.items()})
        msg.level = _level(d)
        msg.values += [log_msgs.KeyValue(key=k, value=str(v)) for k, v in extra.items()]
        return msg
