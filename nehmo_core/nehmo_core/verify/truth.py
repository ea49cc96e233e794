"""The exact failure margin a rollout is judged by: true geometry, never the learned ``l``.

For an arm pair it is the signed distance between the two arms' collision geometry in PyBullet
(negative in penetration), posed in the pair's own cell; for the low-dimensional systems
(Air3D, two planar 2-link arms) the analytic boundary ``l(x)`` is already exact.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import torch

from nehmo_core.geometry.distance_data import CONDITIONED_PAIRS, PAIRS, pair_cell
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.hjr.systems import ArmPairSystem, HJISystem
from nehmo_core.robots.model import Cell, Pose

ExactMargin = Callable[[np.ndarray, float], np.ndarray]
"""``margin(x (B, n) [rad or m], cutoff [m]) -> (B,)`` [m]; values above ``cutoff`` may be
reported as ``cutoff``."""


def pair_arms(name: str) -> tuple[Cell, str, str]:
    """The cell of a shipped pair system and its arms in the system's order (arm 1, arm 2).

    ``kinova_ur5`` is the UR5-Kinova cell seen from the Kinova's base: the arms swap.
    """
    if name == "kinova_ur5":
        cell, a, b = pair_cell("ur5_kinova")
        return cell, b, a
    return pair_cell(name)


class PairDistance:
    """Exact signed distance [m] of a shipped arm pair, ``x = (q¹, q²)`` in the system's order.

    For a pose-conditioned pair, ``x = (q¹, q², r)``: arm 2 stands at ``(r, 0, 0)`` facing arm 1,
    the canonical frame of the conditioned models, moved for each state.
    """

    def __init__(self, system: ArmPairSystem) -> None:
        cell, self.arm_a, self.arm_b = pair_arms(system.name)
        self.n1, self.n2 = system.n1, system.n2
        self.conditioned = bool(system.conditions)
        self.world = CellWorld(cell)
        self._r: float | None = None

    def _place(self, r: float) -> None:
        if r != self._r:
            self.world.set_base_pose(self.arm_b, Pose((r, 0.0, 0.0), (0.0, 0.0, math.pi)))
            self._r = r

    def __call__(self, x: np.ndarray, cutoff: float = 1.0) -> np.ndarray:
        out = np.empty(x.shape[0])
        n1, n2 = self.n1, self.n2
        for i, state in enumerate(np.asarray(x, dtype=np.float64)):
            if self.conditioned:
                self._place(float(state[n1 + n2]))
            self.world.set_joint_positions(self.arm_a, state[:n1])
            self.world.set_joint_positions(self.arm_b, state[n1 : n1 + n2])
            out[i] = self.world.distance(self.arm_a, self.arm_b, cutoff)
        return out

    def close(self) -> None:
        self.world.close()


class AnalyticBoundary:
    """``l(x)`` of a system whose boundary is exact geometry (Air3D, the two-link pair)."""

    def __init__(self, system: HJISystem) -> None:
        self.system = system

    def __call__(self, x: np.ndarray, cutoff: float = np.inf) -> np.ndarray:
        with torch.no_grad():
            margin = self.system.boundary(torch.as_tensor(x, dtype=torch.float64))
        return np.minimum(margin.numpy(), cutoff)

    def close(self) -> None:
        """Nothing to release."""


def exact_margin(system: HJISystem) -> PairDistance | AnalyticBoundary:
    """The exact margin of a system: PyBullet for shipped arm pairs, ``l`` otherwise."""
    shipped = (*PAIRS, *CONDITIONED_PAIRS, "kinova_ur5")
    if isinstance(system, ArmPairSystem) and system.name in shipped:
        return PairDistance(system)
    return AnalyticBoundary(system)
