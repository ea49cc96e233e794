"""Mirror maps of the arm pairs: found by search, checked on the exact geometry."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nehmo_core.geometry.distance_data import pair_cell, uniform_samples
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.geometry.symmetry import robot_mirror_map
from nehmo_core.robots import load_robot

HALF_PI = np.pi / 2


def test_ur5_map_matches_measured_reference() -> None:
    """For example-robot-data's UR5: q1→π−q1, q2→π−q2, q3→−q3, q4→π−q4, q5→−q5.

    (q6 turns the round flange about its own axis; its map is left as −q6.)
    """
    m = robot_mirror_map("ur5")
    assert m.sign == (-1.0,) * 6
    np.testing.assert_allclose(m.offset, [np.pi, np.pi, 0, np.pi, 0, 0])


@pytest.mark.parametrize("robot", ["ur5", "kinova_gen3_6dof", "planar_2link"])
def test_map_mirrors_every_link_origin_and_is_an_involution(robot: str) -> None:
    model = load_robot(robot)
    m = robot_mirror_map(robot)
    kin = ArmKinematics(model)
    rng = np.random.default_rng(1)
    lo, hi = np.maximum(model.lower, -np.pi), np.minimum(model.upper, np.pi)
    q = rng.uniform(lo, hi, size=(200, model.dof))
    with torch.no_grad():
        p = kin.link_positions(torch.from_numpy(q)).numpy()
        pm = kin.link_positions(torch.from_numpy(m.apply(q))).numpy()
    np.testing.assert_allclose(pm, p * np.array([1.0, -1.0, 1.0]), atol=1e-6)
    back = m.apply(m.apply(q))
    diff = np.angle(np.exp(1j * (back - q)))
    np.testing.assert_allclose(diff, 0.0, atol=1e-12)
    torch.testing.assert_close(m.apply_torch(torch.from_numpy(q)), torch.from_numpy(m.apply(q)))


@pytest.mark.parametrize("pair", ["ur5_ur5", "ur5_kinova"])
def test_exact_distance_is_nearly_invariant(pair: str) -> None:
    """On the collision geometry |l(x) − l(f(x))| stays small (the UR5 meshes are not exactly
    mirror-symmetric: reference figures mean 0.7 mm, max 3.3 cm)."""
    cell, a, b = pair_cell(pair)
    n1 = cell.arm(a).robot.dof
    f = robot_mirror_map(cell.arm(a).robot.name) + robot_mirror_map(cell.arm(b).robot.name)
    q = uniform_samples(pair, 150, np.random.default_rng(2))
    with CellWorld(cell) as world:

        def dist(x: np.ndarray) -> float:
            world.set_joint_positions(a, x[:n1])
            world.set_joint_positions(b, x[n1:])
            return world.distance(a, b, 1.0)

        d0 = np.array([dist(x) for x in q])
        d1 = np.array([dist(f.apply(x)) for x in q])
    near = d0 < 0.3
    err = np.abs(d0 - d1)[near]
    assert near.sum() > 30
    assert err.mean() < 0.002
    assert err.max() < 0.04
