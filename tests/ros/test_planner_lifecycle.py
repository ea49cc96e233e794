"""``arm_planner`` as a managed node: started with ``autostart:=false`` it waits unconfigured;
the lifecycle services drive it through configure, activate, deactivate, cleanup and shutdown,
and it commands the arm only while active (deactivate: one zero, then nothing). A cell that does
not exist fails the configure transition and leaves the node unconfigured."""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from _ros_testutil import CellProbe, child_env

from nehmo_core.robots import load_cell
from nehmo_ros.processes import Process, node_command

CELL = load_cell("dual_ur5")
NAMES = [j.name for j in CELL.arm("ur5_0").robot.joints]
STARTUP_S = 240.0
WAIT_S = 60.0


STATES = {"ur5_0": [0.0, -1.2, 1.0, 0.0, 0.0, 0.0], "ur5_1": [2.0, -1.2, 1.0, 0.0, 0.0, 0.0]}


class Probe(CellProbe):
    """Joint states of both arms at 50 Hz, ur5_0's goal; records ur5_0's commands; calls the
    lifecycle services."""

    def __init__(self) -> None:
        super().__init__(
            "lifecycle_probe",
            {a: NAMES for a in CELL.arm_ids},
            lambda: STATES,
            "/ur5_0/velocity_controller/commands",
            goal=("ur5_0", [1.0, -1.0, 1.0, 0.5, 0.5, 0.5]),
        )

    def state(self, node: str) -> str:
        from lifecycle_msgs.srv import GetState

        answer = self.call(GetState, f"/{node}/get_state", GetState.Request(), STARTUP_S)
        return str(answer.current_state.label)

    def transition(self, node: str, transition: int) -> bool:
        from lifecycle_msgs.msg import Transition
        from lifecycle_msgs.srv import ChangeState

        request = ChangeState.Request(transition=Transition(id=transition))
        return bool(self.call(ChangeState, f"/{node}/change_state", request, STARTUP_S).success)

    def commands_since(self, t: float) -> list[list[float]]:
        return [u for s, u in self.commands if s > t]


@pytest.fixture(scope="module")
def probe() -> Iterator[Probe]:
    p = Probe()
    yield p
    p.close()


def _planner(out: Path, name: str, cell: str) -> Process:
    return Process(
        name,
        node_command(
            "nehmo_ros.arm_planner",
            {"arm_id": "ur5_0", "cell": cell, "planner": "naive", "autostart": False},
            ["-r", f"__node:={name}"],
        ),
        child_env(PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1"),
        out / f"{name}.log",
        0,
    )


def _moving(commands: list[list[float]]) -> int:
    return sum(any(abs(v) > 1e-9 for v in u) for u in commands)


def test_the_planner_commands_only_while_active(probe: Probe, tmp_path: Path) -> None:
    from lifecycle_msgs.msg import Transition as T

    node = "lc_planner"
    planner = _planner(tmp_path, node, "dual_ur5")
    try:
        assert probe.state(node) == "unconfigured"
        t0 = time.monotonic()
        probe.spin(1.5)
        assert probe.commands_since(t0) == []  # unconfigured: nothing

        assert probe.transition(node, T.TRANSITION_CONFIGURE)
        assert probe.state(node) == "inactive"
        t1 = time.monotonic()
        probe.spin(1.5)
        assert probe.commands_since(t1) == []  # configured, inactive: nothing

        for _ in range(2):  # activate, deactivate, and once more
            t2 = time.monotonic()
            assert probe.transition(node, T.TRANSITION_ACTIVATE)
            assert probe.state(node) == "active"
            assert probe.spin(WAIT_S, lambda t=t2: _moving(probe.commands_since(t)) >= 10)
            assert probe.transition(node, T.TRANSITION_DEACTIVATE)
            t3 = time.monotonic()
            probe.spin(1.5)
            after = probe.commands_since(t3 - 0.5)
            # the last command after deactivating is a zero, and nothing comes 0.5 s later
            assert after and after[-1] == [0.0] * 6, after[-3:]
            assert probe.commands_since(t3 + 0.5) == []
            assert probe.state(node) == "inactive"

        assert probe.transition(node, T.TRANSITION_CLEANUP)
        assert probe.state(node) == "unconfigured"
        assert probe.transition(node, T.TRANSITION_CONFIGURE)  # configures again from scratch
        assert probe.transition(node, T.TRANSITION_INACTIVE_SHUTDOWN)
        assert probe.state(node) == "finalized"
        log = planner.output()
        assert log.count("arm ur5_0 of cell dual_ur5") == 2  # configured twice
        assert "cleaned up: models and topics released" in log
    finally:
        planner.stop(5.0)


def test_a_configure_with_a_bad_cell_fails_and_stays_unconfigured(
    probe: Probe, tmp_path: Path
) -> None:
    from lifecycle_msgs.msg import Transition as T

    node = "lc_bad_cell"
    planner = _planner(tmp_path, node, "no_such_cell")
    try:
        assert probe.state(node) == "unconfigured"  # the node itself starts
        assert not probe.transition(node, T.TRANSITION_CONFIGURE)
        assert probe.state(node) == "unconfigured"
        probe.spin(0.5)
        assert "configure failed: unknown cell 'no_such_cell'" in planner.output()
    finally:
        planner.stop(5.0)
