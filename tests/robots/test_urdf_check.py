"""``nehmo robot check``: URDFs of real arms pass, and each broken rule gets one clear error."""

from __future__ import annotations

import importlib.metadata
from pathlib import Path

import pytest

from nehmo_core.cli import main
from nehmo_core.errors import ModelFileError
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.urdf_check import check_urdf


def _shipped(suffix: str) -> Path:
    dist = importlib.metadata.distribution("example-robot-data")
    [found] = [f for f in dist.files or [] if str(f).endswith(suffix)]
    return Path(str(dist.locate_file(found)))


@pytest.mark.parametrize(
    ("suffix", "tip", "dof", "root"),
    [
        ("panda_description/urdf/panda.urdf", "panda_hand", 7, "panda_link0"),
        ("xarm_description/urdf/xarm7.urdf", None, 7, "world"),
        ("ur_description/urdf/ur10_robot.urdf", "ee_link", 6, "world"),
    ],
)
def test_arms_of_example_robot_data_pass(suffix: str, tip: str | None, dof: int, root: str) -> None:
    report = check_urdf(_shipped(suffix), tip)
    assert (report.dof, report.root) == (dof, root)
    assert all(j.velocity > 0 for j in report.joints)


def test_the_shipped_arms_pass_with_the_chain_the_planner_uses() -> None:
    for name in ("ur5", "kinova_gen3_6dof"):
        robot = load_robot(name)
        report = check_urdf(robot.urdf_path, robot.tip_link)
        assert [j.name for j in report.joints] == [j.name for j in robot.joints]
        assert [j.velocity for j in report.joints] == [j.velocity for j in robot.joints]


def test_a_gripper_branch_is_ignored_and_an_ambiguous_tip_is_asked_for() -> None:
    panda = _shipped("panda_description/urdf/panda.urdf")
    assert "panda_leftfinger" in check_urdf(panda, "panda_hand").ignored_links
    with pytest.raises(ModelFileError, match=r"several chains could be the arm.*name the tip"):
        check_urdf(panda)  # the fingers' prismatic joints make longer chains


ARM = """<robot name="toy">
  <link name="base"><collision><geometry><box size="0.1 0.1 0.1"/></geometry></collision></link>
  <link name="a">{a_collision}</link>
  <link name="b"><collision><geometry>{b_geometry}</geometry></collision></link>
  <joint name="j1" type="{j1_type}"><parent link="base"/><child link="a"/>{j1_limit}</joint>
  <joint name="j2" type="revolute"><parent link="a"/><child link="b"/>
    <limit lower="-1" upper="1" velocity="1"/></joint>
</robot>"""
GOOD = {
    "a_collision": '<collision><geometry><cylinder radius="0.05" length="0.3"/></geometry>'
    "</collision>",
    "b_geometry": '<sphere radius="0.05"/>',
    "j1_type": "revolute",
    "j1_limit": '<limit lower="-2" upper="2" velocity="1.5"/>',
}


def _write(tmp_path: Path, **changes: str) -> Path:
    path = tmp_path / "toy.urdf"
    path.write_text(ARM.format(**{**GOOD, **changes}))
    return path


def test_a_toy_arm_passes(tmp_path: Path) -> None:
    report = check_urdf(_write(tmp_path))
    assert (report.tip, report.dof) == ("b", 2)
    assert report.joints[0].velocity == 1.5


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"a_collision": ""}, r"links \['a'\] moved by joint 'j1' have no <collision>"),
        ({"j1_type": "prismatic"}, "joint 'j1' is prismatic"),
        ({"j1_limit": '<limit lower="-2" upper="2"/>'}, r"'j1' has no <limit velocity"),
        ({"j1_limit": '<limit lower="2" upper="-2" velocity="1"/>'}, "lower .* must be < upper"),
        ({"j1_limit": '<limit lower="-2" upper="2" velocity="0"/>'}, "velocity must be > 0"),
        (
            {"b_geometry": '<mesh filename="package://nowhere/b.stl"/>'},
            "collision mesh of link 'b' not found: 'package://nowhere/b.stl'",
        ),
    ],
)
def test_each_broken_rule_is_named(tmp_path: Path, changes: dict, message: str) -> None:
    with pytest.raises(ModelFileError, match=message):
        check_urdf(_write(tmp_path, **changes))


def test_a_continuous_joint_needs_only_its_velocity(tmp_path: Path) -> None:
    report = check_urdf(_write(tmp_path, j1_type="continuous", j1_limit='<limit velocity="2"/>'))
    assert report.joints[0].kind == "continuous" and report.joints[0].velocity == 2.0


def test_unknown_tip_and_missing_file_are_named(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="tip link 'hand' is not in the URDF"):
        check_urdf(_write(tmp_path), "hand")
    with pytest.raises(ModelFileError, match="URDF not found"):
        check_urdf(tmp_path / "none.urdf")


def test_the_command_prints_the_chain_or_one_error_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["robot", "check", str(_write(tmp_path))]) == 0
    assert "2 joints from base to b" in capsys.readouterr().out
    assert main(["robot", "check", str(_write(tmp_path, a_collision=""))]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("nehmo robot: error:")
