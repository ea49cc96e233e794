"""``ros_ws/`` builds with colcon from PyPI, and its install space runs the nodes as a ROS user
runs them: source ``install/setup.bash``, then ``install/<pkg>/lib/<pkg>/<executable>``."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from _ros_testutil import child_env


def _in_install_space(install: Path, command: str) -> subprocess.CompletedProcess[str]:
    script = f'source "{install}/setup.bash" && {command}'
    return subprocess.run(
        ["bash", "-c", script], env=child_env(), capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize(
    ("package", "executable"),
    [
        ("nehmo_ros", "arm_planner"),
        ("nehmo_ros", "arm_planners"),
        ("nehmo_ros", "recorder"),
        ("sim_bridge", "sim_bridge"),
    ],
)
def test_the_install_space_has_each_node_executable(
    colcon_install: Path, package: str, executable: str
) -> None:
    path = colcon_install / package / "lib" / package / executable
    assert path.is_file()
    proc = _in_install_space(colcon_install, f'"{path}" --help')
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"`{executable}` node"), proc.stdout[:200]


def test_sourced_setup_imports_the_installed_packages(colcon_install: Path) -> None:
    proc = _in_install_space(
        colcon_install, 'python -c "import nehmo_ros, sim_bridge; print(nehmo_ros.__file__)"'
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().startswith(str(colcon_install / "nehmo_ros")), proc.stdout


MOVE_ARM_ROUND_TRIP = textwrap.dedent(
    """
    import json
    import rclpy
    from rclpy.action import ActionClient, ActionServer
    from rclpy.executors import SingleThreadedExecutor
    from nehmo_interfaces.action import MoveArm

    def execute(goal_handle):
        goal = goal_handle.request
        feedback = MoveArm.Feedback(goal_error=0.25, min_value=float("inf"), mode="planning")
        goal_handle.publish_feedback(feedback)
        goal_handle.succeed()
        error = max(abs(x) for x in goal.position)
        return MoveArm.Result(code=MoveArm.Result.REACHED, message=",".join(goal.name),
                              goal_error=error, elapsed=goal.time_limit)

    rclpy.init()
    node = rclpy.create_node("move_arm_round_trip")
    server = ActionServer(node, MoveArm, "move_arm", execute)
    client = ActionClient(node, MoveArm, "move_arm")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    assert client.wait_for_server(timeout_sec=30.0), "no move_arm server"
    feedbacks = []
    goal = MoveArm.Goal(name=["j1", "j2"], position=[0.1, -0.3], tolerance=0.05, time_limit=2.0)
    sent = client.send_goal_async(goal, feedback_callback=lambda m: feedbacks.append(m.feedback))
    executor.spin_until_future_complete(sent, timeout_sec=30.0)
    assert sent.done() and sent.result().accepted, "goal not accepted"
    result = sent.result().get_result_async()
    executor.spin_until_future_complete(result, timeout_sec=30.0)
    assert result.done(), "no result"
    for _ in range(100):  # the feedback may arrive just after the result
        if feedbacks:
            break
        executor.spin_once(timeout_sec=0.1)
    r = result.result().result
    print(json.dumps({
        "feedback": [[f.mode, f.goal_error, f.min_value] for f in feedbacks],
        "reached": r.code == MoveArm.Result.REACHED,
        "result": [r.code, r.message, r.goal_error, r.elapsed],
    }))
    node.destroy_node()
    rclpy.shutdown()
    """
)


def test_the_interface_package_builds_and_its_action_runs(
    colcon_install: Path, tmp_path: Path
) -> None:
    """``nehmo_interfaces`` (ament_cmake, rosidl) builds with the rest of the workspace, and a
    process that imports only rclpy and it serves and calls ``MoveArm``: goal, feedback,
    result."""
    share = colcon_install / "nehmo_interfaces" / "share" / "nehmo_interfaces"
    assert (share / "action" / "MoveArm.action").is_file()
    script = tmp_path / "move_arm_round_trip.py"
    script.write_text(MOVE_ARM_ROUND_TRIP)
    proc = _in_install_space(colcon_install, f'python "{script}"')
    assert proc.returncode == 0, proc.stderr[-3000:]
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert out["feedback"] == [["planning", 0.25, math.inf]], out
    assert out["reached"] is True, out
    assert out["result"] == [1, "j1,j2", 0.3, 2.0], out


def test_an_installed_node_rejects_a_bad_parameter_with_one_line(colcon_install: Path) -> None:
    exe = colcon_install / "nehmo_ros" / "lib" / "nehmo_ros" / "arm_planner"
    proc = _in_install_space(
        colcon_install, f'"{exe}" --ros-args -p arm_id:=ur5_0 -p cell:=dual_ur5 -p rate:=0.0'
    )
    assert proc.returncode == 2
    lines = [x for x in proc.stderr.splitlines() if "pybullet build time" not in x]
    assert lines == ["arm_planner: error: `rate` must lie in [0.001, 1000]; got 0.0"], lines


# -- `ros2 run` on a pip install ----------------------------------------------------------------
VENV_BIN = Path(sys.executable).parent


def _with_ros2(install: Path, command: str, extra_path: str = "") -> subprocess.CompletedProcess:
    """``command`` in a shell with the install space sourced and the project environment's
    ``ros2`` (and ``extra_path`` after it) on PATH, as under ``./run``."""
    env = child_env()
    env["PATH"] = os.pathsep.join(p for p in (str(VENV_BIN), extra_path, env["PATH"]) if p)
    script = f'source "{install}/setup.bash" && {command}'
    return subprocess.run(
        ["bash", "-c", script], env=env, capture_output=True, text=True, timeout=120
    )


def test_ros2_pkg_executables_lists_the_install_spaces_nodes(colcon_install: Path) -> None:
    proc = _with_ros2(colcon_install, "ros2 pkg executables nehmo_ros")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.splitlines() == [
        "nehmo_ros arm_planner",
        "nehmo_ros arm_planners",
        "nehmo_ros command_watchdog",
        "nehmo_ros lifecycle_manager",
        "nehmo_ros orchestrate",
        "nehmo_ros recorder",
    ]


def test_the_design_cards_ros2_run_command_starts_the_planner(colcon_install: Path) -> None:
    """Exactly ``ros2 run nehmo_ros arm_planner --ros-args -p arm_id:=ur5_0``: the installed
    node runs (and stops at once, naming the parameter it still needs); with a cell it starts
    and waits for its states until SIGINT."""
    proc = _with_ros2(colcon_install, "ros2 run nehmo_ros arm_planner --ros-args -p arm_id:=ur5_0")
    assert proc.returncode == 2
    lines = [x for x in proc.stderr.splitlines() if "pybullet build time" not in x]
    assert len(lines) == 1 and lines[0].startswith("arm_planner: error: `cell` is required"), lines
    env = child_env()
    env["PATH"] = os.pathsep.join((str(VENV_BIN), env["PATH"]))
    script = (
        f'source "{colcon_install}/setup.bash" && exec ros2 run nehmo_ros arm_planner '
        "--ros-args -p arm_id:=ur5_0 -p cell:=dual_ur5 -p model:=synthetic"
    )
    node = subprocess.Popen(
        ["bash", "-c", script], env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        lines = []
        assert node.stdout is not None
        for line in node.stdout:  # the node's own log, through exec: no wrapper in between
            lines.append(line)
            if "waiting" in line:
                break
        assert any("waiting" in x for x in lines), "".join(lines)[-2000:]
        node.send_signal(signal.SIGINT)
        assert node.wait(timeout=60) == 0
    finally:
        if node.poll() is None:
            node.kill()


def test_ros2_says_what_it_is_for_a_verb_it_lacks(colcon_install: Path) -> None:
    proc = _with_ros2(colcon_install, "ros2 topic list")
    assert proc.returncode == 2
    assert proc.stderr.strip() == (
        "ros2: 'topic' needs the ROS 2 command line, which is not on PyPI: this is NeHMO's "
        "stand-in with 'run' and 'pkg executables' only (a full ROS 2: the docker/ image)"
    )
    missing = _with_ros2(colcon_install, "ros2 run nehmo_ros planner")
    assert missing.returncode == 1
    assert "no executable 'planner' in package 'nehmo_ros'" in missing.stderr


def test_a_real_ros2_on_path_is_never_shadowed(colcon_install: Path, tmp_path: Path) -> None:
    real = tmp_path / "ros2"
    real.write_text('#!/bin/sh\necho "real ros2: $*"\n')
    real.chmod(0o755)
    proc = _with_ros2(colcon_install, "ros2 topic list", extra_path=str(tmp_path))
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "real ros2: topic list"
