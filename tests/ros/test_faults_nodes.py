"""Faults around a running ``arm_planner`` process: bad peers and a failing solver.

The test process stands in for the bridge (a :class:`World`, a plain rclpy node in this run's DDS
domain): it publishes every arm's joint states at 50 Hz, integrating the planners'
commands, the goals (latched), and scripts faults into what the planners receive. Planners run
as real node processes; their ``/<arm>/planner/status`` stream and log lines are the evidence.
"""

from __future__ import annotations

import itertools
import math
import re
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _ros_testutil import DOMAIN_ID, child_env
from diagnostic_msgs.msg import DiagnosticStatus
from rclpy.qos import DurabilityPolicy, QoSProfile
from sensor_msgs.msg import JointState
from std_msgs.msg import Float64MultiArray

from nehmo_core.robots import load_cell
from nehmo_core.robots.model import Cell
from nehmo_core.sim.scenarios import sample_scenario, scenario_rng
from nehmo_ros.control import ControlSettings
from nehmo_ros.processes import Process, node_command

#: What a status says when the planner itself ran on the tick's observations.
PLANNED = {"optimal", "naive", "unconstrained", "infeasible", "iteration_limit", "timeout"}
PEER_TIMEOUT = ControlSettings().peer_timeout  # [s] the planner's default
STARTUP_S = 240.0  # a CPU-starved host starts node processes slowly

Script = Callable[[float], "tuple[list[str], list[float]] | str | None"]


@dataclass
class Status:
    """One received planner status: arrival time [s, monotonic], message, level, values."""

    t: float
    message: str
    level: bytes
    values: dict[str, str]

    @property
    def command(self) -> np.ndarray:
        return np.array([float(x) for x in self.values["command"].split(",")])

    @property
    def observation_ns(self) -> int:
        """Wall time [ns] of the planner tick whose observations this status was planned from."""
        return int(self.values["observation_ns"])

    def names(self, key: str, arm_id: str) -> bool:
        """Whether the comma-separated list ``key`` (``stale_peers``, ...) holds ``arm_id``."""
        return arm_id in self.values[key].split(",")


@dataclass
class World:
    """Joint states of every arm at 50 Hz (integrating commands), goals, and scripted faults."""

    cell: Cell
    q: dict[str, np.ndarray]
    goals: dict[str, np.ndarray]
    scripts: dict[str, Script] = field(default_factory=dict)
    statuses: dict[str, list[Status]] = field(default_factory=dict)
    script_start: float = math.inf

    def __post_init__(self) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node

        self.rclpy = rclpy
        rclpy.init(args=[], domain_id=DOMAIN_ID)
        self.node = n = Node("fake_world")
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.state_pubs = {
            a: n.create_publisher(JointState, f"/{a}/joint_states", 10) for a in self.cell.arm_ids
        }
        self.goal_pubs = {
            a: n.create_publisher(JointState, f"/{a}/goal", latched) for a in self.cell.arm_ids
        }
        self.commands: dict[str, np.ndarray] = {}
        for a in self.cell.arm_ids:
            self.statuses[a] = []
            n.create_subscription(
                Float64MultiArray,
                f"/{a}/velocity_controller/commands",
                lambda m, a=a: self.commands.__setitem__(a, np.array(m.data)),
                10,
            )
            n.create_subscription(
                DiagnosticStatus, f"/{a}/planner/status", lambda m, a=a: self._status(a, m), 50
            )
        for a, goal in self.goals.items():
            self.publish_goal(a, list(goal))
        self.last = time.monotonic()
        n.create_timer(0.02, self._tick)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(n)

    def names(self, arm_id: str) -> list[str]:
        return list(self.cell.arm(arm_id).robot.joint_names)

    def publish_goal(self, arm_id: str, position: list[float]) -> None:
        self.goal_pubs[arm_id].publish(JointState(name=self.names(arm_id), position=position))

    def _status(self, arm_id: str, m: Any) -> None:
        values = {kv.key: kv.value for kv in m.values}
        self.statuses[arm_id].append(Status(time.monotonic(), m.message, m.level, values))

    def _tick(self) -> None:
        now = time.monotonic()
        dt, self.last = now - self.last, now
        sec, nanosec = divmod(time.time_ns(), 1_000_000_000)
        for a, pub in self.state_pubs.items():
            robot = self.cell.arm(a).robot
            u = self.commands.get(a)
            if u is not None and u.shape == (robot.dof,):
                self.q[a] = np.clip(self.q[a] + dt * u, robot.lower, robot.upper)
            names, position = self.names(a), [float(x) for x in self.q[a]]
            script = self.scripts.get(a)
            shown = script(now - self.script_start) if script and now >= self.script_start else None
            if shown == "silent":
                continue
            if isinstance(shown, tuple):
                names, position = shown
            msg = JointState(name=names, position=position)
            msg.header.stamp.sec, msg.header.stamp.nanosec = sec, nanosec
            pub.publish(msg)

    def spin(self, seconds: float, until: Callable[[], bool] | None = None) -> bool:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.executor.spin_once(0.01)
            if until is not None and until():
                return True
        return until is None

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def _planner(arm_id: str, cell: str, log: Path, **params: object) -> Process:
    argv = node_command(
        "nehmo_ros.arm_planner",
        {"arm_id": arm_id, "cell": cell, "model": "shipped", **params},
        ["-r", f"__node:=planner_{arm_id}"],
    )
    return Process(arm_id, argv, child_env(), log, 0)


def _scenario(cell: Cell) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    s = sample_scenario(cell, scenario_rng(0, 0))
    return {a: np.array(q) for a, q in s.start.items()}, {a: np.array(q) for a, q in s.goal.items()}


def _warnings(text: str, pattern: str) -> list[str]:
    return [line for line in text.splitlines() if "[WARN]" in line and re.search(pattern, line)]


# ------------------------------------------------------------------------------ peer faults
#: What the peer ur5_1 sends, one phase after the other. A phase ends on what the planner
#: reports, not on a timer (see :class:`PeerScript`).
PHASES = ["normal", "nan", "normal", "short", "normal", "teleport", "normal", "silent", "normal"]
NORMAL_PLANS = 10  # a normal phase ends once this many statuses were planned from its states
FAULT_STATUSES = 15  # a fault ends this many statuses after the planner first reported it
PHASE_DEADLINE = 30.0  # [s] a phase whose event never comes ends anyway (the tests then fail)


#: The status key that names the peer while each fault lasts.
FAULT_KEY = {
    "nan": "untrusted_peers",
    "short": "untrusted_peers",
    "teleport": "untrusted_peers",
    "silent": "stale_peers",
}


@dataclass
class PeerLog:
    """What the scripted peer ur5_1 did: the wall time [ns] at which each phase of PHASES
    began (every joint state of a phase went out after its start and before the next phase's
    start), how many joint states it published in each, and the phases that ended at
    PHASE_DEADLINE because the planner never showed what ends them."""

    starts: list[int] = field(default_factory=list)
    sent: list[int] = field(default_factory=list)
    timed_out: list[str] = field(default_factory=list)
    done: bool = False  # the last phase's event came: the script has run through


def _first_report(statuses: list[Status], log: PeerLog, k: int) -> int | None:
    """Index of the first status planned from observations made after phase ``k`` began that
    names ur5_1 under the key of that phase's fault (None: there is none)."""
    key = FAULT_KEY[PHASES[k]]
    return next(
        (
            i
            for i, s in enumerate(statuses)
            if s.observation_ns >= log.starts[k] and s.names(key, "ur5_1")
        ),
        None,
    )


@dataclass
class PeerScript:
    """The joint states ur5_1 shows in each phase. A normal phase ends once the planner has
    planned NORMAL_PLANS times from observations made in it; a fault ends FAULT_STATUSES
    statuses after the planner's first report of it (a silence lasts at least peer_timeout,
    since only then is it reported): the fault windows follow the planner's own evidence, so a
    slow machine stretches them instead of cutting them short."""

    world: World
    log: PeerLog
    k: int = 0
    since: float = 0.0  # [s] script time at which phase k began

    def _ended(self) -> bool:
        statuses = self.world.statuses["ur5_0"]
        start = self.log.starts[self.k]
        if PHASES[self.k] == "normal":
            planned = [s for s in statuses if s.observation_ns >= start and s.message in PLANNED]
            return len(planned) >= NORMAL_PLANS
        first = _first_report(statuses, self.log, self.k)
        return first is not None and len(statuses) - first >= FAULT_STATUSES

    def __call__(self, t: float) -> tuple[list[str], list[float]] | str | None:
        if not self.log.starts:
            self._enter(t)
        elif not self.log.done:
            ended = self._ended()
            if not ended and t - self.since > PHASE_DEADLINE:
                self.log.timed_out.append(f"{self.k}:{PHASES[self.k]}")
                ended = True
            if ended and self.k == len(PHASES) - 1:
                self.log.done = True  # the last phase goes on
            elif ended:
                self.k += 1
                self._enter(t)
        phase = PHASES[self.k]
        if phase != "silent":
            self.log.sent[self.k] += 1  # the World publishes what this returns right away
        names = self.world.names("ur5_1")
        q = [float(x) for x in self.world.q["ur5_1"]]
        if phase == "nan":
            return names, [math.nan, *q[1:]]
        if phase == "short":
            return names[:5], q[:5]
        if phase == "teleport":
            return names, [q[0] + 0.8, q[1] + 0.5, *q[2:]]
        if phase == "silent":
            return "silent"
        return None

    def _enter(self, t: float) -> None:
        self.since = t
        self.log.starts.append(time.time_ns())
        self.log.sent.append(0)


@pytest.fixture(scope="module")
def peer_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[World, PeerLog, str, int]:
    """One planner (ur5_0) while its peer ur5_1 goes through PHASES; a goal outside the joint
    limits arrives once the last phase is under way."""
    cell = load_cell("dual_ur5")
    start, goals = _scenario(cell)
    world = World(cell, start, {"ur5_0": goals["ur5_0"]})
    log = PeerLog()
    world.scripts["ur5_1"] = PeerScript(world, log)
    proc = _planner("ur5_0", "dual_ur5", tmp_path_factory.mktemp("peer") / "planner.log")
    try:
        started = world.spin(STARTUP_S, lambda: len(world.statuses["ur5_0"]) >= 10)
        assert started, proc.output()[-3000:]
        world.script_start = time.monotonic()
        finished = world.spin(PHASE_DEADLINE * (len(PHASES) + 1), lambda: log.done)
        world.publish_goal("ur5_0", [10.0] * 6)  # outside the joint limits: rejected
        rejected = world.spin(PHASE_DEADLINE, lambda: "rejected goal" in proc.output())
        alive = proc.proc.poll() is None
        code = proc.stop(20.0)
    finally:
        proc.stop(5.0)
        world.close()  # before the next module fixture starts a runtime of its own
    assert alive, proc.output()[-3000:]
    assert finished and len(log.starts) == len(PHASES), log.starts  # every phase came
    assert rejected, proc.output()[-3000:]
    return world, log, proc.output(), code if code is not None else -9


def test_faulty_peer_never_crashes_the_planner(peer_run: tuple) -> None:
    world, _, output, code = peer_run
    assert code == 0, output[-3000:]
    assert "Traceback" not in output
    statuses = world.statuses["ur5_0"]
    commands = np.array([s.command for s in statuses])
    assert np.all(np.isfinite(commands)) and np.all(np.abs(commands) <= 0.5 + 1e-12)


@pytest.mark.parametrize("phase", ["nan", "short", "silent"])
def test_bad_or_silent_peer_is_never_planned_against(peer_run: tuple, phase: str) -> None:
    """After the first bad message (or peer_timeout of silence) the arm holds still (the
    default ``stale_policy``), or takes the fail-safe while a solve is late. The window runs
    from the planner's first report of the fault to its last tick before the peer's next
    phase began: no state of that phase can have reached it by then."""
    world, log, _, _ = peer_run
    k = PHASES.index(phase)
    statuses = world.statuses["ur5_0"]
    first = _first_report(statuses, log, k)
    assert first is not None, (log.timed_out, [s.message for s in statuses])
    window = [s for s in statuses[first:] if s.observation_ns < log.starts[k + 1]]
    planned = [s for s in window if s.message in PLANNED]
    if phase == "silent":  # planned from a state sent before the silence that came in late
        planned = [s for s in planned if float(s.values["age_ur5_1"]) > PEER_TIMEOUT]
    assert not planned, [(s.message, s.values["age_ur5_1"]) for s in window]
    reported = [s for s in window if s.message in ("stale_peer", "untrusted_peer")]
    assert reported, [s.message for s in window]
    assert all(
        s.names("stale_peers", "ur5_1") or s.names(FAULT_KEY[phase], "ur5_1") for s in reported
    )
    assert all(s.level == DiagnosticStatus.WARN for s in reported)
    held = [s for s in window if s.message != "deadline_missed" and s.message not in PLANNED]
    assert all(s.values["hold"] == "true" and not np.any(s.command) for s in held)


def test_rejections_and_jumps_are_counted(peer_run: tuple) -> None:
    world, log, _, _ = peer_run
    last = world.statuses["ur5_0"][-1].values
    bad = sum(n for name, n in zip(PHASES, log.sent, strict=True) if name in ("nan", "short"))
    # at least one per garbage phase, and never a well-formed state (best effort: some may drop)
    assert 2 <= int(last["rejected_states"]) <= bad, (last["rejected_states"], bad)
    assert int(last["state_jumps"]) >= 2  # into the teleport and back


def test_teleport_untrusts_the_peer(peer_run: tuple) -> None:
    """A status planned after the jump into the teleport was counted (and before the jump back
    was) names the peer untrusted."""
    world, log, _, _ = peer_run
    k = PHASES.index("teleport")
    statuses = world.statuses["ur5_0"]
    before = [
        int(s.values["state_jumps"])
        for s in statuses
        if int(s.values["publish_wall_ns"]) < log.starts[k]
    ]
    assert before, [s.message for s in statuses]
    jumped = [
        s
        for s in statuses
        if s.observation_ns >= log.starts[k] and int(s.values["state_jumps"]) == max(before) + 1
    ]
    untrusted = [
        s for s in jumped if s.message == "untrusted_peer" and s.names("untrusted_peers", "ur5_1")
    ]
    assert untrusted, [(s.message, s.values["untrusted_peers"]) for s in jumped]
    assert all(s.values["hold"] == "true" and not np.any(s.command) for s in untrusted)


def test_normal_planning_resumes_after_each_fault(peer_run: tuple) -> None:
    """After the planner reported each fault, it plans again from observations made after the
    fault ended, before it reports the next fault."""
    world, log, _, _ = peer_run
    statuses = world.statuses["ur5_0"]
    for k, name in enumerate(PHASES):
        if name != "normal" or k == 0:
            continue
        fault = _first_report(statuses, log, k - 1)
        assert fault is not None, (k, [s.message for s in statuses])
        following = _first_report(statuses, log, k + 1) if k + 1 < len(PHASES) else None
        after = [s for s in statuses[fault:following] if s.observation_ns >= log.starts[k]]
        assert any(s.message in PLANNED for s in after), (
            k,
            log.timed_out,
            [s.message for s in after],
        )


def test_faults_are_logged_once_per_cause_and_interval(peer_run: tuple) -> None:
    _, _, output, _ = peer_run
    rejected = _warnings(output, r"joint state of ur5_1 rejected")
    jumped = _warnings(output, r"joint state of ur5_1 jumped")
    stale = _warnings(output, r"peers stale")
    assert rejected and jumped and stale, output[-3000:]
    assert len(rejected) <= 6  # throttled: ≤ 1 per 2 s, not 1 per message
    assert "rejected goal" in output and "joint limits" in output


# ---------------------------------------------------------------------------- solver faults
SOLVER_FAULTS = {"ur5_0": "raise@20", "ur5_1": "hang@20", "ur5_2": "slow:0.06@20"}
RUN_STATUSES = 160  # statuses of every planner before the run ends (the fault starts ~20th)


@pytest.fixture(scope="module")
def solver_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[World, dict, dict]:
    """Three planners of triple_ur5, each with its solver failing differently after 20 calls."""
    cell = load_cell("triple_ur5")
    start, goals = _scenario(cell)
    world = World(cell, start, goals)
    out = tmp_path_factory.mktemp("solver")
    procs = {
        a: _planner(a, "triple_ur5", out / f"{a}.log", fault_injection=f, allow_unmodelled=True)
        for a, f in SOLVER_FAULTS.items()
    }
    try:
        started = world.spin(
            STARTUP_S, lambda: all(len(world.statuses[a]) >= 60 for a in SOLVER_FAULTS)
        )
        assert started, {a: p.output()[-2000:] for a, p in procs.items()}
        # counted in statuses, not seconds: every planner goes on ~4 s at 25 Hz past the fault
        ran = world.spin(
            STARTUP_S, lambda: all(len(world.statuses[a]) >= RUN_STATUSES for a in SOLVER_FAULTS)
        )
        assert ran, {a: len(world.statuses[a]) for a in SOLVER_FAULTS}
        alive = {a: p.proc.poll() is None for a, p in procs.items()}
        codes = {a: p.stop(20.0) for a, p in procs.items()}
    finally:
        for p in procs.values():
            p.stop(5.0)
        world.close()
    outputs = {a: p.output() for a, p in procs.items()}
    assert all(alive.values()), outputs
    return world, codes, outputs


def _after_fault(world: World, arm_id: str) -> list[Status]:
    """Statuses well after the fault began (status k comes from plan call k − 1; the fault
    starts at call 20, later when ticks are missed)."""
    return world.statuses[arm_id][40:]


def test_solver_faults_never_end_a_node(solver_run: tuple) -> None:
    world, codes, outputs = solver_run
    for a in SOLVER_FAULTS:
        assert codes[a] == 0, outputs[a][-3000:]
        assert "fault_injection" in outputs[a] and "is ON" in outputs[a]
        after = _after_fault(world, a)
        assert len(after) >= 20, (a, len(after))  # still publishing after the fault began
        assert all(s.values["fault_injection"] == SOLVER_FAULTS[a] for s in after)


def test_a_raising_solver_gets_the_fail_safe_and_is_counted(solver_run: tuple) -> None:
    world, _, outputs = solver_run
    after = _after_fault(world, "ur5_0")
    failed = [s for s in after if s.message == "failed"]
    assert len(failed) >= 0.8 * len(after)
    assert all(s.level == DiagnosticStatus.ERROR for s in failed)
    assert all("Injected" in s.values["error"] for s in failed)
    for s in failed:  # the fail-safe within ±ū, never NaN
        assert np.all(np.isfinite(s.command)) and np.abs(s.command).max() <= 0.5 + 1e-12
    assert sum(bool(np.any(s.command)) for s in failed) >= 0.5 * len(failed)  # it does move
    last = after[-1].values
    assert int(last["solver_errors"]) >= len(failed)
    assert 1 <= len(_warnings(outputs["ur5_0"], "solver failed")) <= 5


def test_a_hung_solver_ends_in_holding_still(solver_run: tuple) -> None:
    world, _, outputs = solver_run
    after = _after_fault(world, "ur5_1")
    assert all(s.message == "deadline_missed" for s in after)
    held = after[10:]  # > peer_timeout (0.25 s) after the hang began: zero velocity
    assert held and all(s.values["hold"] == "true" and not np.any(s.command) for s in held)
    misses = [int(s.values["deadline_misses"]) for s in after]
    ticks = [int(s.values["ticks"]) for s in after]
    assert misses[-1] - misses[0] == ticks[-1] - ticks[0]  # every tick counted
    warned = _warnings(outputs["ur5_1"], "missed its deadline")
    assert warned  # reported, and throttled: at most one line every WARN_EVERY (2 s) of log time
    stamps = [float(line.split("] [", 1)[1].split("]", 1)[0]) for line in warned]
    assert all(b - a >= 1.9 for a, b in itertools.pairwise(stamps)), stamps


def test_a_slow_solver_misses_every_deadline_safely(solver_run: tuple) -> None:
    """Solves of 1.5 periods miss every deadline: the fail-safe of the last observations taken
    up while it is at most 1.5 periods old, else zero (``late_plan``), never a plan."""
    world, _, _ = solver_run
    after = _after_fault(world, "ur5_2")
    missed = [s for s in after if s.message == "deadline_missed"]
    late = [s for s in after if s.message == "late_plan"]
    assert len(missed) + len(late) >= 0.9 * len(after)
    assert missed and all(s.values["fail_safe"] == "true" for s in missed)
    assert all(s.values["hold"] == "true" and not np.any(s.command) for s in late)
    assert int(after[-1].values["deadline_misses"]) >= 0.9 * len(after)
