"""Forward kinematics agrees with PyBullet and with pytorch-kinematics."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.loader import cell_from_dict
from nehmo_core.robots.model import Cell


def _single_arm_cell(robot: str) -> Cell:
    # A non-trivial base pose, so the base transform is exercised too.
    base = {"xyz": [0.3, -0.2, 0.1], "rpy": [0.1, -0.2, 2.5]}
    return cell_from_dict({"name": robot, "arms": [{"id": "a", "robot": robot, "base": base}]})


@pytest.mark.parametrize("robot", ["ur5", "kinova_gen3_6dof", "planar_2link"])
def test_fk_matches_pybullet(robot: str) -> None:
    """Max link-origin position error < 1e-5 m over 1,000 random configurations."""
    cell = _single_arm_cell(robot)
    arm = cell.arms[0]
    kin = ArmKinematics(arm.robot, arm.base)
    rng = np.random.default_rng(0)
    lo = np.maximum(arm.robot.lower, -np.pi)
    hi = np.minimum(arm.robot.upper, np.pi)
    q = rng.uniform(lo, hi, size=(1000, arm.robot.dof))
    tf = kin.link_transforms(torch.from_numpy(q))
    worst = 0.0
    with CellWorld(cell) as world:
        for i in range(len(q)):
            world.set_joint_positions("a", q[i])
            for name, pos in world.link_world_positions("a").items():
                if name in tf:
                    worst = max(worst, float(np.abs(tf[name][i, :3, 3].numpy() - pos).max()))
    assert worst < 1e-5


@pytest.mark.parametrize("robot", ["ur5", "kinova_gen3_6dof"])
def test_fk_matches_pytorch_kinematics(robot: str) -> None:
    cell = _single_arm_cell(robot)
    kin = ArmKinematics(cell.arms[0].robot)  # pytorch-kinematics chain has no base pose
    q = torch.rand(64, 6, dtype=torch.float64, generator=torch.Generator().manual_seed(0)) * 6 - 3
    ours = kin.link_transforms(q)
    ref = kin.pk_chain.forward_kinematics(q, end_only=False)
    for name, T in ref.items():
        torch.testing.assert_close(ours[name], T.get_matrix(), atol=1e-12, rtol=0)


def test_fk_is_differentiable() -> None:
    kin = ArmKinematics(_single_arm_cell("ur5").arms[0].robot)
    q = torch.rand(
        3, 6, dtype=torch.float64, requires_grad=True, generator=torch.Generator().manual_seed(1)
    )

    def tip(x: torch.Tensor) -> torch.Tensor:
        return kin.link_positions(x, ("ee_link",))[:, 0].sum(-1)

    assert torch.autograd.gradcheck(tip, (q,))
