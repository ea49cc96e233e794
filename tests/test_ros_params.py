"""Parameters from ``--ros-args -p`` and ``--params-file`` on the embedded runtime."""

from __future__ import annotations

import json
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
from _ros_testutil import DOMAIN_ID, finish, start

from nehmo_ros.embedded import (
    InvalidParameterValueException,
    Node,
    Parameter,
    ParameterUninitializedException,
    RosArgsError,
    init,
    remove_ros_args,
    try_shutdown,
)
from nehmo_ros.embedded.arguments import node_matches, parse_value


@pytest.fixture
def ros_args() -> Iterator[Callable[..., None]]:
    """init(args) for one test, always shut down after it."""

    def _init(*argv: str) -> None:
        init(args=["prog", *argv], domain_id=DOMAIN_ID)

    yield _init
    try_shutdown()


def test_values_are_typed_like_rcl() -> None:
    assert parse_value("25", "-p") == 25
    assert parse_value("25.0", "-p") == 25.0
    assert parse_value("1e-3", "-p") == 0.001  # PyYAML alone would read a string here
    assert parse_value("true", "-p") is True
    assert parse_value("'true'", "-p") == "true"
    assert parse_value("ur5_0", "-p") == "ur5_0"
    assert parse_value("[1.0, 2]", "-p") == [1.0, 2.0]
    assert parse_value("[a, b]", "-p") == ["a", "b"]
    with pytest.raises(RosArgsError, match="one type"):
        parse_value("[1, a]", "-p")


def test_cli_overrides_and_remap(ros_args: Callable[..., None]) -> None:
    ros_args("--ros-args", "-p", "arm_id:=ur5_0", "-p", "rate:=30.0", "-r", "__node:=planner_0")
    node = Node("arm_planner")
    assert node.get_name() == "planner_0"
    assert node.declare_parameter("arm_id", Parameter.Type.STRING).value == "ur5_0"
    assert node.declare_parameter("rate", 25.0).value == 30.0
    assert node.declare_parameter("epsilon", 0.05).value == 0.05
    assert node.get_parameter("use_sim_time").value is False


def test_params_file_wildcard_node_and_nesting(
    ros_args: Callable[..., None], tmp_path: Path
) -> None:
    params = tmp_path / "p.yaml"
    params.write_text(
        "/**:\n  ros__parameters:\n    rate: 20.0\n    planner: naive\n"
        "planner_1:\n  ros__parameters:\n    rate: 10.0\n    model:\n      path: m.safetensors\n"
        "other:\n  ros__parameters:\n    rate: 1.0\n"
    )
    ros_args(
        "--ros-args",
        "--params-file",
        str(params),
        "-r",
        "__node:=planner_1",
        "-p",
        "planner:=nehmo",
    )
    node = Node("arm_planner")
    assert node.declare_parameter("rate", 25.0).value == 10.0  # exact node name beats /**
    assert node.declare_parameter("planner", "x").value == "nehmo"  # later -p wins
    assert node.declare_parameter("model.path", "").value == "m.safetensors"


def test_integer_for_double_is_refused_with_one_clear_message(
    ros_args: Callable[..., None],
) -> None:
    ros_args("--ros-args", "-p", "rate:=25")
    node = Node("arm_planner")
    with pytest.raises(InvalidParameterValueException) as info:
        node.declare_parameter("rate", 25.0)
    text = str(info.value)
    assert "`rate`" in text and "DOUBLE" in text and "25.0" in text and "-p rate:=25" in text


def test_required_parameter_without_value(ros_args: Callable[..., None]) -> None:
    ros_args()
    node = Node("arm_planner")
    node.declare_parameter("arm_id", Parameter.Type.STRING)
    with pytest.raises(ParameterUninitializedException, match="arm_id"):
        node.get_parameter("arm_id")


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--ros-args", "-p", "rate"], "NAME:=VALUE"),
        (["--ros-args", "--params-file", "/nonexistent/p.yaml"], "cannot read"),
        (["--ros-args", "--bogus"], "unknown ROS argument"),
        (["--ros-args", "--log-level", "loud"], "--log-level"),
    ],
)
def test_malformed_ros_args(argv: list[str], message: str) -> None:
    with pytest.raises(RosArgsError, match=message):
        init(args=["prog", *argv], domain_id=DOMAIN_ID)
    try_shutdown()


def test_bad_params_file_yaml(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("/**:\n  ros__parameters: [1, 2\n")
    with pytest.raises(RosArgsError, match="invalid YAML"):
        init(args=["prog", "--ros-args", "--params-file", str(bad)], domain_id=DOMAIN_ID)
    try_shutdown()


def test_node_name_patterns() -> None:
    assert node_matches("/**", "/ns/a")
    assert node_matches("/*", "/a") and not node_matches("/*", "/ns/a")
    assert node_matches("/ns/*", "/ns/a") and not node_matches("/ns/*", "/a")
    assert node_matches("a", "/a") or node_matches("/a", "/a")
    assert remove_ros_args(["p", "x", "--ros-args", "-p", "a:=1", "--", "y"]) == ["p", "x", "y"]


def test_node_process_prints_one_error_line_for_a_bad_value() -> None:
    proc = start("params", "--ros-args", "-p", "arm_id:=ur5_0", "-p", "rate:=fast")
    code, out, err = finish(proc, timeout=30)
    assert code == 2, (out, err)
    lines = [line for line in err.splitlines() if line.strip()]
    assert len(lines) == 1, err
    assert "`rate`" in lines[0] and "'fast'" in lines[0] and "DOUBLE" in lines[0]


def test_node_process_reads_params(tmp_path: Path) -> None:
    params = tmp_path / "p.yaml"
    params.write_text("/**:\n  ros__parameters:\n    arm_id: ur5_1\n    peers: [ur5_0, kinova]\n")
    proc = start("params", "--ros-args", "--params-file", str(params), "-p", "t_plan:=0.2")
    code, out, err = finish(proc, timeout=30)
    assert code == 0, err
    values = json.loads(out)
    assert values["arm_id"] == "ur5_1" and values["t_plan"] == 0.2
    assert values["peers"] == ["ur5_0", "kinova"] and values["rate"] == 25.0
