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

from nehmo_core.errors import NehmoError
from nehmo_core.geometry.distance_data import (
    SWAPPED_PAIRS,
    pair_joint_domain,
    system_pair_cell,
)
from nehmo_core.geometry.distance_model import SHIPPED_DISTANCE_MODELS, load_distance_model
from nehmo_core.geometry.symmetry import JointMap, robot_mirror_map
from nehmo_core.hjr.systems.arm_pair import ArmPairSystem, JointInterval
from nehmo_core.hjr.systems.registry import ARM_PAIR_NAMES
from nehmo_core.robots.model import RobotModel, wrap_angle

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


def pair_symmetry(pair: str) -> JointMap:
    """The mirror map of a pair's joint vector (arm 1's, then arm 2's)."""
    cell, a, b = system_pair_cell(pair)
    return _pair_map(cell.arm(a).robot, cell.arm(b).robot)


def make_arm_pair_system(pair: str) -> ArmPairSystem:
    """The HJI system of a registered arm pair (``ū = d̄ = 0.5`` rad/s, ``T = 0.6`` s).

    A swapped pair's boundary is its source's distance with the arms exchanged. The mirror maps
    of both robots make the symmetry (used by ``bc+sym``); ``X_train`` is the half of arm 2's
    first joint that its map sends onto the other half. A ``limits``-domain pair (built by
    ``nehmo pair build``) spans each limited joint's limits, widened
    (:func:`~nehmo_core.geometry.distance_data.pair_joint_domain`); the others every joint's circle.
    """
    source = SWAPPED_PAIRS.get(pair, pair)
    cell, a, b = system_pair_cell(pair)
    r1, r2 = cell.arm(a).robot, cell.arm(b).robot
    f = pair_symmetry(pair)
    distance = load_distance_model(source).float()
    boundary = SwappedBoundary(distance, r1.dof, r2.dof) if pair in SWAPPED_PAIRS else distance
    # A conditioned pair (``*_any``): r is a constant coordinate; the mirror y → −y keeps both
    # bases on the x axis, so it is the same joint map at every r.
    base_range = distance.config.base2_range
    domain = pair_joint_domain(pair)
    return ArmPairSystem(
        conditions=(base_range,) if base_range is not None else (),
        boundary_fn=boundary,
        n1=r1.dof,
        n2=r2.dof,
        symmetry_sign=np.array(f.sign),
        symmetry_offset=np.array(f.offset),
        train_region=_train_region(f, r1.dof),
        system_name=pair,
        joint_periodic=None if domain is None else tuple(bool(v) for v in domain[2]),
        joint_box=None if domain is None else tuple(zip(domain[0], domain[1], strict=True)),
    )


def _pair_map(r1: RobotModel, r2: RobotModel) -> JointMap:
    """Both robots' mirror maps; the identity where a robot has none (its pairs train ``bc``)."""
    parts = []
    for robot in (r1, r2):
        try:
            parts.append(robot_mirror_map(robot.name))
        except NehmoError:
            n = robot.dof
            parts.append(JointMap((1.0,) * n, (0.0,) * n, tuple(bool(c) for c in robot.continuous)))
    return parts[0] + parts[1]


def _train_region(f: JointMap, joint: int) -> JointInterval:
    """``X_train``: the half of ``joint`` (arm 2's first, a reflection ``q → −q + c`` under the
    mirror) that the map sends onto the other half, ``[c/2 − π, c/2]`` (wrapped)."""
    if f.sign[joint] != -1.0:  # no halves to fold (no mirror map): X_train is everything
        return JointInterval(joint=joint, low=-np.inf, high=np.inf)
    centre = float(wrap_angle(f.offset[joint] / 2.0 - np.pi / 2.0))
    low, high = centre - np.pi / 2, centre + np.pi / 2
    if low < -np.pi - 1e-9:  # the half wraps past ±π: take the other one
        low, high = low + np.pi, high + np.pi
    return JointInterval(joint=joint, low=low, high=high)
