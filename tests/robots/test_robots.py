"""Robot models and cell layouts load from the shipped files, and bad input is rejected."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest

from nehmo_core.errors import InvalidValueError, ModelFileError, NehmoError, UnknownNameError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots import ROBOT_NAMES, cell_names, load_cell, load_robot
from nehmo_core.robots.loader import cell_from_dict, robot_from_urdf
from nehmo_core.robots.model import ArmSpec, Cell, Pose


def test_ur5_model_from_example_robot_data() -> None:
    ur5 = load_robot("ur5")
    assert ur5.dof == 6
    assert ur5.joint_names[0] == "shoulder_pan_joint"
    assert ur5.joint_names[-1] == "wrist_3_joint"
    assert ur5.continuous.all()  # ±2π (elbow ±π): a full turn each
    assert "package://" not in ur5.urdf_path.read_text()
    # SRDF pairs are excluded from the self-collision list, adjacent links too.
    pairs = {frozenset(p) for p in ur5.self_collision_pairs()}
    assert frozenset(("forearm_link", "wrist_3_link")) not in pairs
    assert frozenset(("base_link", "forearm_link")) in pairs


def test_kinova_model_limits() -> None:
    kin = load_robot("kinova_gen3_6dof")
    assert kin.dof == 6
    assert kin.continuous.tolist() == [True, False, False, True, False, True]
    np.testing.assert_allclose(kin.upper[[1, 2, 4]], [2.41, 2.66, 2.23])
    np.testing.assert_allclose(kin.lower[[1, 2, 4]], [-2.41, -2.66, -2.23])


@pytest.mark.parametrize(
    ("pair", "joint"),
    [(("base_link", "bicep_link"), 1), (("forearm_link", "spherical_wrist_2_link"), 4)],
)
def test_kinova_pairs_touching_only_at_a_joint_limit_are_not_checked(pair, joint) -> None:
    """The primitives of these pairs touch only with the joint at (within 0.03 rad of) its
    limit, where the real links clear: the SRDF disables them, every other pair stays on."""
    kin = load_robot("kinova_gen3_6dof")
    assert frozenset(pair) not in {frozenset(p) for p in kin.self_collision_pairs()}
    assert len(kin.self_collision_pairs()) == 13  # 21 non-adjacent pairs minus these two
    world = CellWorld(Cell("one", (ArmSpec("k", kin, Pose()),)))
    rng = np.random.default_rng(0)
    lo, hi = np.maximum(kin.lower, -np.pi), np.minimum(kin.upper, np.pi)
    touching = []
    try:
        for _ in range(400):
            q = rng.uniform(lo, hi)
            q[joint] = rng.uniform(0.9, 1.0) * (hi[joint] if rng.random() < 0.5 else lo[joint])
            world.set_joint_positions("k", q)
            a, b = (world.link_index("k", name) for name in pair)
            body = world.body("k")
            pts = pb.getClosestPoints(body, body, 0.0, a, b, physicsClientId=world.client)
            if pts and min(p[8] for p in pts) <= 0.0:
                touching.append(abs(q[joint]))
    finally:
        world.close()
    assert touching  # the shapes do meet near the limit ...
    assert min(touching) > hi[joint] - 0.03  # ... and only there


def test_planar_two_link() -> None:
    arm = load_robot("planar_2link")
    assert arm.dof == 2 and arm.continuous.all()


def test_unknown_robot_lists_valid_names() -> None:
    with pytest.raises(UnknownNameError) as exc:
        load_robot("ur10")
    for name in ROBOT_NAMES:
        assert name in str(exc.value)


@pytest.mark.parametrize("name", ["dual_ur5", "triple_ur5", "five_ur5", "ur5_kinova"])
def test_shipped_cells(name: str) -> None:
    cell = load_cell(name)
    assert cell.name == name
    assert len(set(cell.arm_ids)) == len(cell.arms)
    # Every arm other than the centre one sits 0.6 m from it and faces it.
    for arm in cell.arms[1:]:
        x, y, _ = arm.base.xyz
        assert math.hypot(x, y) == pytest.approx(0.6)
        facing = np.array([math.cos(arm.base.yaw), math.sin(arm.base.yaw)])
        assert facing @ np.array([-x, -y]) / 0.6 == pytest.approx(1.0)


def test_cell_counts() -> None:
    assert [len(load_cell(n).arms) for n in ("dual_ur5", "triple_ur5", "five_ur5")] == [2, 3, 5]
    assert set(cell_names()) >= {"dual_ur5", "triple_ur5", "five_ur5", "ur5_kinova"}


def test_unknown_cell_lists_valid_names() -> None:
    with pytest.raises(UnknownNameError, match="dual_ur5"):
        load_cell("quad_ur5")
    with pytest.raises(UnknownNameError) as exc:
        load_cell("dual_ur5").arm("ur5_9")
    assert "ur5_0" in str(exc.value)


def test_cell_yaml_errors_name_the_field(tmp_path: Path) -> None:
    with pytest.raises(InvalidValueError, match=r"arms"):
        cell_from_dict({"name": "x"})
    with pytest.raises(InvalidValueError, match=r"arms\[0\]\.robot"):
        cell_from_dict({"arms": [{"id": "a"}]})
    with pytest.raises(UnknownNameError, match="ur5"):
        cell_from_dict({"arms": [{"id": "a", "robot": "ur55"}]})
    with pytest.raises(InvalidValueError, match="unique"):
        cell_from_dict({"arms": [{"id": "a", "robot": "ur5"}, {"id": "a", "robot": "ur5"}]})
    with pytest.raises(InvalidValueError, match="xyz"):
        cell_from_dict({"arms": [{"id": "a", "robot": "ur5", "base": {"xyz": [0, 0]}}]})
    arm = {"id": "a", "robot": "ur5"}
    for base, field in (
        ({"xzy": [0, 0, 1]}, r"arms\[0\]\.base` may only have keys xyz, rpy"),  # misspelt
        ({"xyz": [float("nan"), 0, 0]}, r"arms\[0\]\.base\.xyz` must be a list of 3 finite"),
        ({"xyz": "0 0 0"}, r"arms\[0\]\.base\.xyz`"),
        ({"rpy": 1.0}, r"arms\[0\]\.base\.rpy`"),
        ([0, 0, 0], r"arms\[0\]\.base` must be a mapping"),
    ):
        with pytest.raises(InvalidValueError, match=field):
            cell_from_dict({"arms": [{**arm, "base": base}]})
    with pytest.raises(InvalidValueError, match=r"arms\[0\]` may only have keys"):
        cell_from_dict({"arms": [{**arm, "bsae": {"xyz": [0, 0, 1]}}]})
    bad = tmp_path / "bad.yaml"
    bad.write_text("arms: [unclosed")
    with pytest.raises(NehmoError, match="not valid YAML"):
        load_cell(bad)
    with pytest.raises(ModelFileError, match="not found"):
        load_cell(tmp_path / "missing.yaml")


def test_joint_vector_checks() -> None:
    ur5 = load_robot("ur5")
    with pytest.raises(InvalidValueError, match="must have 6 joint values"):
        ur5.check_q([0.0] * 5)
    with pytest.raises(InvalidValueError, match="finite"):
        ur5.check_q([0.0, float("nan"), 0, 0, 0, 0], "goal")
    with pytest.raises(InvalidValueError, match="`goal`"):
        ur5.check_q([0.0] * 7, "goal")
    kin = load_robot("kinova_gen3_6dof")
    with pytest.raises(InvalidValueError, match="joint_2"):
        kin.check_within_limits([0.0, 3.0, 0, 0, 0, 0])
    assert kin.check_within_limits([10.0, 2.0, 0, 0, 0, 0]).shape == (6,)


def test_wrap_only_continuous_joints() -> None:
    kin = load_robot("kinova_gen3_6dof")
    q = kin.wrap([4.0, 2.0, -2.5, -4.0, 1.0, 7.0])
    np.testing.assert_allclose(
        q, [4.0 - 2 * np.pi, 2.0, -2.5, -4.0 + 2 * np.pi, 1.0, 7.0 - 2 * np.pi]
    )


def test_missing_mesh_is_reported(tmp_path: Path) -> None:
    ur5 = load_robot("ur5")
    text = ur5.urdf_path.read_text().replace("collision/forearm.stl", "collision/gone.stl")
    urdf = tmp_path / "ur5.urdf"
    urdf.write_text(text)
    with pytest.raises(ModelFileError, match=r"gone\.stl"):
        robot_from_urdf("ur5", urdf, "ee_link")
    with pytest.raises(ModelFileError, match="not found"):
        robot_from_urdf("ur5", tmp_path / "nope.urdf", "ee_link")


def test_relative_mesh_paths_resolve(tmp_path: Path) -> None:
    kin = load_robot("kinova_gen3_6dof")
    copy = tmp_path / "k.urdf"
    shutil.copy(kin.urdf_path, copy)
    assert robot_from_urdf("k", copy, "end_effector_link").dof == 6
