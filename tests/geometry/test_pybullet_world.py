"""Exact signed distances and collision checks of a cell's PyBullet world."""

from __future__ import annotations

import math

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots import load_cell

# An upright UR5 in our joint zeros: shoulder_lift and wrist_1 at −π/2.
UPRIGHT = np.array([0.0, -np.pi / 2, 0.0, -np.pi / 2, 0.0, 0.0])


@pytest.fixture(scope="module")
def dual() -> CellWorld:
    world = CellWorld(load_cell("dual_ur5"))
    yield world
    world.close()


def test_far_apart_arms_are_separated(dual: CellWorld) -> None:
    dual.set_configuration({"ur5_0": UPRIGHT, "ur5_1": UPRIGHT})
    d = dual.distance("ur5_0", "ur5_1")
    # Upright arms 0.6 m apart: the gap is 0.6 m minus roughly two link radii.
    assert 0.3 < d < 0.6
    assert not dual.in_collision()


def test_penetration_is_negative_and_reported(dual: CellWorld) -> None:
    reach = np.array([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # both arms stretched toward each other
    dual.set_configuration({"ur5_0": reach, "ur5_1": reach})
    assert dual.distance("ur5_0", "ur5_1") < 0
    hits = dual.collisions(self_collision=False)
    assert hits and hits[0].arm_a == "ur5_0" and hits[0].arm_b == "ur5_1"
    assert hits[0].distance < 0


def test_distance_is_continuous(dual: CellWorld) -> None:
    dual.set_joint_positions("ur5_1", UPRIGHT)
    values = []
    for a in np.linspace(-np.pi / 2, 0.0, 40):
        dual.set_joint_positions("ur5_0", [0.0, a, 0.0, -np.pi / 2, 0.0, 0.0])
        values.append(dual.distance("ur5_0", "ur5_1"))
    assert np.max(np.abs(np.diff(values))) < 0.05
    assert values[0] > 0 > values[-1] or values[-1] < values[0]


def test_self_collision_detected() -> None:
    with CellWorld(load_cell("dual_ur5")) as world:
        world.set_joint_positions("ur5_0", UPRIGHT)
        world.set_joint_positions("ur5_1", [np.pi, 0.0, 0.0, 0.0, 0.0, 0.0])
        assert not world.collisions(self_collision=True)
        # Elbow folded fully back: the forearm passes through the upper arm / shoulder.
        world.set_joint_positions("ur5_0", [0.0, -np.pi / 2, 3.1, 0.0, 0.0, 0.0])
        hits = world.collisions(self_collision=True)
        assert any(h.arm_a == h.arm_b == "ur5_0" for h in hits)


def test_all_pairs_checked_in_five_arm_cell() -> None:
    with CellWorld(load_cell("five_ur5")) as world:
        for arm_id in world.cell.arm_ids:
            world.set_joint_positions(arm_id, UPRIGHT)
        # Two outer arms (not the centre one) reach toward each other diagonally.
        assert not world.in_collision()
        world.set_joint_positions("ur5_1", [-np.pi / 4, 0.0, 0.0, 0.0, 0.0, 0.0])
        world.set_joint_positions("ur5_3", [np.pi / 4, 0.0, 0.0, 0.0, 0.0, 0.0])
        pairs = {(h.arm_a, h.arm_b) for h in world.collisions(self_collision=False)}
        assert ("ur5_1", "ur5_3") in pairs


def test_bad_input(dual: CellWorld) -> None:
    with pytest.raises(InvalidValueError, match="6 joint values"):
        dual.set_joint_positions("ur5_0", [0.0] * 5)
    with pytest.raises(InvalidValueError, match="finite"):
        dual.set_joint_positions("ur5_0", [np.nan] * 6)
    with pytest.raises(UnknownNameError, match="ur5_1"):
        dual.distance("ur5_0", "ur5_7")


@pytest.mark.parametrize("arm_id", ["kinova_0", "ur5_0"])
def test_set_base_pose_places_the_base_link_frame(arm_id: str) -> None:
    """PyBullet poses a base by its inertial frame (the Kinova's sits 8.4 cm above its link
    frame): set_base_pose must put the URDF link frame where asked, as the loaded cell does."""
    from nehmo_core.robots.model import Pose

    with CellWorld(load_cell("ur5_kinova")) as world:
        declared = world.cell.arm(arm_id).base
        np.testing.assert_allclose(world.base_link_frame(arm_id), declared.matrix(), atol=1e-6)
        for pose in (
            Pose((0.37, -0.2, 0.0), (0.0, 0.0, math.pi)),
            Pose((1.1, 0.4, 0.05), (0.0, 0.0, -0.8)),
        ):
            world.set_base_pose(arm_id, pose)
            np.testing.assert_allclose(world.base_link_frame(arm_id), pose.matrix(), atol=1e-6)
            origin = world.link_world_positions(arm_id)["base_link"]
            np.testing.assert_allclose(origin, pose.xyz, atol=1e-6)
        # the same pose as declared gives the same distance as the loaded cell
        world.set_base_pose(arm_id, declared)
        q = {a: np.full(6, 0.3) for a in world.cell.arm_ids}
        world.set_configuration(q)
        moved = world.distance("ur5_0", "kinova_0")
    with CellWorld(load_cell("ur5_kinova")) as fresh:
        fresh.set_configuration(q)
        assert moved == pytest.approx(fresh.distance("ur5_0", "kinova_0"), abs=1e-6)
