"""Processes dying under the suite: a planner SIGKILLed mid-episode, the bridge and a recorder
stopped by signals, a second recorder SIGKILLed and its log recovered with the command line.

One dual-UR5 episode in wall time (scenario 0 of seed 0: the arms' paths cross) with the
bridge, two planners and two recorders as separate rclpy processes, in this test run's DDS
domain. Recorder A is stopped with SIGTERM at the end, recorder B is SIGKILLed
a few seconds after the planner; A's finished log is the reference for what B must still hold.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from _ros_testutil import DOMAIN_ID, REPO, child_env

from nehmo_core.logs import LogFileError, iter_log, read_log, summarize
from nehmo_core.logs.messages import DiagnosticStatus, JointState
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import save_scenario_set
from nehmo_core.sim.scenarios import generate_scenario_set
from nehmo_ros.processes import Process, node_command

STARTUP_S = 240.0
COMMAND_TIMEOUT = 0.2  # the bridge's watchdog [s]


@dataclass(frozen=True)
class Run:
    out: Path
    t_kill_planner: int  # [ns] wall time of the SIGKILL of planner ur5_1
    t_kill_recorder: int  # [ns] wall time of the SIGKILL of recorder B
    t_stop: int  # [ns] wall time of the stop signals
    codes: dict[str, int | None]
    outputs: dict[str, str]


def _bad_commands(arm_id: str, seconds: float) -> None:
    """Publish malformed commands for ``arm_id`` at 25 Hz: NaN, too short, too fast."""
    import rclpy
    from rclpy.node import Node
    from std_msgs.msg import Float64MultiArray

    bad = [[math.nan] * 6, [0.1] * 5, [10.0] * 6]
    rclpy.init(args=[], domain_id=DOMAIN_ID)
    try:
        node = Node("bad_commands")
        topic = f"/{arm_id}/velocity_controller/commands"
        pub = node.create_publisher(Float64MultiArray, topic, 10)
        matched = time.monotonic() + 30.0  # discovery of the subscriptions
        while (
            pub.get_subscription_count() < 3 and time.monotonic() < matched
        ):  # bridge, 2 recorders
            time.sleep(0.02)
        end, k = time.monotonic() + seconds, 0
        while time.monotonic() < end:
            pub.publish(Float64MultiArray(data=bad[k % len(bad)]))
            k += 1
            time.sleep(0.04)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


def _stop(proc: Process, timeout: float) -> int | None:
    """Wait for a signalled process; one still running after ``timeout`` gets SIGABRT (its
    Python stack goes to its log) and then SIGKILL."""
    try:
        proc.proc.wait(timeout)
    except subprocess.TimeoutExpired:
        proc.proc.send_signal(signal.SIGABRT)
        time.sleep(1.0)
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
        launch(
            "bridge",
            "sim_bridge.bridge",
            {
                "cell": cell.name,
                "scenarios": scenarios,
                "time_limit": 120.0,
                "start_timeout": STARTUP_S,
                "command_timeout": COMMAND_TIMEOUT,
                "min_subscribers": 4,  # both planners and both recorders hear every state
            },
        )
        _wait(procs["bridge"], "episode started")
        time.sleep(1.5)
        t_kill_planner = time.time_ns()
        os.kill(procs["planner_ur5_1"].proc.pid, signal.SIGKILL)
        time.sleep(0.5)
        _bad_commands("ur5_1", 1.5)  # garbage must not move the held arm
        time.sleep(1.0)
        t_kill_recorder = time.time_ns()
        os.kill(procs["recorder_b"].proc.pid, signal.SIGKILL)
        time.sleep(1.0)
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
        yield Run(out, t_kill_planner, t_kill_recorder, t_stop, codes, outputs)
    finally:
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
    assert summary.end_ns >= run.t_stop - 100_000_000  # recorded up to the stop


def test_the_watchdog_stops_the_arm_of_a_killed_planner(run: Run) -> None:
    assert run.codes["planner_ur5_1"] == -signal.SIGKILL
    assert "watchdog: no command for ur5_1" in run.outputs["bridge"]
    line = next(x for x in run.outputs["bridge"].splitlines() if x.startswith("sim_bridge: counts"))
    counts = json.loads(line.split("counts ", 1)[1])
    # the kill trips it; a planner starved of CPU before the kill may have tripped it already
    assert counts["watchdog_trips"]["ur5_1"] >= 1
    assert counts["dropped_commands"]["ur5_1"] >= 20  # NaN, short and too fast: all dropped
    assert counts["dropped_commands"]["ur5_0"] == 0
    assert "dropped command of ur5_1" in run.outputs["bridge"]
    states = _states(run.out / "recorder_a", "ur5_1")
    before = [m for t, m in states if t < run.t_kill_planner]
    assert any(np.any(np.abs(m.velocity) > 0.05) for m in before)  # it was moving
    held = [m for t, m in states if t > run.t_kill_planner + (COMMAND_TIMEOUT + 0.15) * 1e9]
    assert len(held) > 100
    assert all(not np.any(m.velocity) for m in held)
    positions = np.array([m.position for m in held])
    assert np.ptp(positions, axis=0).max() == 0.0


def test_the_other_arm_keeps_planning_around_it(run: Run) -> None:
    log = run.out / "recorder_a"
    statuses = [
        (r.log_time_ns, r.message)
        for r in iter_log(log, ["/ur5_0/planner/status"])
        if isinstance(r.message, DiagnosticStatus)
    ]
    after = [m for t, m in statuses if run.t_kill_planner + 0.5e9 < t < run.t_stop]
    assert len(after) >= 10, len(after)  # still publishing between the kill and the stop
    values = [{kv.key: kv.value for kv in m.values} for m in after]
    planned = [v for v in values if v["peers_constrained"]]  # plan() ran (no deadline miss)
    assert len(planned) >= 0.8 * len(values), [m.message for m in after]
    assert all("ur5_1" in v["peers_constrained"] for v in planned)  # still planned around
    trouble = [(v["stale_peers"], v["untrusted_peers"]) for v in values]
    # the held arm's states keep coming; a process starved of CPU can deliver one late
    assert sum(bool(s or u) for s, u in trouble) <= 0.2 * len(trouble), trouble
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
    # Everything B received up to its last flush (≤ 0.5 s or 50 messages before the kill) is
    # there: compare with recorder A, which heard the same publishers, from the time both heard
    # them (the bridge publishes the held state before the episode; one recorder may match it
    # earlier than the other).
    cut = run.t_kill_recorder - 1_000_000_000
    for arm_id in ("ur5_0", "ur5_1"):
        a = [t for t, _ in _states(run.out / "recorder_a", arm_id) if t < cut]
        b = [t for t, _ in _states(fixed, arm_id) if t < cut]
        assert a and b, (arm_id, len(a), len(b))
        both = max(a[0], b[0])
        a, b = [t for t in a if t >= both], [t for t in b if t >= both]
        assert len(a) > 100 and len(b) >= len(a) - 2, (arm_id, len(a), len(b))
    recovered = read_log(fixed)
    assert max(r.log_time_ns for r in recovered) > run.t_kill_recorder - 1_000_000_000
