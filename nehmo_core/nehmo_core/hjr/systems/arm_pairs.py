"""The shipped 12-D arm-pair HJI systems: UR5-UR5 and UR5-Kinova Gen3 (6-DoF).

Boundary ``l(x)``: the shipped learned distance of the pair (frozen). Symmetry: the mirror
joint maps of both robots (``geometry.symmetry``), which leave ``l`` unchanged by construction.
``X_train``: joint 1 of arm 2 within [−π/2, π/2]; the map sends it to the other half because
both robots' joint-1 maps are ``q → π − q``. :func:`nehmo_core.hjr.systems.make_system`
builds them by name (:mod:`.registry` lists them).
"""

from __future__ import annotations

import numpy as np
import torch

from nehmo_core.geometry.distance_data import pair_cell
from nehmo_core.geometry.distance_model import load_distance_model
from nehmo_core.geometry.symmetry import robot_mirror_map
from nehmo_core.hjr.systems.arm_pair import ArmPairSystem, JointInterval
from nehmo_core.hjr.systems.registry import ARM_PAIR_NAMES

ARM_PAIRS = ARM_PAIR_NAMES


class SwappedBoundary(torch.nn.Module):
    """``l(q_a, q_b) = distance(q_b, q_a)``: a pair distance with the arms' roles exchanged.

    The Kinova-controls game (``kinova_ur5``: Kinova at the origin, UR5 0.6 m away facing it)
    is the UR5-Kinova cell seen from the other base (a rigid motion), so its boundary is the
    shipped ``ur5_kinova`` distance with the joint vectors swapped.
    """

    def __init__(self, distance: torch.nn.Module, n_first: int) -> None:
        super().__init__()
        self.distance = distance
        self.n_first = n_first  # joints of the arm that comes first in the *new* order

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.distance(torch.cat([x[:, self.n_first :], x[:, : self.n_first]], dim=1))


def make_arm_pair_system(pair: str) -> ArmPairSystem:
    """The HJI system of a shipped arm pair (``ū = d̄ = 0.5`` rad/s, ``T = 0.6`` s)."""
    if pair == "kinova_ur5":
        return _kinova_ur5_system()
    cell, a, b = pair_cell(pair)
    r1, r2 = cell.arm(a).robot, cell.arm(b).robot
    f = robot_mirror_map(r1.name) + robot_mirror_map(r2.name)
    # Both joint-1 maps are q → π − q: the halves [−π/2, π/2] and its complement swap.
    assert f.sign[r1.dof] == -1.0 and np.isclose(f.offset[r1.dof], np.pi)
    distance = load_distance_model(pair).float()
    # A conditioned pair (``*_any``): r is a constant coordinate; the mirror y → −y keeps both
    # bases on the x axis, so it is the same joint map at every r.
    base_range = distance.config.base2_range
    return ArmPairSystem(
        conditions=(base_range,) if base_range is not None else (),
        boundary_fn=distance,
        n1=r1.dof,
        n2=r2.dof,
        symmetry_sign=np.array(f.sign),
        symmetry_offset=np.array(f.offset),
        train_region=JointInterval(joint=r1.dof, low=-np.pi / 2, high=np.pi / 2),
        system_name=pair,
    )


def _kinova_ur5_system() -> ArmPairSystem:
    cell, ur5_id, kinova_id = pair_cell("ur5_kinova")
    kinova, ur5 = cell.arm(kinova_id).robot, cell.arm(ur5_id).robot
    f = robot_mirror_map(kinova.name) + robot_mirror_map(ur5.name)
    assert f.sign[kinova.dof] == -1.0 and np.isclose(f.offset[kinova.dof], np.pi)
    boundary = SwappedBoundary(load_distance_model("ur5_kinova").float(), kinova.dof)
    return ArmPairSystem(
        boundary_fn=boundary,
        n1=kinova.dof,
        n2=ur5.dof,
        symmetry_sign=np.array(f.sign),
        symmetry_offset=np.array(f.offset),
        train_region=JointInterval(joint=kinova.dof, low=-np.pi / 2, high=np.pi / 2),
        system_name="kinova_ur5",
    )
