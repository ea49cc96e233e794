"""Processes dying under the suite: a planner SIGKILLed mid-episode, the bridge and a recorder
stopped by signals, a second recorder SIGKILLed and its log recovered with the command line.

One dual-UR5 episode in wall time (scenario 0 of seed 0: the arms' paths cross) with the
bridge, two planners and two recorders as separate rclpy processes, in this test run's DDS
domain. The run goes from event to event: planner ur5_1 is SIGKILLed once its arm moves,
malformed commands for that arm go out once the bridge's watchdog holds it, recorder B is
SIGKILLed once its file holds joint states from after all that, and recorder A is stopped with
SIGTERM at the end; A's finished log is the reference for what B must still hold.
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _ros_testutil import DOMAIN_ID, REPO, child_env, spin_until

from nehmo_core.logs import LogFileError, iter_log, read_log, summarize
from nehmo_core.logs.messages import DiagnosticStatus, JointState
from nehmo_core.logs.recover import recover
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import save_scenario_set
from nehmo_core.sim.scenarios import generate_scenario_set
from nehmo_ros.control import ControlSettings
from nehmo_ros.processes import Process, node_command

STARTUP_S = 240.0
WAIT_S = 60.0  # deadline of every wait for an event of the running suite
COMMAND_TIMEOUT = 0.2  # the bridge's watchdog [s]
BAD_COMMANDS = 30  # malformed commands sent for the killed planner's arm
HELD_STATES = 10  # held states of that arm the run waits for
PEER_TIMEOUT = ControlSettings().peer_timeout  # [s] the planners' default
LOG_LINE = re.compile(r"^\[(\w+)\] \[(\d+)\.(\d+)\] \[[^\]]*\]: (.*)$")  # rcutils' default


@dataclass(frozen=True)
class Run:
    out: Path
    t_kill_planner: int  # [ns] wall time of the SIGKILL of planner ur5_1
    t_flushed: int  # [ns] recorder B had flushed joint states of every arm stamped after this
    t_recorded: int  # [ns] recorder A had flushed joint states stamped after this before the stop
    t_stop: int  # [ns] wall time of the stop signals
    codes: dict[str, int | None]
    outputs: dict[str, str]


def _values(status: Any) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _names(values: dict[str, str], key: str, arm_id: str) -> bool:
    """Whether the comma-separated list ``key`` (``stale_peers``, ...) holds ``arm_id``."""
    return arm_id in values[key].split(",")


class Probe:
    """A plain rclpy node in the test process: it hears every arm's joint states (the bridge
    waits for it as for the suite's nodes) and ur5_0's planner status, and sends malformed
    commands for ur5_1."""

    def __init__(self) -> None:
        import rclpy
        from diagnostic_msgs.msg import DiagnosticStatus as RosStatus
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import qos_profile_sensor_data
        from sensor_msgs.msg import JointState as RosJointState

        self.rclpy = rclpy
        rclpy.init(args=[], domain_id=DOMAIN_ID)
        self.node = Node("probe")
        self.moved = False  # ur5_1 moved: a state with a joint speed above 0.05 rad/s
        self.states: list[tuple[int, bool]] = []  # ur5_1: (stamp [ns], held: zero velocity)
        self.statuses: list[dict[str, str]] = []  # ur5_0's planner status values
        self._held: tuple[int, int, int] = (0, 0, 0)  # held_since: (since, states seen, count)
        self.node.create_subscription(
            RosJointState, "/ur5_0/joint_states", lambda m: None, qos_profile_sensor_data
        )
        self.node.create_subscription(
            RosJointState, "/ur5_1/joint_states", self._on_state, qos_profile_sensor_data
        )
        self.node.create_subscription(
            RosStatus, "/ur5_0/planner/status", lambda m: self.statuses.append(_values(m)), 50
        )
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.closed = False

    def _on_state(self, msg: Any) -> None:
        stamp = int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)
        speed = float(np.abs(np.asarray(msg.velocity)).max(initial=0.0))
        self.moved = self.moved or speed > 0.05
        self.states.append((stamp, speed == 0.0))

    def spin(self, seconds: float, until: Callable[[], bool]) -> bool:
        """Spin until ``until()`` holds (True) or ``seconds`` pass (False)."""
        return spin_until(self.executor, seconds, until)

    def held_since(self, t_ns: int) -> int:
        """States of ur5_1 stamped after ``t_ns`` with zero velocity."""
        since, seen, count = self._held if self._held[0] == t_ns else (t_ns, 0, 0)
        count += sum(t > t_ns and held for t, held in self.states[seen:])
        self._held = (since, len(self.states), count)
        return count

    def planned_since(self, t_ns: int) -> bool:
        """ur5_0 planned around ur5_1 from observations made after ``t_ns``."""
        return any(
            int(v["observation_ns"]) > t_ns and _names(v, "peers_constrained", "ur5_1")
            for v in self.statuses
        )

    def bad_commands(self, count: int) -> None:
        """``count`` malformed commands for ur5_1 at 25 Hz (NaN, too short, too fast), once the
        bridge and both recorders subscribe; returns when every subscriber acknowledged them."""
        from rclpy.duration import Duration
        from std_msgs.msg import Float64MultiArray

        bad = [[math.nan] * 6, [0.1] * 5, [10.0] * 6]
        topic = "/ur5_1/velocity_controller/commands"
        pub = self.node.create_publisher(Float64MultiArray, topic, 10)
        matched = self.spin(WAIT_S, lambda: pub.get_subscription_count() >= 3)
        assert matched, pub.get_subscription_count()  # the bridge and two recorders
        for k in range(count):
            pub.publish(Float64MultiArray(data=bad[k % len(bad)]))
            time.sleep(0.04)
        assert pub.wait_for_all_acked(Duration(seconds=WAIT_S))

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)
        self.rclpy.try_shutdown()


def _watchdog_hold_ns(output: str, arm_id: str) -> int | None:
    """Wall time [ns] of the bridge's last watchdog trip for ``arm_id`` when no resume line
    followed it (the watchdog holds the arm since), else None."""
    held = None
    for line in output.splitlines():
        match = LOG_LINE.match(line)
        if match is None:
            continue
        message = match.group(4)
        if message.startswith(f"watchdog: no command for {arm_id} "):
            held = int(match.group(2)) * 1_000_000_000 + int(match.group(3).ljust(9, "0")[:9])
        elif message.startswith(f"watchdog: commands for {arm_id} resumed"):
            held = None
    return held


def _poll(seconds: float, until: Callable[[], bool]) -> bool:
    """Check ``until()`` every 0.1 s for up to ``seconds``; whether it held."""
    end = time.monotonic() + seconds
    while not until():
        if time.monotonic() >= end:
            return False
        time.sleep(0.1)
    return True


def _flushed_after(bag: Path, scratch: Path, t_ns: int) -> bool:
    """Whether the bag of a running recorder already holds, on disk, joint states of every
    arm stamped after ``t_ns`` (read through a recovered copy)."""
    copy = scratch / f"copy_{time.monotonic_ns()}"
    scratch.mkdir(exist_ok=True)
    try:
        recover(bag, copy)
        return all(any(t > t_ns for t, _ in _states(copy, a)) for a in ("ur5_0", "ur5_1"))
    finally:
        shutil.rmtree(copy, ignore_errors=True)


def _stop(proc: Process, timeout: float) -> int | None:
    """Wait for a signalled process; one still running after ``timeout`` gets SIGABRT (its
    Python stack goes to its log) and then SIGKILL."""
    try:
        proc.proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.proc.send_signal(signal.SIGABRT)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.proc.wait(10.0)  # faulthandler writes the stack, then the process ends
    return proc.stop(5.0)


def _wait(proc: Process, marker: str) -> None:
    assert proc.wait_for(marker, STARTUP_S), proc.output()[-3000:]


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    out = tmp_path_factory.mktemp("kill")
    cell = load_cell("dual_ur5")
    scenarios = save_scenario_set(generate_scenario_set(cell, 0, 1), out / "scenarios.json")
    env = child_env(PYTHONFAULTHANDLER="1")  # a hung process shows where, on SIGABRT
    procs: dict[str, Process] = {}
    probes: list[Probe] = []

    def launch(name: str, module: str, params: dict[str, object]) -> Process:
        argv = node_command(module, params, ["-r", f"__node:={name}"])
        procs[name] = Process(name, argv, env, out / f"{name}.log", 0)
        return procs[name]

    try:
        for name in ("recorder_a", "recorder_b"):
            launch(name, "nehmo_ros.recorder", {"cell": cell.name, "output": out / name})
        for arm_id in cell.arm_ids:
            launch(
                f"planner_{arm_id}", "nehmo_ros.arm_planner", {"arm_id": arm_id, "cell": "dual_ur5"}
            )
        for name in ("recorder_a", "recorder_b"):
            _wait(procs[name], "recording")
        probe = Probe()
        probes.append(probe)
        launch(
            "bridge",
            "sim_bridge.bridge",
            {
                "cell": cell.name,
                "scenarios": scenarios,
                "time_limit": 1200.0,
                "stop_on_success": False,  # the watchdog watches until the stop
                "start_timeout": STARTUP_S,
                "command_timeout": COMMAND_TIMEOUT,
                "min_subscribers": 5,  # both planners, both recorders and the probe
            },
        )
        _wait(procs["bridge"], "episode started")
        assert probe.spin(WAIT_S, lambda: probe.moved), len(probe.states)  # ur5_1 moves
        t_kill_planner = time.time_ns()
        os.kill(procs["planner_ur5_1"].proc.pid, signal.SIGKILL)
        procs["planner_ur5_1"].proc.wait(WAIT_S)
        bridge = procs["bridge"]
        held = _poll(WAIT_S, lambda: _watchdog_hold_ns(bridge.output(), "ur5_1") is not None)
        assert held, bridge.output()[-3000:]
        probe.bad_commands(BAD_COMMANDS)  # garbage must not move the held arm
        hold_ns = _watchdog_hold_ns(bridge.output(), "ur5_1")
        assert hold_ns is not None, bridge.output()[-3000:]
        assert probe.spin(WAIT_S, lambda: probe.held_since(hold_ns) >= HELD_STATES)
        assert probe.spin(WAIT_S, lambda: probe.planned_since(t_kill_planner))
        t_flushed = time.time_ns()
        scratch = out / "scratch"
        flushed = _poll(WAIT_S, lambda: _flushed_after(out / "recorder_b", scratch, t_flushed))
        assert flushed, procs["recorder_b"].output()[-3000:]
        os.kill(procs["recorder_b"].proc.pid, signal.SIGKILL)
        procs["recorder_b"].proc.wait(WAIT_S)
        probe.close()
        t_recorded = time.time_ns()
        recorded = _poll(WAIT_S, lambda: _flushed_after(out / "recorder_a", scratch, t_recorded))
        assert recorded, procs["recorder_a"].output()[-3000:]  # A records on after B's kill
        t_stop = time.time_ns()
        procs["bridge"].proc.send_signal(signal.SIGINT)
        procs["recorder_a"].proc.send_signal(signal.SIGTERM)
        procs["planner_ur5_0"].proc.send_signal(signal.SIGINT)
        codes = {}
        for name in ("bridge", "recorder_a", "planner_ur5_0", "planner_ur5_1", "recorder_b"):
            codes[name] = _stop(procs[name], 20.0)
        codes["planner_ur5_1"] = procs["planner_ur5_1"].proc.returncode
        codes["recorder_b"] = procs["recorder_b"].proc.returncode
        outputs = {name: p.output() for name, p in procs.items()}
        yield Run(out, t_kill_planner, t_flushed, t_recorded, t_stop, codes, outputs)
    finally:
        for probe in probes:
            probe.close()
        for p in procs.values():
            p.stop(5.0)


def _states(log: Path, arm_id: str) -> list[tuple[int, JointState]]:
    return [
        (r.log_time_ns, r.message)
        for r in iter_log(log, [f"/{arm_id}/joint_states"])
        if isinstance(r.message, JointState)
    ]


def test_signals_end_bridge_and_recorder_cleanly(run: Run) -> None:
    assert run.codes["bridge"] == 0, run.outputs["bridge"][-3000:]
    assert run.codes["recorder_a"] == 0, run.outputs["recorder_a"][-3000:]
    assert run.codes["planner_ur5_0"] == 0, run.outputs["planner_ur5_0"][-3000:]
    assert "sim_bridge: stopped, episode running" in run.outputs["bridge"]
    assert "messages written to" in run.outputs["recorder_a"]
    for name in ("bridge", "recorder_a", "planner_ur5_0"):
        assert "Traceback" not in run.outputs[name], run.outputs[name][-3000:]
    summary = summarize(run.out / "recorder_a")  # a finished file: summary section present
    assert summary.message_count > 500
    assert summary.end_ns > run.t_recorded  # all it had written before the stop is there


def test_the_watchdog_stops_the_arm_of_a_killed_planner(run: Run) -> None:
    assert run.codes["planner_ur5_1"] == -signal.SIGKILL
    hold_ns = _watchdog_hold_ns(run.outputs["bridge"], "ur5_1")
    assert hold_ns is not None, run.outputs["bridge"][-3000:]  # held from then to the end
    line = next(x for x in run.outputs["bridge"].splitlines() if x.startswith("sim_bridge: counts"))
    counts = json.loads(line.split("counts ", 1)[1])
    # the kill trips it; a planner starved of CPU before the kill may have tripped it already
    assert counts["watchdog_trips"]["ur5_1"] >= 1
    # NaN, short and too fast: every one the bridge took is dropped (its reader keeps 10)
    assert 1 <= counts["dropped_commands"]["ur5_1"] <= BAD_COMMANDS
    assert counts["dropped_commands"]["ur5_0"] == 0
    assert "dropped command of ur5_1" in run.outputs["bridge"]
    commands = [
        np.asarray(r.message.data, dtype=float)
        for r in iter_log(run.out / "recorder_a", ["/ur5_1/velocity_controller/commands"])
    ]
    malformed = [c for c in commands if c.shape != (6,) or not np.all(np.abs(c) <= 1.0)]
    assert len(malformed) == BAD_COMMANDS  # every one went out (recorder A heard them all)
    states = _states(run.out / "recorder_a", "ur5_1")
    before = [m for t, m in states if t < run.t_kill_planner]
    assert any(np.any(np.abs(m.velocity) > 0.05) for m in before)  # it was moving
    held = [m for t, m in states if t > hold_ns]
    assert len(held) >= HELD_STATES
    assert all(not np.any(m.velocity) for m in held)
    positions = np.array([m.position for m in held])
    assert np.ptp(positions, axis=0).max() == 0.0


def test_the_other_arm_keeps_planning_around_it(run: Run) -> None:
    """ur5_0 plans around the held arm from observations made after the kill, and never plans
    against it while it is stale or untrusted."""
    log = run.out / "recorder_a"
    statuses = [
        _values(r.message)
        for r in iter_log(log, ["/ur5_0/planner/status"])
        if isinstance(r.message, DiagnosticStatus)
    ]
    after = [v for v in statuses if run.t_kill_planner < int(v["observation_ns"]) < run.t_stop]
    planned = [v for v in after if v["peers_constrained"]]  # plan() ran (no deadline miss)
    assert planned, [(v["observation_ns"], v["stale_peers"]) for v in after]
    assert all(_names(v, "peers_constrained", "ur5_1") for v in planned)  # planned around
    assert all(not v["stale_peers"] and not v["untrusted_peers"] for v in planned)
    assert all(float(v["age_ur5_1"]) <= PEER_TIMEOUT for v in planned)
    assert not list(iter_log(log, ["/nehmo/collisions"]))


def test_a_sigkilled_recorder_log_is_recovered_by_the_command(run: Run) -> None:
    assert run.codes["recorder_b"] == -signal.SIGKILL
    broken, fixed = run.out / "recorder_b", run.out / "recorder_b_fixed"
    with pytest.raises(LogFileError, match=r"nehmo_core\.logs\.recover"):
        read_log(broken)
    command = [sys.executable, "-m", "nehmo_core.logs.recover", str(broken), str(fixed)]
    result = subprocess.run(command, env=child_env(), capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 0, result.stderr
    assert "messages" in result.stdout and "written to" in result.stdout
    assert "Traceback" not in result.stderr
    again = subprocess.run(command, env=child_env(), capture_output=True, text=True, cwd=REPO)
    assert again.returncode == 1 and "does not overwrite" in again.stderr  # never clobbers
    # Everything B had flushed before the kill (every arm's joint states up to t_flushed, seen
    # in its file while it ran) is there: compare with recorder A, which heard the same
    # publishers, from the time both heard them (the bridge publishes the held state before
    # the episode; one recorder may match it earlier than the other).
    for arm_id in ("ur5_0", "ur5_1"):
        a = [t for t, _ in _states(run.out / "recorder_a", arm_id) if t <= run.t_flushed]
        b = [t for t, _ in _states(fixed, arm_id) if t <= run.t_flushed]
        assert a and b, (arm_id, len(a), len(b))
        both = max(a[0], b[0])
        a, b = [t for t in a if t >= both], [t for t in b if t >= both]
        assert len(a) >= 10 and len(b) >= len(a) - 2, (arm_id, len(a), len(b))
        assert any(t > run.t_flushed for t, _ in _states(fixed, arm_id))
