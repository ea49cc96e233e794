"""Robots are description files: the shipped ones load as before, and ``nehmo robot add`` makes
another arm loadable by name through ``NEHMO_ROBOTS``."""

from __future__ import annotations

import importlib.metadata
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from nehmo_core.cli import main
from nehmo_core.errors import InvalidValueError, ModelFileError, UnknownNameError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots import descriptions
from nehmo_core.robots.loader import cell_from_dict, load_robot
from nehmo_core.robots.registry import ROBOT_NAMES


def _xarm7() -> Path:
    dist = importlib.metadata.distribution("example-robot-data")
    [found] = [f for f in dist.files or [] if str(f).endswith("xarm_description/urdf/xarm7.urdf")]
    return Path(str(dist.locate_file(found)))


@pytest.fixture
def user_robots(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    folder = tmp_path / "robots"
    folder.mkdir()
    monkeypatch.setenv(descriptions.ENV, str(folder))
    load_robot.cache_clear()
    yield folder
    load_robot.cache_clear()


def test_the_shipped_robots_are_descriptions_with_their_facts() -> None:
    assert set(ROBOT_NAMES) == {"ur5", "kinova_gen3_6dof", "panda", "planar_2link"}
    ur5 = load_robot("ur5")
    assert ur5.dof == 6 and ur5.tip_link == "ee_link"
    # the paper's ranges in this project's joint zeros (−π/2 on shoulder_lift and wrist_1)
    assert ur5.facts.sampling_ranges is not None
    assert ur5.facts.sampling_ranges[1] == (-1.0 - math.pi / 2, 0.5 - math.pi / 2)
    assert ur5.facts.sampling_ranges[3] == (-0.2 - math.pi / 2, 0.8 - math.pi / 2)
    assert "package://" not in ur5.urdf_path.read_text()  # meshes resolved for PyBullet
    kinova = load_robot("kinova_gen3_6dof")
    assert kinova.facts.sphere_radius == 0.065 and len(kinova.facts.keypoints) == 8


def test_an_added_arm_loads_by_name_and_builds_a_cell(user_robots: Path) -> None:
    assert main(["robot", "add", str(_xarm7()), "--name", "xarm7", "--dir", str(user_robots)]) == 0
    robot = load_robot("xarm7")
    assert robot.dof == 7 and robot.tip_link == "link_eef"
    assert "xarm7" in descriptions.robot_names()
    cell = cell_from_dict(
        {
            "name": "two_xarms",
            "arms": [
                {"id": "a", "robot": "xarm7"},
                {"id": "b", "robot": "xarm7", "base": {"xyz": [1.0, 0.0, 0.0]}},
            ],
        }
    )
    with CellWorld(cell) as world:
        world.set_configuration({"a": np.zeros(7), "b": np.zeros(7)})
        assert 0.0 < world.distance("a", "b") < 1.0


def test_adding_checks_the_urdf_and_the_name(user_robots: Path, tmp_path: Path) -> None:
    with pytest.raises(InvalidValueError, match="must not name a robot that exists"):
        main_or_raise(["robot", "add", str(_xarm7()), "--name", "ur5", "--dir", str(user_robots)])
    with pytest.raises(InvalidValueError, match="lower-case"):
        main_or_raise(["robot", "add", str(_xarm7()), "--name", "X7", "--dir", str(user_robots)])
    assert main(["robot", "add", str(tmp_path / "no.urdf"), "--name", "x", "--dir", "d"]) == 2


def main_or_raise(argv: list[str]) -> None:
    from nehmo_core.cli import build_parser
    from nehmo_core.robots.robot_cli import run

    run(build_parser().parse_args(argv))


@pytest.mark.parametrize(
    ("text", "error", "message"),
    [
        ("name: other\nurdf: a.urdf\ntip: t\n", InvalidValueError, "must be the folder's name"),
        ("name: arm\nurdf: a.urdf\n", InvalidValueError, r"\.tip` is required"),
        ("name: arm\nurdf: a.urdf\ntip: t\ncolour: red\n", InvalidValueError, "may only have"),
        ("name: arm\nurdf: missing.urdf\ntip: t\n", ModelFileError, "file not found"),
    ],
)
def test_a_broken_description_is_named(
    user_robots: Path, text: str, error: type, message: str
) -> None:
    (user_robots / "arm").mkdir()
    (user_robots / "arm" / "robot.yaml").write_text(text)
    (user_robots / "arm" / "a.urdf").write_text("<robot name='a'/>")
    with pytest.raises(error, match=message):
        load_robot("arm")


def test_a_name_described_twice_or_unknown_is_an_error(user_robots: Path) -> None:
    (user_robots / "ur5").mkdir()
    (user_robots / "ur5" / "robot.yaml").write_text("name: ur5\nurdf: x.urdf\ntip: t\n")
    with pytest.raises(ModelFileError, match="'ur5' is described twice"):
        descriptions.robot_names()
    (user_robots / "ur5" / "robot.yaml").unlink()
    with pytest.raises(UnknownNameError, match="unknown robot 'iiwa14'"):
        load_robot("iiwa14")
