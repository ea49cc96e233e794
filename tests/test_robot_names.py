"""Robot facts live with the robots: code outside ``nehmo_core/robots/`` names no robot.

Whatever is known about a robot by name (keypoints, CHOMP radius, sampling ranges) is in its
description file (``robots/data/<name>/robot.yaml``), and what is known about a pair of robots
(which learned distances and value functions exist) is in the robot registry,
:mod:`nehmo_core.robots.registry`; both reach other code through ``robot.facts`` or the
registry's tables. So no string constant of the planner, geometry, simulation, evaluation, HJR,
verification or ROS code may equal a robot name or a shipped pair / model name. Docstrings (and
comments) are exempt, and so are data files and tests. A constant that is the name of a shipped
cell layout (``ur5_kinova`` is a cell as well as a pair) names the cell, which is data, and
passes.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.robots import ROBOT_NAMES, cell_names, load_cell, load_robot
from nehmo_core.robots.descriptions import robot_description
from nehmo_core.robots.registry import ARM_PAIRS, MODELS_DIR, PAIR_NAMES, SWAPPED_PAIRS, robot_facts

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "nehmo_core" / "nehmo_core"
ROBOTS_PACKAGE = CORE / "robots"
SCANNED = [CORE, ROOT / "nehmo_ros" / "nehmo_ros", ROOT / "sim_bridge" / "sim_bridge"]


def _forbidden() -> set[str]:
    """Robot names, pair names and shipped model names (file stems) that contain one."""
    models = {p.stem for p in MODELS_DIR.glob("*.json")}
    named = {m for m in models if any(r in m for r in ROBOT_NAMES)}
    return (set(ROBOT_NAMES) | set(PAIR_NAMES) | named) - set(cell_names())


def _sources() -> list[Path]:
    files = [f for root in SCANNED for f in sorted(root.rglob("*.py"))]
    return [f for f in files if not f.is_relative_to(ROBOTS_PACKAGE)]


def _name_literals(path: Path, names: set[str]) -> list[tuple[int, str]]:
    """``(line, constant)`` of every string constant in ``names`` but docstrings."""
    tree = ast.parse(path.read_text(), filename=str(path))
    bare = {
        id(node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant)
    }  # docstrings, module/class/function/attribute ones alike
    return [
        (node.lineno, node.value)
        for node in ast.walk(tree)
        if isinstance(node, ast.Constant)
        and isinstance(node.value, str)
        and node.value in names
        and id(node) not in bare
    ]


def test_no_robot_or_pair_name_literal_outside_the_robot_registry() -> None:
    names = _forbidden()
    assert {"ur5", "kinova_gen3_6dof", "ur5_ur5", "kinova_ur5_any"} <= names  # the list is real
    files = _sources()
    assert len(files) > 100 and any(f.name == "scenarios.py" for f in files)
    found = [
        f"{f.relative_to(ROOT)}:{line}: {value!r}"
        for f in files
        for line, value in _name_literals(f, names)
    ]
    assert not found, "robot names outside nehmo_core/robots/ (put the fact in the robot " + (
        "registry, nehmo_core/robots/registry.py):\n" + "\n".join(found)
    )


def test_the_check_finds_a_literal_and_skips_docstrings(tmp_path: Path) -> None:
    code = tmp_path / "mod.py"
    code.write_text('"""ur5"""\n\nX = {"ur5": 1}\n"""ur5"""\n\n\ndef f():\n    """ur5"""\n')
    assert _name_literals(code, {"ur5"}) == [(3, "ur5")]


@pytest.mark.parametrize("name", ROBOT_NAMES)
def test_a_loaded_robot_carries_its_registry_facts(name: str) -> None:
    robot = load_robot(name)
    assert robot.facts == robot_facts(name) == robot_description(name).facts
    links = set(ArmKinematics(robot).link_names)
    assert set(robot.facts.keypoints) <= links
    assert {x for a, b, _ in robot.facts.keypoint_segments for x in (a, b)} <= links
    if robot.facts.sampling_ranges is not None:
        assert len(robot.facts.sampling_ranges) == robot.dof
        assert all(lo <= hi for lo, hi in robot.facts.sampling_ranges)


@pytest.mark.parametrize("pair", ARM_PAIRS, ids=lambda p: p.name)
def test_every_pair_names_the_robots_of_its_frame(pair) -> None:  # type: ignore[no-untyped-def]
    assert set(pair.robots) <= set(ROBOT_NAMES)
    if pair.cell is not None:
        cell_name, a, b = pair.cell
        cell = load_cell(cell_name)
        assert (cell.arm(a).robot.name, cell.arm(b).robot.name) == pair.robots
    if pair.swapped is not None:
        other = next(p for p in ARM_PAIRS if p.name == SWAPPED_PAIRS[pair.name])
        assert other.robots == pair.robots[::-1] and other.swapped is None
