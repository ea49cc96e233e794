"""The 12-D arm-pair systems: boundary, symmetry and the Kinova-controls game."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.hjr.systems.arm_pairs import ARM_PAIRS, make_arm_pair_system
from nehmo_core.robots import registry
from nehmo_core.robots.loader import cell_from_dict

SYMMETRIC = [
    p.name
    for p in registry.ARM_PAIRS
    if p.name in ARM_PAIRS and "bc+sym" in (*p.values, *p.optional_values)
]
"""The pairs that train bc+sym: their robots' mirror maps hold on the geometry (a pair whose
robots have none, such as the Panda's, ships bc)."""


NEARLY_SYMMETRIC = {
    "kinova_gen3_6dof_kinova_gen3_6dof_any": (0.009, 0.001),
    "ur5_kinova_gen3_6dof_far": (0.0095, 0.0003),
    "kinova_gen3_6dof_ur5_far": (0.0095, 0.0003),
}
"""(largest, mean) |l(x) − l(f(x))| [m] of built pairs, held to their own measured figures (at
2000 states: 8.3 and 0.84 mm for the two Kinovas, 9.3 and 0.25 mm for the UR5-Kinova far range):
their learned distance reads points that k-means placed in each link's collision geometry, which
are not mirror images of each other, so their boundary is symmetric only as closely as the
distance is learned (its certified level: 8.5 and 7.8 mm); the mirror
map itself holds on the exact geometry (the build's check). The ``bc+sym`` value is folded,
so exactly symmetric; its certificates were taken on it as it is."""


@pytest.mark.parametrize("pair", SYMMETRIC)
def test_boundary_is_invariant_under_the_symmetry(pair: str) -> None:
    system = make_arm_pair_system(pair)
    x = system.sample_states(2000, torch.Generator().manual_seed(0))
    with torch.no_grad():
        diff = (system.boundary(x) - system.boundary(system.symmetry(x))).abs()
    largest, mean = NEARLY_SYMMETRIC.get(pair, (1e-4, 1e-4))  # 1e-4: a float32 model
    assert float(diff.max()) < largest and float(diff.mean()) < mean
    assert system.in_train(x).float().mean().item() == pytest.approx(0.5, abs=0.05)
    assert bool(system.in_train(system.fold(x)).all())


def test_kinova_controls_game_sees_the_same_geometry() -> None:
    """kinova_ur5 puts the Kinova at the origin: its boundary must match that cell exactly."""
    system = make_arm_pair_system("kinova_ur5")
    cell = cell_from_dict(
        {
            "name": "kinova_ur5",
            "arms": [
                {"id": "k", "robot": "kinova_gen3_6dof"},
                {"id": "u", "robot": "ur5", "base": {"xyz": [0.6, 0, 0], "rpy": [0, 0, np.pi]}},
            ],
        }
    )
    rng = np.random.default_rng(0)
    errors = []
    with CellWorld(cell) as world:
        for _ in range(300):
            qk, qu = rng.uniform(-2.2, 2.2, 6), rng.uniform(-np.pi, np.pi, 6)
            world.set_joint_positions("k", qk)
            world.set_joint_positions("u", qu)
            d = world.distance("k", "u", 1.0)
            if d < 0.1:
                x = torch.tensor(np.concatenate([qk, qu])[None], dtype=torch.float32)
                with torch.no_grad():
                    errors.append(abs(float(system.boundary(x)) - d))
    assert len(errors) > 30
    assert np.mean(errors) < 0.025
