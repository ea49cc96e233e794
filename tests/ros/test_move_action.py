"""The ``move_arm`` action end to end: a client of its own (only rclpy and the built
``nehmo_interfaces``, no project code, the install space sourced) drives ``arm_planner`` started
from the colcon install space.

The test process simulates both arms of the dual-UR5 cell kinematically (``q += u·dt`` at
100 Hz from the commands ur5_0's planner publishes; ur5_1 stands still, turned away)
and records every command. The client sends, in order: a goal with a wrong joint count
(rejected), a near goal (feedback, then ``REACHED``), a far goal canceled after a few feedbacks
(``CANCELED``; the arm must then get zero commands), a far goal preempted by a near one
(``ABORTED`` "preempted", then ``REACHED``).
"""

from __future__ import annotations

import json
import math
import subprocess
import textwrap
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _ros_testutil import CellProbe, child_env, spin_until

from nehmo_core.robots import load_cell
from nehmo_ros.processes import Process, node_command

CELL = load_cell("dual_ur5")
NAMES = [j.name for j in CELL.arm("ur5_0").robot.joints]
# both arms turned away from each other (0.45 m apart), so every goal here is free to reach
START = {
    "ur5_0": np.array([math.pi, -1.2, 1.0, -1.4, -1.57, 0.0]),
    "ur5_1": np.array([math.pi, -1.2, 1.0, -1.4, -1.57, 0.0]),
}
STARTUP_S = 240.0

CLIENT = textwrap.dedent(
    """
    import json, sys, time
    import rclpy
    from rclpy.action import ActionClient
    from rclpy.node import Node
    from nehmo_interfaces.action import MoveArm

    names, near, far, near2 = json.loads(sys.argv[1])
    rclpy.init()
    node = Node("move_arm_client")
    client = ActionClient(node, MoveArm, "/ur5_0/move_arm")
    assert client.wait_for_server(timeout_sec=240), "no /ur5_0/move_arm server"

    def wait(future, seconds):
        rclpy.spin_until_future_complete(node, future, timeout_sec=seconds)
        assert future.done(), "no answer"
        return future.result()

    def goal(position, names=names, limit=30.0):
        return MoveArm.Goal(name=names, position=position, tolerance=0.0, time_limit=limit)

    def send(g, feedback):
        keep = lambda m: feedback.append(m.feedback)
        return wait(client.send_goal_async(g, feedback_callback=keep), 30)

    def summary(result, feedback, **extra):
        r = result.result
        return dict(status=result.status, code=r.code, message=r.message,
                    goal_error=r.goal_error, feedback=len(feedback),
                    modes=sorted({f.mode for f in feedback}),
                    peers=sorted({f.critical_peer for f in feedback}),
                    min_value=min((f.min_value for f in feedback), default=None),
                    errors=[f.goal_error for f in feedback][::10], **extra)

    out = {}
    out["bad"] = send(goal([0.0] * 3, names=[]), []).accepted
    fb = []
    h = send(goal(near), fb)
    out["near"] = summary(wait(h.get_result_async(), 120), fb)
    fb = []
    h = send(goal(far), fb)
    while len(fb) < 8:
        rclpy.spin_once(node, timeout_sec=0.1)
    t_cancel = time.monotonic()
    wait(h.cancel_goal_async(), 30)
    out["cancel"] = summary(wait(h.get_result_async(), 30), fb, t_cancel=t_cancel,
                            t_done=time.monotonic())
    time.sleep(1.5)
    fb_old, fb = [], []
    out["t_resume"] = time.monotonic()
    old = send(goal(far), fb_old)
    while len(fb_old) < 5:
        rclpy.spin_once(node, timeout_sec=0.1)
    new = send(goal(near2), fb)
    out["preempted"] = summary(wait(old.get_result_async(), 30), fb_old)
    out["second"] = summary(wait(new.get_result_async(), 120), fb)
    print("RESULT " + json.dumps(out), flush=True)
    node.destroy_node()
    rclpy.shutdown()
    """
)


class Sim(CellProbe):
    """Both arms kinematically at 100 Hz; ur5_0 follows its latest command (held 0.2 s)."""

    def __init__(self, q: dict[str, np.ndarray]) -> None:
        self.q = q
        self._last: tuple[float, np.ndarray] | None = None
        super().__init__(
            "move_arm_sim",
            {a: NAMES for a in CELL.arm_ids},
            self._step,
            "/ur5_0/velocity_controller/commands",
            period=0.01,
        )

    def _on_command(self, msg: Any) -> None:
        super()._on_command(msg)
        u = np.asarray(msg.data, dtype=float)
        if len(u) == 6 and np.all(np.isfinite(u)):
            self._last = (time.monotonic(), u)

    def _step(self) -> dict[str, np.ndarray]:
        if self._last is not None and time.monotonic() - self._last[0] < 0.2:
            self.q["ur5_0"] = self.q["ur5_0"] + 0.01 * self._last[1]
        return self.q


@dataclass(frozen=True)
class Run:
    result: dict[str, Any]
    commands: list[tuple[float, list[float]]]
    planner_log: str


def _goals() -> tuple[list[float], list[float], list[float]]:
    start = START["ur5_0"]
    near = start + np.array([0.3, 0.0, 0.0, 0.0, 0.2, 0.0])
    far = start + np.array([1.5, 0.0, 0.0, 0.0, 0.0, 0.0])
    near2 = start + np.array([-0.2, 0.0, 0.0, 0.0, 0.0, 0.2])
    return [list(map(float, g)) for g in (near, far, near2)]  # type: ignore[return-value]


@pytest.fixture(scope="module")
def run(colcon_install: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Run]:
    out = tmp_path_factory.mktemp("move_action")
    env = child_env(PYTHONUNBUFFERED="1", OMP_NUM_THREADS="1")
    planner = Process(
        "arm_planner",
        node_command(
            "nehmo_ros.arm_planner",
            {"arm_id": "ur5_0", "cell": "dual_ur5", "planner": "nehmo"},
            install_space=str(colcon_install),
        ),
        env,
        out / "planner.log",
        0,
    )
    sim = Sim({a: q.copy() for a, q in START.items()})
    script = out / "client.py"
    script.write_text(CLIENT)
    near, far, near2 = _goals()
    command = f'source "{colcon_install}/setup.bash" && exec python "{script}" "$1"'
    client = subprocess.Popen(
        ["bash", "-c", command, "client", json.dumps([NAMES, near, far, near2])],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        spin_until(sim.executor, STARTUP_S + 300, lambda: client.poll() is not None)
        text = client.communicate(timeout=10)[0]
        lines = [x for x in text.splitlines() if x.startswith("RESULT ")]
        assert client.returncode == 0 and lines, text[-3000:] + planner.output()[-3000:]
        yield Run(json.loads(lines[-1][len("RESULT ") :]), list(sim.commands), planner.output())
    finally:
        if client.poll() is None:
            client.kill()
        sim.close()
        planner.stop(5.0)


def test_a_goal_with_the_wrong_joint_count_is_rejected(run: Run) -> None:
    assert run.result["bad"] is False
    assert "rejected move_arm goal" in run.planner_log


def test_a_near_goal_is_reached_with_feedback(run: Run) -> None:
    near = run.result["near"]
    assert near["code"] == 1 and near["message"] == "reached", json.dumps(near)
    assert near["status"] == 4  # action_msgs/GoalStatus SUCCEEDED
    assert near["goal_error"] <= 0.1
    assert near["feedback"] >= 5
    assert "planning" in near["modes"] or "fail_safe" in near["modes"]
    # the peer is in reach: feedback names it and its value
    assert set(near["peers"]) - {""} == {"ur5_1"} and math.isfinite(near["min_value"])
    assert near["goal_error"] < near["errors"][0]  # the arm closed in on the goal


def test_a_canceled_goal_stops_the_arm(run: Run) -> None:
    cancel = run.result["cancel"]
    assert cancel["code"] == 4 and cancel["status"] == 5  # CANCELED
    assert cancel["goal_error"] > 0.1  # canceled before the far goal was reached
    t_done, t_resume = cancel["t_done"], run.result["t_resume"]
    moving_before = [u for t, u in run.commands if t < cancel["t_cancel"] and any(u)]
    assert moving_before  # it was moving toward the far goal
    held = [u for t, u in run.commands if t_done + 0.1 < t < t_resume]
    assert len(held) >= 20 and all(not any(u) for u in held), (len(held), held[:5])


def test_a_new_goal_preempts_the_running_one(run: Run) -> None:
    old, new = run.result["preempted"], run.result["second"]
    assert old["code"] == 3 and old["message"] == "preempted by a new goal"
    assert old["status"] == 6  # ABORTED
    assert new["code"] == 1 and new["goal_error"] <= 0.1, json.dumps(new)
