"""Keypoints in the bulk of the collision geometry: inside their links, seeded, carried by cards."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
import torch

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.collision_points import collision_points
from nehmo_core.geometry.distance_model import (
    DistanceModelConfig,
    PairDistanceModel,
    load_distance_file,
)
from nehmo_core.geometry.distance_train import DistanceTrainSettings
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose


@pytest.fixture(scope="module")
def panda_points() -> tuple[tuple[str, float, float, float], ...]:
    return collision_points(load_robot("panda"))


def test_every_point_lies_inside_the_geometry_of_its_link(panda_points) -> None:
    """Every collision link of the chain holds points, and each point is inside the geometry of
    its link or of what hangs from it (the fingers are the hand's)."""
    robot = load_robot("panda")
    assert {p[0] for p in panda_points} == set(robot.links)
    world = CellWorld(Cell("one", (ArmSpec("arm", robot, Pose()),)))
    try:
        c, body, links = world.client, world.body("arm"), world.links("arm")
        probe = pb.createMultiBody(
            0, pb.createCollisionShape(pb.GEOM_SPHERE, radius=1e-3, physicsClientId=c),
            physicsClientId=c,
        )  # fmt: skip
        world.set_joint_positions("arm", np.zeros(robot.dof))
        for link, x, y, z in panda_points:
            index = links[link]
            if index >= 0:
                state = pb.getLinkState(
                    body, index, computeForwardKinematics=True, physicsClientId=c
                )
                pos, orn = state[4], state[5]
            else:
                pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=c)
            rot = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)
            world_point = np.array(pos) + rot @ np.array([x, y, z])
            pb.resetBasePositionAndOrientation(
                probe, world_point.tolist(), (0, 0, 0, 1), physicsClientId=c
            )
            own = [index] + [links[f] for f in ("panda_leftfinger", "panda_rightfinger")] * (
                link == "panda_hand"
            )
            hits = [
                h for i in own
                for h in pb.getClosestPoints(probe, body, 0.0, linkIndexB=i, physicsClientId=c)
            ]  # fmt: skip
            assert hits and min(h[8] for h in hits) < 0, (link, x, y, z)
    finally:
        world.close()


def test_points_are_seeded_and_follow_the_spacing(panda_points) -> None:
    robot = load_robot("panda")
    assert collision_points(robot) == panda_points
    coarse = collision_points(robot, spacing=0.3)
    assert len(coarse) < len(panda_points)
    # the forearm (link 5, about 0.3 m of housing) gets several points at the default spacing
    assert sum(p[0] == "panda_link5" for p in panda_points) >= 3


def test_bad_spacing_is_rejected_by_name() -> None:
    with pytest.raises(InvalidValueError, match="spacing"):
        collision_points(load_robot("panda"), spacing=0.0)
    with pytest.raises(InvalidValueError, match="keypoints"):
        DistanceTrainSettings(keypoints="spheres")
    with pytest.raises(InvalidValueError, match="grad_clip"):
        DistanceTrainSettings(grad_clip=0.0)


def test_a_model_with_its_own_points_round_trips_through_its_card(
    panda_points, tmp_path: Path
) -> None:
    config = DistanceModelConfig(
        "panda", "panda", (0.0, 0.0, 0.0), (0.0, 0.0, np.pi), hidden=(8,),
        base2_range=(0.25, 2.05), points1=panda_points, points2=panda_points[:5],
    )  # fmt: skip
    model = PairDistanceModel(config)
    assert model.kp1.count == len(panda_points) and model.kp2.count == 5
    path = tmp_path / "distance_panda_panda_any.safetensors"
    model.save(path, {"pair": "panda_panda_any"})
    loaded = load_distance_file(path, "panda_panda_any")
    assert loaded.config == config
    q = torch.from_numpy(np.random.default_rng(0).uniform(-1, 1, (4, 15)))
    q[:, 14] = 0.8
    assert torch.allclose(loaded(q), model(q))


def test_the_casadi_graph_of_a_model_with_its_own_points_matches_torch(panda_points) -> None:
    from nehmo_core.geometry.distance_casadi import distance_function

    config = DistanceModelConfig(
        "panda", "panda", (0.0, 0.0, 0.0), (0.0, 0.0, np.pi), hidden=(16, 16),
        base2_range=(0.25, 2.05), points1=panda_points, points2=panda_points,
    )  # fmt: skip
    model = PairDistanceModel(config)
    gen = torch.Generator().manual_seed(3)
    with torch.no_grad():
        for p in model.mlp.parameters():
            p.copy_(0.3 * torch.randn(p.shape, generator=gen, dtype=p.dtype))
    fn = distance_function(model)
    q = np.random.default_rng(4).uniform(-2.0, 2.0, (6, 15))
    q[:, 14] = np.linspace(0.3, 1.9, 6)
    ref_v, ref_g = model.distance_and_gradient(q)
    out = [fn(qi) for qi in q]
    np.testing.assert_allclose([float(o[0]) for o in out], ref_v, atol=1e-9, rtol=0)
    np.testing.assert_allclose([np.asarray(o[1]).ravel() for o in out], ref_g, atol=1e-9, rtol=0)
