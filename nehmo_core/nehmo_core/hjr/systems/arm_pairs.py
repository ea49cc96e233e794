"""The shipped 12-D arm-pair HJI systems: UR5-UR5 and UR5-Kinova Gen3 (6-DoF).

Boundary ``l(x)``: the shipped learned distance of the pair (frozen). Symmetry: the mirror
joint maps of both robots (``geometry.symmetry``), which leave ``l`` unchanged by construction.
``X_train``: joint 1 of arm 2 within [−π/2, π/2]; the map sends it to the other half because
both robots' joint-1 maps are ``q → π − q``. :func:`nehmo_core.hjr.systems.make_system`
builds them by name (:mod:`.registry` lists them). The Kinova-controls games (``kinova_ur5``,
``kinova_ur5_any``) reuse the UR5-Kinova distances with the arms swapped
(:data:`~nehmo_core.geometry.distance_data.SWAPPED_PAIRS`).
"""

from __future__ import annotations

import numpy as np
import torch

from nehmo_core.geometry.distance_data import SWAPPED_PAIRS, pair_cell
from nehmo_core.geometry.distance_model import SHIPPED_DISTANCE_MODELS, load_distance_model
from nehmo_core.geometry.symmetry import robot_mirror_map
from nehmo_core.hjr.systems.arm_pair import ArmPairSystem, JointInterval
from nehmo_core.hjr.systems.registry import ARM_PAIR_NAMES

ARM_PAIRS = tuple(p for p in ARM_PAIR_NAMES if SWAPPED_PAIRS.get(p, p) in SHIPPED_DISTANCE_MODELS)
"""The arm pairs of :data:`ARM_PAIR_NAMES` whose learned distance is in ``models/`` (the ones
:func:`make_arm_pair_system` can build here)."""


class SwappedBoundary(torch.nn.Module):
    """``l(q_a, q_b[, c]) = distance(q_b, q_a[, c])``: a pair distance with the arms' roles
    exchanged; condition coordinates ``c`` (the base distance ``r`` of a conditioned pair) stay
    last.

    The Kinova-controls game (``kinova_ur5``: Kinova at the origin, UR5 0.6 m away facing it)
    is the UR5-Kinova cell seen from the other base (a rigid motion), so its boundary is the
    shipped ``ur5_kinova`` distance with the joint vectors swapped. So is ``kinova_ur5_any``'s
    (UR5 at ``(r, 0, 0)`` facing the Kinova) the ``ur5_kinova_any`` distance at the same ``r``:
    seen from a base that faces the other along x, the other stands at ``(r, 0, 0)`` facing it.
    """

    def __init__(
        self, distance: torch.nn.Module, n_first: int, n_second: int | None = None
    ) -> None:
        super().__init__()
        self.distance = distance
        self.n_first = n_first  # joints of the arm that comes first in the *new* order
        # joints of the other arm; None: every coordinate after the first arm's (no conditions)
        self.n_second = n_second

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        n = x.shape[1] if self.n_second is None else self.n_first + self.n_second
        first, second, rest = x[:, : self.n_first], x[:, self.n_first : n], x[:, n:]
        return self.distance(torch.cat([second, first, rest], dim=1))


def make_arm_pair_system(pair: str) -> ArmPairSystem:
    """The HJI system of a shipped arm pair (``ū = d̄ = 0.5`` rad/s, ``T = 0.6`` s)."""
    if pair in SWAPPED_PAIRS:
        return _swapped_system(pair)
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


def _swapped_system(name: str) -> ArmPairSystem:
    """A game whose controlled arm is arm 2 of the learned distance it reuses (the Kinova's
    side of a UR5-Kinova pair): the same mirror maps, in the swapped order."""
    cell, pair_first, pair_second = pair_cell(SWAPPED_PAIRS[name])
    own, other = cell.arm(pair_second).robot, cell.arm(pair_first).robot
    f = robot_mirror_map(own.name) + robot_mirror_map(other.name)
    assert f.sign[own.dof] == -1.0 and np.isclose(f.offset[own.dof], np.pi)
    distance = load_distance_model(SWAPPED_PAIRS[name]).float()
    base_range = distance.config.base2_range
    return ArmPairSystem(
        conditions=(base_range,) if base_range is not None else (),
        boundary_fn=SwappedBoundary(distance, own.dof, other.dof),
        n1=own.dof,
        n2=other.dof,
        symmetry_sign=np.array(f.sign),
        symmetry_offset=np.array(f.offset),
        train_region=JointInterval(joint=own.dof, low=-np.pi / 2, high=np.pi / 2),
        system_name=name,
    )
