"""`sim_bridge` node: simulates a cell's arms (PyBullet, exact collisions) for the ROS suite.

    install/sim_bridge/lib/sim_bridge/sim_bridge --ros-args -p cell:=dual_ur5 -p seed:=13

Every physics step (``physics_rate``, 100 Hz) it integrates each arm's latest velocity command
with :class:`nehmo_core.sim.cell_sim.CellSimulator`, checks every arm pair and every arm's
self-collision exactly (pairs that provably do not touch skip the exact query:
:mod:`sim_bridge.broadphase`), and publishes:

- ``/<arm>/joint_states`` (sensor_msgs/JointState: positions [rad], the applied velocity
  [rad/s]; one common stamp for all arms per step);
- ``/nehmo/collisions`` (diagnostic_msgs/DiagnosticArray, one ERROR status per colliding pair)
  on every step that collides;
- ``/clock`` (rosgraph_msgs/Clock) when ``sim_time`` is true: simulated time, 0 at the start of
  the episode, paced at ``real_time_factor`` × wall time. Other nodes then run with
  ``use_sim_time:=true``; each step's clock goes out after its joint states, so a node woken by
  it reads the states of that instant. Without ``sim_time`` the stamps are wall time and
  ``real_time_factor`` must be 1.

It subscribes to ``/<arm>/velocity_controller/commands`` (std_msgs/Float64MultiArray, one value per
joint in the robot's joint order). Commands of the wrong length, not finite or beyond a joint's
velocity limit (the URDF's) are dropped (ros2_control drops wrong lengths silently; here each is
counted and logged). **Validity:** a command drives its arm for at most ``command_validity``
(0.06 s: the one 40 ms period its planner checked it for, plus jitter) after it came; an arm
whose planner runs late then holds still until its next command, not on a command nobody checked
(steps counted per arm). **Watchdog:** an arm whose latest command is older than ``command_timeout``
(simulated time with ``sim_time``, else wall time) holds still; each time that happens to an arm
that was being commanded (its planner died, hung or lost the connection) a WARN line says so, and
another when commands resume; the episode's end line counts the trips per arm.

**Scenario reset.** At start the cell is set to an episode's start configuration: episode
``episode`` of the scenario set file ``scenarios`` (nehmo_core.sim.scenarios JSON), or, without
a file, scenario ``index`` of the seeded set ``seed``. The goals go out on ``/<arm>/goal`` and
the episode description (the evaluation's metadata JSON) on ``/nehmo/scenario``, both latched
(transient local), so planners and recorder that start later still get them. With
``wait_for_planners`` the episode (and the simulated clock, which stays at 0 until then)
starts only when every arm's command topic has a publisher, plus ``start_delay`` s for
discovery to settle (at most ``start_timeout`` s of waiting). The episode ends at the first
collision (with ``stop_on_collision``), when every arm is within ``success_tolerance`` of its
goal (with ``stop_on_success``), or at ``time_limit``; the arms then hold still, and with
``exit_when_done`` the node exits.
"""

from __future__ import annotations

import json
import math
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray, String

from nehmo_core.errors import InvalidValueError
from nehmo_core.eval.episode_log import EPISODE_FORMAT, EPISODE_FORMAT_VERSION, cell_metadata
from nehmo_core.eval.metrics import goal_distance
from nehmo_core.eval.setups import parse_row
from nehmo_core.eval.telemetry import collisions_message
from nehmo_core.logs.messages import serialize
from nehmo_core.logs.topics import (
    CLOCK_TOPIC,
    COLLISIONS_TOPIC,
    SCENARIO_TOPIC,
    command_topic,
    goal_topic,
    joint_states_topic,
)
from nehmo_ros.node_support import declare_parameters, load_cell_parameter, run_main
from sim_bridge.broadphase import BroadPhaseSimulator
from sim_bridge.settings import PARAMS, BridgeSettings, load_episode

#: Goals and the scenario are latched (transient local): late subscribers still get them.
LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: History of the streaming publishers (reliable, keep last): 2 s at 100 Hz, so a reliable
#: subscriber (the recorder) that stalls for up to 2 s (CPU starved) loses nothing.
HISTORY = 200


class SimBridgeNode(Node):
    """The node: one simulator, a wall-clock timer stepping it, topics per arm."""

    def __init__(self) -> None:
        super().__init__("sim_bridge")
        n = self
        p = declare_parameters(self, PARAMS)
        if n.get_parameter("use_sim_time").value:
            raise InvalidValueError(
                "use_sim_time", "must be false for the bridge (it is the clock source)", True
            )
        self.cell = load_cell_parameter(p["cell"])
        self.s = BridgeSettings(
            physics_rate=float(p["physics_rate"]),
            control_rate=float(p["control_rate"]),
            sim_time=bool(p["sim_time"]),
            real_time_factor=float(p["real_time_factor"]),
            command_timeout=float(p["command_timeout"]),
            time_limit=float(p["time_limit"]),
            success_norm=str(p["success_norm"]),
            success_tolerance=float(p["success_tolerance"]),
            stop_on_collision=bool(p["stop_on_collision"]),
            stop_on_success=bool(p["stop_on_success"]),
            self_collision=bool(p["self_collision"]),
            wait_for_planners=bool(p["wait_for_planners"]),
            start_timeout=float(p["start_timeout"]),
            start_delay=float(p["start_delay"]),
            min_subscribers=int(p["min_subscribers"]),
            exit_when_done=bool(p["exit_when_done"]),
            actuators=str(p["actuators"]),
            command_validity=float(p["command_validity"]),
        )
        kinds = parse_row(p["planners"], self.cell) if p["planners"] else {}
        self.scenario, source = load_episode(self.cell, p)
        self.sim = BroadPhaseSimulator(
            self.cell, substeps=1, self_collision=self.s.self_collision, actuators=self.s.actuators
        )
        self.sim.reset(self.scenario.start)
        self.metadata = self._metadata(kinds, source)

        self.state_pubs = {
            a: n.create_publisher(JointState, joint_states_topic(a), HISTORY)
            for a in self.cell.arm_ids
        }
        self.goal_pubs = {
            a: n.create_publisher(JointState, goal_topic(a), LATCHED) for a in self.cell.arm_ids
        }
        self.scenario_pub = n.create_publisher(String, SCENARIO_TOPIC, LATCHED)
        self.collision_pub = n.create_publisher(DiagnosticArray, COLLISIONS_TOPIC, HISTORY)
        self.clock_pub = (
            n.create_publisher(Clock, CLOCK_TOPIC, HISTORY) if self.s.sim_time else None
        )
        #: Each arm's latest command and when it came (seconds of ``_now``).
        self.commands: dict[str, tuple[np.ndarray, float]] = {}
        self.commanded: set[str] = set()
        self.dropped: dict[str, int] = dict.fromkeys(self.cell.arm_ids, 0)
        self.watchdog_trips: dict[str, int] = dict.fromkeys(self.cell.arm_ids, 0)
        #: Physics steps each arm held still because its latest command outlived its validity.
        self.expired_steps: dict[str, int] = dict.fromkeys(self.cell.arm_ids, 0)
        #: Messages published (printed at the stop, for load tests).
        self.published = {"joint_states_per_arm": 0, "clock": 0, "collisions": 0}
        self._held: set[str] = set()  # arms the watchdog holds now
        self.velocity_limits = {
            a.arm_id: np.array([j.velocity for j in a.robot.joints]) for a in self.cell.arms
        }
        self.command_subs = {
            a: n.create_subscription(
                Float64MultiArray, command_topic(a), self._command_callback(a), 10
            )
            for a in self.cell.arm_ids
        }
        self.t_ns = 0  # simulated time since the episode start [ns]
        self.started = False
        self.outcome = ""
        self.created = time.monotonic()
        self.done = False
        self._done_at = math.inf
        self._ready_at = math.inf
        self._publish_episode()
        self.timer = n.create_timer(
            1.0 / (self.s.physics_rate * self.s.real_time_factor), self._step
        )
        n.get_logger().info(
            f"cell {self.cell.name} ({', '.join(self.cell.arm_ids)}), episode {source}, "
            f"{self.s.physics_rate:g} Hz physics, "
            f"{'simulated time on /clock' if self.s.sim_time else 'wall time'}, "
            f"rmw {rclpy.get_rmw_implementation_identifier()}"
        )

    def _metadata(self, kinds: dict[str, str], source: dict[str, Any]) -> dict[str, Any]:
        """The evaluation's episode description (nehmo_core.eval.episode_log)."""
        s = self.s
        period_ns = round(1e9 / s.control_rate)
        return {
            "format": EPISODE_FORMAT,
            "version": EPISODE_FORMAT_VERSION,
            "source": "ros",
            "scenario": source,
            "cell": cell_metadata(self.cell),
            "planners": kinds or dict.fromkeys(self.cell.arm_ids, "unknown"),
            "timed_arms": list(self.cell.arm_ids),
            "control": {
                "rate_hz": s.control_rate,
                "period_ns": period_ns,
                "latency_ticks": 1,
                "substeps": s.substeps_per_tick,
                "self_collision": s.self_collision,
                "actuators": s.actuators,
                "time_limit": s.time_limit,
                "max_ticks": round(s.time_limit * s.control_rate),
                "physics_rate_hz": s.physics_rate,
                "command_timeout": s.command_timeout,
                "command_validity": s.command_validity,
                "sim_time": s.sim_time,
            },
            "success": {"norm": s.success_norm, "tolerance": s.success_tolerance},
            "start": {a: [float(v) for v in self.scenario.start[a]] for a in self.cell.arm_ids},
            "goal": {a: [float(v) for v in self.scenario.goal[a]] for a in self.cell.arm_ids},
        }

    # -- publishing ---------------------------------------------------------------------------
    def _stamp_ns(self) -> int:
        """Stamp of the current state: simulated time, or wall time without ``sim_time``."""
        if self.s.sim_time:
            return self.t_ns
        return self.get_clock().now().nanoseconds

    def _joint_state(self, arm_id: str, q: np.ndarray, v: np.ndarray, t_ns: int) -> JointState:
        msg = JointState(
            name=list(self.cell.arm(arm_id).robot.joint_names),
            position=q.tolist(),
            velocity=v.tolist(),
        )
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(t_ns), 1_000_000_000)
        return msg

    def _publish_episode(self) -> None:
        t_ns = self._stamp_ns()
        self.scenario_pub.publish(String(data=json.dumps(self.metadata)))
        empty = np.zeros(0)
        for a, pub in self.goal_pubs.items():
            pub.publish(self._joint_state(a, self.scenario.goal[a], empty, t_ns))

    def _publish_state(self, velocities: dict[str, np.ndarray]) -> None:
        """The step's joint states, then the clock: a planner ticked by this clock reads the
        states of this instant, and the bridge is done with its step before planners wake."""
        t_ns = self._stamp_ns()
        # what sensors read (noisy with a realistic actuator model) and how fast each arm moves
        observed, moving = self.sim.observed(), self.sim.velocities(velocities)
        for a, pub in self.state_pubs.items():
            pub.publish(self._joint_state(a, observed[a], moving[a], t_ns))
        self.published["joint_states_per_arm"] += 1
        if self.clock_pub is not None:
            clock = Clock()
            clock.clock.sec, clock.clock.nanosec = divmod(int(t_ns), 1_000_000_000)
            self.clock_pub.publish(clock)
            self.published["clock"] += 1

    def _now(self) -> float:
        """The watchdog's clock [s]: simulated time with ``sim_time``, else monotonic time."""
        if self.s.sim_time:
            return self.t_ns / 1e9
        return time.monotonic()

    # -- callbacks ----------------------------------------------------------------------------
    def _command_callback(self, arm_id: str) -> Callable[[Any], None]:
        return lambda msg: self._on_command(arm_id, msg)

    def _on_command(self, arm_id: str, msg: Any) -> None:
        robot = self.cell.arm(arm_id).robot
        try:
            data = np.asarray(list(msg.data), dtype=np.float64)
        except (TypeError, ValueError):
            data = np.full(0, np.nan)
        limits = self.velocity_limits[arm_id]
        if (
            data.shape != (robot.dof,)
            or not np.all(np.isfinite(data))
            or np.any(np.abs(data) > limits + 1e-9)
        ):
            self.dropped[arm_id] += 1
            self.get_logger().warning(
                f"dropped command of {arm_id}: needs {robot.dof} finite values within the "
                f"velocity limits {limits.tolist()} rad/s, got {data.tolist()} "
                f"({self.dropped[arm_id]} dropped)",
                throttle_duration_sec=2.0,
            )
            return
        self.commands[arm_id] = (data, self._now())
        self.commanded.add(arm_id)

    def _applied(self) -> dict[str, np.ndarray]:
        """Each arm's velocity for this step: its latest command while it is valid, else zero
        (a late planner: ``command_validity``; a silent one: the watchdog; the episode's end)."""
        now = self._now()
        out = {}
        running = self.started and not self.done
        for arm in self.cell.arms:
            a = arm.arm_id
            latest = self.commands.get(a)
            age = now - latest[1] if latest is not None else math.inf
            fresh = age <= self.s.command_timeout
            valid = fresh and age <= self.s.command_validity
            if running:
                self._watch(a, latest is not None and not fresh, now, latest)
                if fresh and not valid:
                    self._expired(a, age)
            still = np.zeros(arm.robot.dof)
            out[a] = latest[0] if running and valid and latest is not None else still
        return out

    def _expired(self, arm_id: str, age: float) -> None:
        """Count (and report, throttled) a step held still because a command ran out."""
        self.expired_steps[arm_id] += 1
        self.get_logger().warning(
            f"{arm_id}'s latest command is {age:.3f} s old (> command_validity "
            f"{self.s.command_validity:g} s: its planner runs late): holding it still until the "
            f"next ({self.expired_steps[arm_id]} steps so far)",
            throttle_duration_sec=2.0,
        )

    def _watch(
        self, arm_id: str, expired: bool, now: float, latest: tuple[np.ndarray, float] | None
    ) -> None:
        """Report the watchdog taking over an arm (and giving it back)."""
        if expired and arm_id not in self._held:
            self._held.add(arm_id)
            self.watchdog_trips[arm_id] += 1
            age = now - latest[1] if latest is not None else math.inf
            self.get_logger().warning(
                f"watchdog: no command for {arm_id} in {age:.2f} s (> command_timeout "
                f"{self.s.command_timeout:g} s): holding it still "
                f"(trip {self.watchdog_trips[arm_id]})"
            )
        elif not expired and arm_id in self._held:
            self._held.discard(arm_id)
            self.get_logger().info(f"watchdog: commands for {arm_id} resumed")

    def _step(self) -> None:
        if not self.started:
            self._maybe_start()
        velocities = self._applied()
        if self.started and not self.done:
            result = self.sim.step(velocities, self.s.dt_ns / 1e9)
            self.t_ns += self.s.dt_ns
            if result.collisions:
                msg = collisions_message(result.collisions, self._stamp_ns())
                self.collision_pub.publish(serialize(msg))
                self.published["collisions"] += 1
            self._check_done(bool(result.collisions))
        self._publish_state(velocities)

    def _maybe_start(self) -> None:
        """Start the episode once every arm's command topic has a matched publisher (a planner
        is up) and every joint-state topic ``min_subscribers`` matched readers (planners and
        recorder), plus ``start_delay`` for discovery to settle, or after ``start_timeout``."""
        now = time.monotonic()
        missing = [a for a in self.cell.arm_ids if self.command_subs[a].get_publisher_count() < 1]
        missing += [
            f"{a} (joint-state readers {pub.get_subscription_count()} < {self.s.min_subscribers})"
            for a, pub in self.state_pubs.items()
            if pub.get_subscription_count() < self.s.min_subscribers
        ]
        if self.s.wait_for_planners and now - self.created < self.s.start_timeout:
            if missing:
                self._ready_at = math.inf
                self.get_logger().info(
                    f"waiting for planners of {missing}", throttle_duration_sec=5.0
                )
                return
            self._ready_at = min(self._ready_at, now)
            if now - self._ready_at < self.s.start_delay:
                return
        elif missing:
            self.get_logger().warning(f"starting without planners for {missing}")
        self.started = True
        self.get_logger().info("episode started")

    def _check_done(self, collided: bool) -> None:
        s, t = self.s, self.t_ns / 1e9
        reached = all(
            goal_distance(self.sim.q[a], self.scenario.goal[a], self.cell, a, s.success_norm)
            < s.success_tolerance
            for a in self.cell.arm_ids
        )
        if collided and s.stop_on_collision:
            self.outcome = "collision"
        elif reached and s.stop_on_success:
            self.outcome = "success"
        elif t >= s.time_limit - 1e-9:
            self.outcome = "time_limit"
        if self.outcome:
            self.done = True
            self._done_at = time.monotonic()
            dropped = sum(self.dropped.values())
            trips = {a: n for a, n in self.watchdog_trips.items() if n}
            expired = {a: n for a, n in self.expired_steps.items() if n}
            self.get_logger().info(
                f"episode done: {self.outcome} after {t:.2f} s ({dropped} commands dropped, "
                f"watchdog trips {trips}, steps held on expired commands {expired})"
            )
            print(f"sim_bridge: episode {self.outcome} t={t:.3f}", flush=True)

    @property
    def finished(self) -> bool:
        """True 0.5 s after the end of the episode with ``exit_when_done`` (the held state
        keeps going out meanwhile, so every subscriber has the final state)."""
        return self.s.exit_when_done and time.monotonic() - self._done_at > 0.5

    def on_stop(self) -> None:
        self.timer.cancel()
        self.sim.close()
        if not self.done:
            state = "running" if self.started else "not started"
            print(f"sim_bridge: stopped, episode {state} t={self.t_ns / 1e9:.3f}", flush=True)
        counts = {
            "published": self.published,
            "dropped_commands": self.dropped,
            "watchdog_trips": self.watchdog_trips,
            "expired_command_steps": self.expired_steps,
        }
        print(f"sim_bridge: counts {json.dumps(counts)}", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `sim_bridge` console script."""
    return run_main("sim_bridge", SimBridgeNode, argv, usage=__doc__)


if __name__ == "__main__":
    sys.exit(main())
