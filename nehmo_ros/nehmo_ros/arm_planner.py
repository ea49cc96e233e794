"""`arm_planner` node: plans one arm's joint velocities at a fixed rate with `nehmo_core`.

    ros2 run nehmo_ros arm_planner --ros-args -p arm_id:=ur5_0 -p cell:=dual_ur5

Topics, ``<id>`` = ``arm_id``:

- subscribes ``/<a>/joint_states`` of every arm ``a`` of the cell (sensor_msgs/JointState) and
  ``/<id>/goal`` (sensor_msgs/JointState, positions [rad] by joint name);
- publishes ``/<id>/velocity_controller/commands`` (std_msgs/Float64MultiArray, [rad/s] in the
  robot's joint order) every ``1/rate`` s from a timer, ``/<id>/planner/status``
  (diagnostic_msgs/DiagnosticStatus) after every command, and the same status on
  ``/diagnostics`` (diagnostic_msgs/DiagnosticArray) once a second, at once when not OK;
- serves ``/<id>/planner/pause`` and ``/<id>/planner/resume`` (std_srvs/Trigger: pause) and
  the ``/<id>/move_arm`` action (nehmo_interfaces/MoveArm: move_action), which shares the goal
  topic's code path;
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
fail_safe: what a stale or untrusted peer triggers), ``plan_age`` [periods] (1.5: a plan of
older observations is not sent, ``late_plan``; ``.inf``: off), ``jump_margin`` [rad] (slack of
the test that flags joint states moving faster than ``opt.d_max``; ``.inf``: off),
``allow_unmodelled``
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
from collections.abc import Callable, Mapping, Sequence
from typing import Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.parameter import Parameter
from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64, Float64MultiArray

from nehmo_core.errors import InvalidValueError
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
from nehmo_ros.markers import MarkerPublisher
from nehmo_ros.move_action import GoalKeeper
from nehmo_ros.node_support import (
    NODE_ERRORS,
    Param,
    declare_parameters,
    load_cell_parameter,
    refuse_renamed,
    require_text,
    run_main,
    settle_heap,
)
from nehmo_ros.pause import PauseServices
from nehmo_ros.planner_report import WARN_EVERY, PlannerReports
from nehmo_ros.planners import build_planner, warm_up
from nehmo_ros.state_intake import StateIntake

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
    "peer_timeout": Param(_CONTROL.peer_timeout, "[s] a state older than this is stale", 0, 60),
    "stale_policy": Param(_CONTROL.stale_policy, "hold | fail_safe: on a stale/untrusted peer"),
    "jump_margin": Param(
        _CONTROL.jump_margin, "[rad] slack of the test flagging states faster than opt.d_max"
    ),
    "plan_age": Param(
        _CONTROL.plan_age, "[periods] a plan of older observations is not sent (.inf: off)"
    ),
    "allow_unmodelled": Param(False, "accept peers in reach that no pair model covers"),
    "autostart": Param(True, "configure and activate at start (false: a lifecycle manager does)"),
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
#: History of the command and status publishers (reliable, keep last): 2 s at 25 Hz, so a
#: recorder that stalls for up to 2 s (CPU starved) loses nothing.
HISTORY = 50


def _typed(value: object) -> object:
    """A parameter's value as its setting takes it (arrays as tuples)."""
    if isinstance(value, str | bool | int | float):
        return value
    return tuple(float(v) for v in value)  # type: ignore[attr-defined]


class ArmPlannerNode(StateIntake, PlannerReports, LifecycleNode):
    """The node: parameters → planner → controller; timer, subscriptions, publishers.

    A managed (lifecycle) node: *configure* checks the parameters and the cell, loads and
    compiles the models and creates the topics, services and the action; *activate* starts the
    command timer; *deactivate* stops it after one zero command; *cleanup* and *shutdown*
    release everything. Unconfigured or inactive, it publishes no command. With ``autostart``
    (the default) it configures and activates itself at start, and a bad parameter stops it
    with one line, as a plain node.

    It spins in a single-threaded executor; the solve runs in the controller's own thread
    (:class:`~nehmo_ros.control.SolveWorker`), so the 25 Hz timer never waits on it. (rclpy's
    multi-threaded executor with the solve in a callback group of its own put only 65-68 % of
    the command periods within 40 ± 5 ms, against 96-100 % this way: ``bench/ros_rate.py``.)
    """

    def __init__(
        self, node_name: str = "arm_planner", own: Mapping[str, Any] | None = None
    ) -> None:
        # ``own``: parameters of this node alone, over the command line's (several arm nodes
        # in one process: nehmo_ros.planner_group)
        given = [Parameter(k, value=v) for k, v in (own or {}).items()]
        super().__init__(node_name, parameter_overrides=given)
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
        autostart = declare_parameters(self, PARAMS)["autostart"]
        self.configured = False
        self.timer: Any = None  # the command timer while active
        self._last_publish: float | None = None
        self._sent: tuple[float, int] | None = None  # (period [s], publish_wall_ns) of this tick
        self._after: tuple[Decision, int] | None = None  # (decision, stamp) left for _after_tick
        if autostart:
            self._configure()  # errors stop the node with one line
            self.trigger_configure()
            self.trigger_activate()

    # -- lifecycle ------------------------------------------------------------------------------
    def on_configure(self, state: Any) -> TransitionCallbackReturn:
        if not self.configured:
            try:
                self._configure()
            except NODE_ERRORS as err:
                self.get_logger().error(f"configure failed: {err}")
                return TransitionCallbackReturn.FAILURE
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: Any) -> TransitionCallbackReturn:
        self._ready, self._last_publish = False, None
        self._after = None
        self.timer = self.create_timer(self.period, self._on_tick)
        self.get_logger().info("active: commanding")
        return TransitionCallbackReturn.SUCCESS

    def on_deactivate(self, state: Any) -> TransitionCallbackReturn:
        self._stop_commands()
        self.get_logger().info("inactive: one zero command, then none")
        return TransitionCallbackReturn.SUCCESS

    def on_cleanup(self, state: Any) -> TransitionCallbackReturn:
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: Any) -> TransitionCallbackReturn:
        self._stop_commands()
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def _stop_commands(self) -> None:
        if self.timer is not None:
            self.destroy_timer(self.timer)
            self.timer = self._after = None
            self.command_pub.publish(Float64MultiArray(data=[0.0] * self.robot.dof))
            self.published["commands"] += 1

    def _release(self) -> None:
        """Stop the worker, drop the models and every topic, service and the action."""
        if not self.configured:
            return
        self.controller.stop()
        self.goals.destroy()
        for entity in self._entities:
            for kind in ("publisher", "subscription", "service"):
                if type(entity).__name__.lower() == kind:
                    getattr(self, f"destroy_{kind}")(entity)
        self.configured = False
        self.get_logger().info("cleaned up: models and topics released")

    def _owned(self) -> list[Any]:
        return [*self.publishers, *self.subscriptions, *self.services]

    def _configure(self) -> None:
        """Everything but the timer: parameters, cell, planner, topics, services, action."""
        p = {name: self.get_parameter(name).value for name in PARAMS}
        before = self._owned()
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
            plan_age=float(p["plan_age"]),
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
        self._latest: dict[str, tuple[bytes, float]] = {}  # arm → newest raw state, received
        for other in self.cell.arm_ids:  # raw: only the newest state per tick is decoded
            self.create_subscription(
                JointState,
                joint_states_topic(other),
                self._state_callback(other),
                qos_profile_sensor_data,
                raw=True,
            )
        self.goals = GoalKeeper(self, self.controller, arm_id)  # the topic's and the action's
        self.markers = MarkerPublisher(self, self.controller, arm_id, settings.opt.epsilon, rate)
        self.create_subscription(JointState, goal_topic(arm_id), self.goals.on_topic, LATCHED)
        self.pause_services = PauseServices(self, self.controller, arm_id)
        self.period = control.period
        self._entities = [e for e in self._owned() if e not in before]
        self.configured = True
        log_msgs.typestore()  # the status codec, loaded now rather than in the first tick
        settle_heap()  # what configure loaded stays out of the collector's walks while ticking
        self.get_logger().info(
            f"arm {arm_id} of cell {self.cell.name}: planner {p['planner']} (model "
            f"{p['model']}), {rate:g} Hz, deadline {deadline * 1e3:.1f} ms, peers "
            f"{list(self.controller.peer_ids)}, rmw {rclpy.get_rmw_implementation_identifier()}"
        )

    # -- callbacks ----------------------------------------------------------------------------
    def _bound_callback(self, arm_id: str) -> Callable[[Any], None]:
        return lambda msg: self._on_bound(arm_id, msg)

    def _on_bound(self, arm_id: str, msg: Any) -> None:
        try:
            self.controller.announce(arm_id, float(msg.data))
        except Exception as err:  # InvalidValueError: a bound outside [0, 1]
            self.get_logger().warning(
                f"speed bound of {arm_id} rejected: {err}", throttle_duration_sec=WARN_EVERY
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
        """The command first; the solve and the reports after the other nodes' commands."""
        stamp_ns = self.get_clock().now().nanoseconds
        self._read_states()
        self._sent = None
        decision = self.controller.tick(time.monotonic(), stamp_ns, send=self._send, solve=False)
        self._after = (decision, stamp_ns)
        if self.executor is None:  # not spun by an executor (tests): at once
            self._on_after_tick()
        else:
            self.executor.create_task(self._on_after_tick)

    def _send(self, decision: Decision) -> None:
        """Publish the tick's command first, before the solve starts and before any report; its
        publish instant (``publish_wall_ns``) and the period since the last are kept in
        ``_sent`` for the status."""
        if not self._ready:
            if not decision.ready:  # nothing to command yet: the bridge's watchdog holds the arm
                self.get_logger().info(f"waiting ({decision.status})", throttle_duration_sec=2.0)
                return
            self._ready = True
            self.get_logger().info("planning")
        self.command_pub.publish(Float64MultiArray(data=[float(u) for u in decision.velocity]))
        wall_ns, now = time.time_ns(), time.monotonic()
        self.published["commands"] += 1
        period = math.nan if self._last_publish is None else now - self._last_publish
        self._last_publish = now
        self._sent = (period, wall_ns)

    def on_stop(self) -> None:
        """Active: command a stop once (if the middleware is still up); end the worker thread."""
        if not self.configured:
            print(f"{self.get_name()}: stopped (unconfigured)", flush=True)
            return
        if self.timer is not None:
            self.timer.cancel()
        self.controller.stop()
        if rclpy.ok() and self.timer is not None:
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
            "late_plans": c.late_plans,
        }
        print(f"{self.get_name()}: stopped; counts {json.dumps(counts)}", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `arm_planner` console script."""
    sys.setswitchinterval(5e-4)  # the timer thread gets the GIL back from the solver quickly
    return run_main("arm_planner", ArmPlannerNode, argv, usage=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
