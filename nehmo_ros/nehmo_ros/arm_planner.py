"""`arm_planner` node: plans one arm's joint velocities at a fixed rate with `nehmo_core`.

    ros2 run nehmo_ros arm_planner --ros-args -p arm_id:=ur5_0 -p cell:=dual_ur5

Topics, ``<id>`` = ``arm_id``:

- subscribes ``/<a>/joint_states`` of every arm ``a`` of the cell (sensor_msgs/JointState) and
  ``/<id>/goal`` (sensor_msgs/JointState, positions [rad] by joint name);
- publishes ``/<id>/velocity_controller/commands`` (std_msgs/Float64MultiArray, [rad/s] in the
  robot's joint order) every ``1/rate`` s from a timer, ``/<id>/planner/status``
  (diagnostic_msgs/DiagnosticStatus) after every command, and the same status on
  ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) once a second, at once when not OK;
- serves ``/<id>/planner/pause`` and ``/<id>/planner/resume`` (std_srvs/Trigger: pause);
- publishes ``/<id>/planner/speed_bound`` (std_msgs/Float64) with every command, the speed bound
  the arm keeps (a share of ``u_max``; 1: none), and subscribes to every peer's: a peer that
  keeps its bound is planned against it (:mod:`nehmo_core.planning.stages.speed_bounds`). Planners
  that announce nothing (``naive``, ``reckless``, ...) publish nothing there, so peers treat them as
  silent.

The solve runs in a worker thread (:class:`nehmo_ros.control.ArmController`): the command of
tick k was planned from the observations of tick k−1; missed deadlines, solver failures and
stale peers end in the fail-safe or a hold, and every tick's status says which.

Parameters (validated at start; a bad one stops the node with one line naming it, the rule and
the value): ``arm_id`` (required), ``cell`` (required: shipped name or YAML path), ``planner``
(nehmo | nehmo_paper | nehmo_no_sym | opt_deepreach | nehmo_wrap | naive | reckless), ``model``
(shipped | synthetic | path), ``rate`` [Hz], ``peer_timeout`` [s], ``stale_policy`` (hold |
fail_safe: what a stale or untrusted peer triggers), ``jump_margin`` [rad] (slack of the test
that flags joint states moving faster than ``opt.d_max``; ``.inf``: off), ``allow_unmodelled``
(accept peers in reach that no pair model covers: they are then not constrained; default false:
an error), ``fault_injection`` (tests only, default '' = off: :mod:`nehmo_ros.fault_injection`),
and every planner setting by its dotted name (``opt.t_plan``, ``hold.bound``,
``escape.stall_ticks``, ...: :func:`planner_params`, ``docs/settings.md``); ``opt.deadline`` [s]
is 0 by default: 75 % of the period, and ``opt.tick`` comes from ``rate``.

Faults are reported, never fatal: rejected or jumping joint states, stale peers, solver
exceptions and missed deadlines each log a WARN line (at most one per cause every 2 s) and
show in every status (level WARN for a fail-safe or hold, ERROR for a solver exception or no
own state) with running counters. A missed deadline's status has ``solve_time`` NaN; the
abandoned solve's own time comes as ``late_solve_time`` [s] (its tick: ``late_solve_tick``) in
the first status after it finished, NaN (-1) in every other status.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from nehmo_core.errors import InvalidValueError
from nehmo_core.eval.telemetry import stamp, status_message
from nehmo_core.logs import messages as log_msgs
from nehmo_core.logs.topics import (
    command_topic,
    goal_topic,
    joint_states_topic,
    speed_bound_topic,
    status_topic,
)
from nehmo_core.planning.settings import REMOVED, RENAMED, PlannerSettings
from nehmo_ros.control import ArmController, ControlSettings, Decision
from nehmo_ros.fault_injection import FaultInjectingPlanner, parse_fault
from nehmo_ros.node_support import (
    Param,
    declare_parameters,
    load_cell_parameter,
    refuse_renamed,
    require_text,
    run_main,
)
from nehmo_ros.pause import PauseServices
from nehmo_ros.planners import build_planner, warm_up

#: Goals and the scenario are latched (transient local): a late subscriber still gets them.
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: The diagnostics convention (diagnostic_aggregator, rqt_robot_monitor, Foxglove).
DIAGNOSTICS_TOPIC = "/diagnostics"

_CONTROL = ControlSettings()
NODE_PARAMS: dict[str, Param] = {
    "arm_id": Param("", "id of the arm this node commands (one of the cell's arms)"),
    "cell": Param("", "shipped cell name (dual_ur5, ...) or a cell YAML path"),
    "planner": Param(
        "nehmo",
        "nehmo | nehmo_paper | nehmo_no_sym | opt_deepreach | nehmo_wrap | naive | reckless",
    ),
    "model": Param("shipped", "shipped | synthetic | [KIND=]PATH,... (run dir or .safetensors)"),
    "rate": Param(_CONTROL.rate, "[Hz] command rate", 1e-3, 1000.0),
    "peer_timeout": Param(
        _CONTROL.peer_timeout, "[s] a joint state older than this is stale", 0.0, 60.0
    ),
    "stale_policy": Param(
        _CONTROL.stale_policy, "hold | fail_safe: what a stale or untrusted peer triggers"
    ),
    "jump_margin": Param(
        _CONTROL.jump_margin, "[rad] slack of the test flagging states faster than opt.d_max"
    ),
    "allow_unmodelled": Param(False, "accept peers in reach that no pair model covers"),
    "fault_injection": Param("", "tests only: raise | solver_raise | hang | slow; '' = off"),
}
"""The node's own parameters; the planner's settings follow (:func:`planner_params`)."""
FROM_RATE = ("opt.tick",)
"""Planner settings the node sets from ``rate`` instead of a parameter."""
DEADLINE = Param(0.0, "[s] solve budget within a period; 0: 75 % of the period", 0.0, 10.0)


def planner_params() -> dict[str, Param]:
    """One node parameter per planner setting, named ``group.field`` (``hold.bound``),
    with the description, unit and range of its settings group."""
    defaults = PlannerSettings().flat()
    out: dict[str, Param] = {}
    for name, _, _, rule in PlannerSettings.specs():
        if name in FROM_RATE:
            continue
        if name == "opt.deadline":
            out[name] = DEADLINE
            continue
        default = defaults[name]
        text = f"[{rule.unit}] {rule.doc}" if rule.unit else rule.doc
        low, high = rule.low, rule.high
        if isinstance(default, tuple):
            default, low, high = [float(v) for v in default], None, None
        elif low is None or high is None or not math.isfinite(high):
            low = high = None
        out[name] = Param(default, text, low, high)
    return out


PLANNER_PARAMS = planner_params()
PARAMS: dict[str, Param] = {**NODE_PARAMS, **PLANNER_PARAMS}
#: Seconds between two WARN lines of one cause.
WARN_EVERY = 2.0
#: History of the command and status publishers (reliable, keep last): 2 s at 25 Hz, so a
#: recorder that stalls for up to 2 s (CPU starved) loses nothing.
HISTORY = 50
#: Ticks between two statuses on ``/diagnostics`` while all is OK (1 Hz at 25 Hz); a WARN or
#: ERROR status goes out at once.
DIAGNOSTICS_EVERY = 25


def _typed(value: object) -> object:
    """A parameter's value as its setting takes it (arrays as tuples)."""
    if isinstance(value, str | bool | int | float):
        return value
    return tuple(float(v) for v in value)  # type: ignore[attr-defined]


def _level(decision: Decision) -> int:
    levels = log_msgs.DiagnosticStatus
    if decision.error or decision.status in ("no_own_state", "non_finite_command"):
        return int(levels.ERROR)
    if decision.fail_safe or decision.hold or decision.stale or decision.untrusted:
        return int(levels.WARN)
    return int(levels.OK)


class ArmPlannerNode(Node):
    """The node: parameters → planner → controller; timer, subscriptions, publishers.

    It spins in a single-threaded executor; the solve runs in the controller's own thread
    (:class:`~nehmo_ros.control.SolveWorker`), so the 25 Hz timer never waits on it. (rclpy's
    multi-threaded executor with the solve in a callback group of its own put only 65-68 % of
    the command periods within 40 ± 5 ms, against 96-100 % this way: ``bench/ros_rate.py``.)
    """

    def __init__(self) -> None:
        super().__init__("arm_planner")
        refuse_renamed(
            self,
            {
                **{
                    old: f"is now `{new}` (settings are named group.field)"
                    for old, new in RENAMED.items()
                },
                **{old: f"no longer exists: {why}" for old, why in REMOVED.items()},
            },
        )
        p = declare_parameters(self, PARAMS)
        self.cell = load_cell_parameter(p["cell"])
        arm_id = require_text("arm_id", p["arm_id"], f"one of the cell's arms {self.cell.arm_ids}")
        if arm_id not in self.cell.arm_ids:
            raise InvalidValueError(
                "arm_id", f"must name an arm of cell {self.cell.name!r} {self.cell.arm_ids}", arm_id
            )
        self.arm_id = arm_id
        rate = float(p["rate"])
        if not (math.isfinite(rate) and 0 < rate <= 1000):
            raise InvalidValueError("rate", "must lie in (0, 1000] Hz", rate)
        deadline = float(p["opt.deadline"]) or 0.75 / rate
        if not deadline < 1.0 / rate:
            raise InvalidValueError(
                "opt.deadline", f"must be < 1/rate = {1.0 / rate:.4g} s (0: 75 %)", deadline
            )
        given = {k: _typed(p[k]) for k in PLANNER_PARAMS if k != "opt.deadline"}
        settings = PlannerSettings().override(
            {**given, "opt.deadline": deadline, "opt.tick": 1.0 / rate}
        )
        control = ControlSettings(
            rate=rate,
            peer_timeout=float(p["peer_timeout"]),
            stale_policy=p["stale_policy"],
            jump_margin=float(p["jump_margin"]),
            opt=settings.opt,
        )
        fault = parse_fault(str(p["fault_injection"]))
        planner = build_planner(
            p["planner"], self.cell, arm_id, p["model"], settings, bool(p["allow_unmodelled"])
        )
        unmodelled = planner.peers_unmodelled
        if unmodelled:
            self.get_logger().warning(f"peers {list(unmodelled)} are NOT constrained")
        epsilon_source = planner.epsilon_source
        if epsilon_source:
            self.get_logger().info(epsilon_source)
        warm_up(planner, self.cell, arm_id)
        self.fault = ""
        if fault is not None:
            planner = FaultInjectingPlanner(planner, fault)
            self.fault = str(fault)
            self.get_logger().warning(
                f"fault_injection={self.fault} is ON: this node fails on purpose (tests only)"
            )
        self.controller = ArmController(self.cell, arm_id, planner, control)
        self.robot = self.cell.arm(arm_id).robot
        self.kind = p["planner"]
        self._last_publish: float | None = None
        self._ready = False
        self._diagnostics_due = 0
        #: Messages published and joint states received (printed at the stop, for load tests).
        self.published = {"commands": 0, "statuses": 0}
        self.received: dict[str, int] = dict.fromkeys(self.cell.arm_ids, 0)

        self.command_pub = self.create_publisher(Float64MultiArray, command_topic(arm_id), HISTORY)
        self.status_pub = self.create_publisher(DiagnosticStatus, status_topic(arm_id), HISTORY)
        self.diagnostics_pub = self.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, HISTORY)
        self.bound_pub = self.create_publisher(Float64, speed_bound_topic(arm_id), HISTORY)
        for other in self.controller.peer_ids:
            self.create_subscription(
                Float64, speed_bound_topic(other), self._bound_callback(other), HISTORY
            )
        for other in self.cell.arm_ids:
            self.create_subscription(
                JointState,
                joint_states_topic(other),
                self._state_callback(other),
                qos_profile_sensor_data,
            )
        self.create_subscription(JointState, goal_topic(arm_id), self._on_goal, LATCHED)
        self.pause_services = PauseServices(self, self.controller, arm_id)
        self.timer = self.create_timer(control.period, self._on_tick)
        self.get_logger().info(
            f"arm {arm_id} of cell {self.cell.name}: planner {p['planner']} (model "
            f"{p['model']}), {rate:g} Hz, deadline {deadline * 1e3:.1f} ms, peers "
            f"{list(self.controller.peer_ids)}, rmw {rclpy.get_rmw_implementation_identifier()}"
        )

    # -- callbacks ----------------------------------------------------------------------------
    def _state_callback(self, arm_id: str) -> Callable[[Any], None]:
        return lambda msg: self._on_state(arm_id, msg)

    def _on_state(self, arm_id: str, msg: Any) -> None:
        now = time.monotonic()
        self.received[arm_id] += 1
        try:
            stamp = msg.header.stamp
            stamp_ns = int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)
            note = self.controller.update_state(arm_id, msg.name, msg.position, now, stamp_ns)
        except Exception as err:  # a malformed message never takes the node down
            note = f"rejected: {type(err).__name__}: {err}"
        if note is None:
            return
        untrusted = f"; {arm_id} untrusted for {self.controller.settings.peer_timeout:g} s"
        if note.startswith("rejected"):
            self.get_logger().warning(
                f"joint state of {arm_id} {note} ({self.controller.states.rejected[arm_id]} "
                f"rejected){untrusted}",
                throttle_duration_sec=WARN_EVERY,
            )
        else:
            self.get_logger().warning(
                f"joint state of {arm_id} {note} ({self.controller.states.jumps[arm_id]} jumps)"
                f"{untrusted}",
                throttle_duration_sec=WARN_EVERY,
            )

    def _bound_callback(self, arm_id: str) -> Callable[[Any], None]:
        return lambda msg: self._on_bound(arm_id, msg)

    def _on_bound(self, arm_id: str, msg: Any) -> None:
        try:
            self.controller.announce(arm_id, float(msg.data))
        except Exception as err:  # InvalidValueError: a bound outside [0, 1]
            self.get_logger().warning(
                f"speed bound of {arm_id} rejected: {err}", throttle_duration_sec=WARN_EVERY
            )

    def _on_goal(self, msg: Any) -> None:
        try:
            goal = self.controller.set_goal(msg.name, msg.position)
        except Exception as err:  # InvalidValueError, or a malformed message
            self.get_logger().error(
                f"rejected goal: {err}; keeping the previous goal", throttle_duration_sec=WARN_EVERY
            )
            return
        self.get_logger().info(
            f"goal {[round(float(x), 3) for x in goal]}", throttle_duration_sec=5.0
        )

    def _on_tick(self) -> None:
        try:
            self._tick()
        except Exception as err:  # a bug here must not end the node: stop the arm, report
            self.get_logger().error(
                f"tick failed ({type(err).__name__}: {err}); commanding zero velocity",
                throttle_duration_sec=WARN_EVERY,
            )
            self.command_pub.publish(Float64MultiArray(data=[0.0] * self.robot.dof))
            self.published["commands"] += 1

    def _tick(self) -> None:
        now = time.monotonic()
        stamp_ns = self.get_clock().now().nanoseconds
        decision = self.controller.tick(now, stamp_ns)
        if not self._ready:
            if not decision.ready:  # nothing to command yet: the bridge's watchdog holds the arm
                self.get_logger().info(f"waiting ({decision.status})", throttle_duration_sec=2.0)
                return
            self._ready = True
            self.get_logger().info("planning")
        command = Float64MultiArray(data=[float(u) for u in decision.velocity])
        self.command_pub.publish(command)
        self.published["commands"] += 1
        if self.controller.announces:  # a planner that announces nothing stays silent
            self.bound_pub.publish(Float64(data=self.controller.announcement))
        period = math.nan if self._last_publish is None else now - self._last_publish
        self._last_publish = now
        status = self._status(decision, period, time.time_ns())
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

    def _status(self, d: Decision, period: float, wall_ns: int) -> Any:
        """The evaluation's status message (telemetry) plus the node's own counters."""
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
            "rejected_states": sum(self.controller.states.rejected.values()),
            "state_jumps": sum(self.controller.states.jumps.values()),
            "period": repr(period),
            "publish_wall_ns": wall_ns,
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

    def on_stop(self) -> None:
        """Command a stop once (if the middleware is still up) and end the worker thread."""
        self.timer.cancel()
        self.controller.stop()
        if rclpy.ok():
            self.command_pub.publish(Float64MultiArray(data=[0.0] * self.robot.dof))
            self.published["commands"] += 1
        c = self.controller.counters
        counts = {
            "published": self.published,
            "received_joint_states": self.received,
            "ticks": c.ticks,
            "deadline_misses": c.deadline_misses,
            "fail_safes": c.fail_safes,
            "solver_errors": c.solver_errors,
        }
        print(f"arm_planner: stopped; counts {json.dumps(counts)}", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `arm_planner` console script."""
    sys.setswitchinterval(5e-4)  # the timer thread gets the GIL back from the solver quickly
    return run_main("arm_planner", ArmPlannerNode, argv, usage=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
