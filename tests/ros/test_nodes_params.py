"""Invalid node parameters stop the node with one line naming the parameter, rule and value."""

from __future__ import annotations

import subprocess
import sys

import pytest
from _ros_testutil import child_env

CASES = [
    ("nehmo_ros.arm_planner", ["cell:=dual_ur5"], "`arm_id` is required"),
    ("nehmo_ros.arm_planner", ["cell:=dual_ur5", "arm_id:=ur5_9"], "`arm_id` must name an arm"),
    (
        "nehmo_ros.arm_planner",
        ["cell:=dual_ur5", "arm_id:=ur5_0", "planner:=naive", "opt.epsilon:=-0.1"],
        "`opt.epsilon` must be > 0; got -0.1",
    ),
    (
        "nehmo_ros.arm_planner",
        ["cell:=dual_ur5", "arm_id:=ur5_0", "hold_bound:=1.0"],
        "`hold_bound` is now `hold.bound`",
    ),
    (
        "nehmo_ros.arm_planner",
        ["cell:=dual_ur5", "arm_id:=ur5_0", "planner:=magic"],
        "unknown planner 'magic'",
    ),
    (
        "nehmo_ros.arm_planner",
        ["cell:=dual_ur5", "arm_id:=ur5_0", "rate:=25"],
        "`rate` must be of type float; got 25",
    ),
    (
        "nehmo_ros.arm_planner",
        ["cell:=dual_ur5", "arm_id:=ur5_0", "rate:=2000.0"],
        "`rate` must lie in [0.001, 1000]; got 2000.0",
    ),
    ("sim_bridge.bridge", ["cell:=dual_ur5", "physics_rate:=-5.0"], "`physics_rate` must be"),
    ("sim_bridge.bridge", ["cell:=no_such_cell"], "unknown cell 'no_such_cell'"),
    (
        "sim_bridge.bridge",
        ["cell:=dual_ur5", "real_time_factor:=2.0"],
        "`real_time_factor` must be 1 without sim_time",
    ),
    ("nehmo_ros.recorder", ["cell:=dual_ur5", "output:=run.mcap"], "`output` must name a bag"),
    (
        "nehmo_ros.recorder",
        ["cell:=dual_ur5", "output:=run_bag", "flush_interval:=-0.5"],
        "`flush_interval` must be > 0; got -0.5",
    ),
]


@pytest.mark.parametrize(
    ("module", "params", "expected"),
    CASES,
    ids=[
        "no_arm_id",
        "unknown_arm",
        "epsilon",
        "renamed",
        "planner",
        "rate_type",
        "rate_range",
        "bridge",
        "cell",
        "rtf",
        "out",
        "flush_interval",
    ],
)
def test_invalid_parameter_stops_the_node_with_one_line(
    module: str, params: list[str], expected: str
) -> None:
    argv = [sys.executable, "-m", module, "--ros-args"]
    for p in params:
        argv += ["-p", p]
    proc = subprocess.run(argv, env=child_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if "pybullet build time" not in line]
    assert len(lines) == 1, proc.stderr
    assert expected in lines[0], lines[0]
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    ("args", "env", "expected"),
    [
        (["-p", "cell"], {}, "-p expects NAME:=VALUE; got 'cell'"),
        (["-p"], {}, "-p needs an argument"),
        (["-p", "cell:=dual_ur5"], {"ROS_DOMAIN_ID": "999"}, "ROS_DOMAIN_ID must be an integer"),
        (["-r", "a"], {}, "Couldn't parse remap rule"),
    ],
    ids=["no_value", "no_rule", "domain_id", "remap"],
)
@pytest.mark.parametrize(
    ("module", "program"), [("nehmo_ros.recorder", "recorder"), ("sim_bridge.bridge", "sim_bridge")]
)
def test_bad_ros_arguments_stop_the_node_with_one_line(
    module: str, program: str, args: list[str], env: dict[str, str], expected: str
) -> None:
    """Errors of ``rclpy.init`` (the ``--ros-args`` section, the DDS domain) too."""
    argv = [sys.executable, "-m", module, "--ros-args", *args]
    proc = subprocess.run(argv, env=child_env(**env), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    lines = [line for line in proc.stderr.splitlines() if "pybullet build time" not in line]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"{program}: error: ") and expected in lines[0], lines[0]
    assert "Traceback" not in proc.stderr


@pytest.mark.parametrize(
    ("module", "program", "parameter"),
    [
        ("nehmo_ros.arm_planner", "arm_planner", "arm_id"),
        ("nehmo_ros.recorder", "recorder", "output"),
        ("sim_bridge.bridge", "sim_bridge", "physics_rate"),
    ],
)
def test_help_prints_the_nodes_usage(module: str, program: str, parameter: str) -> None:
    """``--help`` (before ``--ros-args``) prints the node's usage and parameters, not an error
    about a missing parameter; after ``--ros-args`` it is an unknown ROS argument."""
    proc = subprocess.run(
        [sys.executable, "-m", module, "--help"],
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"`{program}` node:"), proc.stdout[:200]
    assert f"``{parameter}``" in proc.stdout
    late = [sys.executable, "-m", module, "--ros-args", "--help"]
    proc = subprocess.run(late, env=child_env(), capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2 and "unknown ROS argument '--help'" in proc.stderr
