"""The command watchdog between a planner and a velocity controller, with a planner SIGKILLed;
the planner's pause and resume services on the way.

A real ``arm_planner`` (naive, dual-UR5 cell) publishes to ``/ur5_0/planner/commands`` through
a remap, as a real setup starts it; ``command_watchdog`` forwards to the controller's topic
``/ur5_0/velocity_controller/commands``, which a plain rclpy probe in the test process reads
(the probe also publishes both arms' joint states and ur5_0's goal). Once the arm is commanded
to move, the probe pauses the planner (zeros follow) and resumes it (it moves again); then the
planner is SIGKILLed: zeros must follow on the controller's topic, tripped only
after the timeout, and nothing else after them. Then the probe sends a valid command (forwarded:
the watchdog lets go) and a NaN one (replaced by zeros at once), and stops the watchdog with
SIGTERM (a last zero, its counters).
"""

from __future__ import annotations

import math
import re
import signal
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from _ros_testutil import CellProbe, child_env

from nehmo_core.robots import load_cell
from nehmo_ros.command_watchdog import planner_topic
from nehmo_ros.processes import Process, node_command

CELL = load_cell("dual_ur5")
NAMES = [j.name for j in CELL.arm("ur5_0").robot.joints]
TIMEOUT = 0.2  # [s] the watchdog's
RATE = 100.0  # [Hz] the watchdog's check
STARTUP_S = 240.0
WAIT_S = 60.0
TRIP = re.compile(r"watchdog: no command for ur5_0 in ([0-9.]+) s")


def _states() -> dict[str, list[float]]:
    return {a: [0.0, -1.2, 1.0, 0.0, 0.0, 0.0] if a == "ur5_0" else [0.0] * 6 for a in CELL.arm_ids}


class Probe(CellProbe):
    """States of both arms at 50 Hz, ur5_0's goal, and what reaches the controller's topic."""

    def __init__(self) -> None:
        from std_msgs.msg import Float64MultiArray

        super().__init__(
            "watchdog_probe",
            {a: NAMES for a in CELL.arm_ids},
            _states,
            "/ur5_0/velocity_controller/commands",
            goal=("ur5_0", [1.0, -1.0, 1.0, 0.5, 0.5, 0.5]),
        )
        self.Float64MultiArray = Float64MultiArray
        self.planner_side = self.node.create_publisher(
            Float64MultiArray, planner_topic("ur5_0"), 10
        )

    @property
    def received(self) -> list[tuple[float, list[float]]]:
        return self.commands

    def trigger(self, service: str) -> tuple[bool, str]:
        """Call a std_srvs/Trigger service; (success, message)."""
        from std_srvs.srv import Trigger

        response = self.call(Trigger, service, Trigger.Request(), WAIT_S)
        return bool(response.success), str(response.message)

    def command(self, data: list[float]) -> None:
        self.planner_side.publish(self.Float64MultiArray(data=data))


def _moving(data: list[float]) -> bool:
    return any(abs(v) > 1e-9 for v in data)


@dataclass(frozen=True)
class Run:
    t_kill: float
    t_probe: float  # the probe's own commands start
    paused: list[list[float]]  # what reached the controller after the pause call
    answers: list[tuple[bool, str]]  # pause, resume, resume again
    received: list[tuple[float, list[float]]]
    after_valid: list[list[float]]  # what reached the controller after the probe's own command
    after_nan: list[list[float]]  # ... after the probe's NaN command
    watchdog_code: int | None
    watchdog_log: str
    planner_log: str


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    out = tmp_path_factory.mktemp("watchdog")
    env = child_env(PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    watchdog = Process(
        "command_watchdog",
        node_command(
            "nehmo_ros.command_watchdog",
            {"arm_id": "ur5_0", "timeout": TIMEOUT, "rate": RATE},
        ),
        env,
        out / "watchdog.log",
        0,
    )
    remap = ["-r", f"/ur5_0/velocity_controller/commands:={planner_topic('ur5_0')}"]
    planner = Process(
        "arm_planner",
        node_command(
            "nehmo_ros.arm_planner",
            {"arm_id": "ur5_0", "cell": "dual_ur5", "planner": "naive"},
            remap,
        ),
        env,
        out / "planner.log",
        0,
    )
    probe = Probe()
    try:
        moving = lambda: sum(_moving(d) for _, d in probe.received) >= 10  # noqa: E731
        assert probe.spin(STARTUP_S, moving), planner.output()[-2000:] + watchdog.output()[-2000:]
        answers = [probe.trigger("/ur5_0/planner/pause")]
        mark = len(probe.received)
        held = lambda: sum(not _moving(d) for _, d in probe.received[mark:]) >= 10  # noqa: E731
        assert probe.spin(WAIT_S, held)
        paused = [d for _, d in probe.received[mark:]]
        answers += [probe.trigger("/ur5_0/planner/resume"), probe.trigger("/ur5_0/planner/resume")]
        mark = len(probe.received)
        assert probe.spin(WAIT_S, lambda: any(_moving(d) for _, d in probe.received[mark:]))
        planner.proc.send_signal(signal.SIGKILL)
        t_kill = time.monotonic()
        planner.proc.wait(timeout=WAIT_S)
        zeros_after = lambda: any(t > t_kill and not _moving(d) for t, d in probe.received)  # noqa: E731
        assert probe.spin(WAIT_S, zeros_after), watchdog.output()[-2000:]
        probe.spin(1.0, lambda: False)  # zeros keep coming
        mark, t_probe = len(probe.received), time.monotonic()
        probe.command([0.1] * 6)
        assert probe.spin(WAIT_S, lambda: any(_moving(d) for _, d in probe.received[mark:]))
        after_valid = [d for _, d in probe.received[mark:]]
        mark = len(probe.received)
        probe.command([math.nan] * 6)
        probe.spin(0.5, lambda: False)
        after_nan = [d for _, d in probe.received[mark:]]
        watchdog.proc.send_signal(signal.SIGTERM)
        code = watchdog.proc.wait(timeout=WAIT_S)
        yield Run(
            t_kill,
            t_probe,
            paused,
            answers,
            list(probe.received),
            after_valid,
            after_nan,
            code,
            watchdog.output(),
            planner.output(),
        )
    finally:
        probe.close()
        for p in (planner, watchdog):
            p.stop(5.0)


def test_a_killed_planners_arm_gets_zeros_after_the_timeout(run: Run) -> None:
    before = [d for t, d in run.received if t < run.t_kill]
    assert sum(_moving(d) for d in before) >= 10  # the planner's commands were forwarded
    after = [d for t, d in run.received if run.t_kill < t < run.t_probe]
    first_zero = next(k for k, d in enumerate(after) if not _moving(d))
    # once the zeros start, nothing moves the arm again until a new command comes
    assert all(not _moving(d) for d in after[first_zero:]), after[first_zero:]
    assert all(len(d) == 6 for d in after)
    ages = [float(a) for a in TRIP.findall(run.watchdog_log)]
    assert ages and ages[0] >= TIMEOUT  # the kill's trip, not before its time


def test_pause_holds_the_arm_and_resume_moves_it_again(run: Run) -> None:
    pause, resume, again = run.answers
    assert pause == (True, "paused: commanding zero velocity")
    assert resume == (True, "resumed: planning from the current state")
    assert again == (False, "not paused")
    # after the pause call at most the commands already on their way move the arm, then zeros
    first_zero = next(k for k, d in enumerate(run.paused) if not _moving(d))
    assert first_zero <= 2 and all(not _moving(d) for d in run.paused[first_zero:])
    assert "paused (zero velocity until /planner/resume)" in run.planner_log


def test_a_new_command_is_forwarded_and_a_bad_one_replaced_by_zeros(run: Run) -> None:
    assert [0.1] * 6 in run.after_valid
    assert "commands for ur5_0 resumed" in run.watchdog_log
    assert run.after_nan and all(d == [0.0] * 6 for d in run.after_nan)
    assert "rejected a command of 6 values for ur5_0" in run.watchdog_log


def test_the_watchdog_stops_cleanly_with_its_counters(run: Run) -> None:
    assert run.watchdog_code == 0, run.watchdog_log[-2000:]
    counts = re.search(r"stopped: \{'forwarded': \d+, 'rejected': (\d+), 'zeros': \d+, "
                       r"'trips': (\d+), 'expired': (\d+)\}", run.watchdog_log)  # fmt: skip
    assert counts is not None, run.watchdog_log[-2000:]
    # at least two trips: the killed planner, the probe's single command going stale (a
    # planner slowed past the timeout by a loaded machine trips it too, as it should)
    assert int(counts.group(1)) == 1 and int(counts.group(2)) >= 2
    assert int(counts.group(3)) >= int(counts.group(2))  # every trip expired the command first


def test_bad_parameters_are_one_line(tmp_path: Path) -> None:
    import subprocess

    done = subprocess.run(
        node_command("nehmo_ros.command_watchdog", {"arm_id": "ur5_0", "timeout": -1.0}),
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert done.returncode == 2
    assert done.stderr.strip().splitlines()[-1] == (
        "command_watchdog: error: `timeout` must lie in [0.001, 60]; got -1.0"
    )
