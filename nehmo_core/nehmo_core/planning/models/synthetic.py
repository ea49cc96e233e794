"""Stand-in pair models for tests and benchmarks, until trained value functions exist.

* :func:`planning_distance_model` returns the shipped learned distance of a pair when its weights
  are present, else a *proxy* of the same class and size whose MLP passes one feature through:
  ``l ≈ softmin₆₀(keypoint distances) − radius`` [m]. The proxy is a crude but meaningful
  distance (it is small when the arms' keypoints are close), and it costs what the real model
  costs to evaluate.
* :func:`arm_pair_system` builds the :class:`~nehmo_core.hjr.systems.ArmPairSystem` of a pair
  with that boundary and the pair's mirror symmetry.
* :func:`random_value_function` builds a value network with random weights; with ``bc`` or
  ``bc+sym`` and a small ``residual_scale`` its ``V`` is the distance plus a small smooth
  residual, so a planner constrained by it behaves sensibly.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from nehmo_core.errors import ModelFileError
from nehmo_core.geometry.distance_data import pair_cell
from nehmo_core.geometry.distance_model import (
    DistanceModelConfig,
    PairDistanceModel,
    load_distance_model,
)
from nehmo_core.geometry.symmetry import robot_mirror_map
from nehmo_core.hjr.networks import NetworkSettings, ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import ArmPairSystem, JointInterval

__all__ = [
    "arm_pair_system",
    "planning_distance_model",
    "proxy_distance_model",
    "random_value_function",
]

_LINEAR_OFFSET = 10.0  # keeps SiLU in its near-linear range: silu(x) = x·σ(x), σ(10) ≈ 1 − 5e-5


def proxy_distance_model(pair: str, radius: float = 0.08, seed: int = 0) -> PairDistanceModel:
    """A :class:`PairDistanceModel` whose output is ``≈ softmin₆₀(keypoint distances) − radius``.

    Hidden units other than the pass-through one get small random weights (the output ignores
    them) so that evaluation costs as much as a trained model of the default size.
    """
    cell, a, b = pair_cell(pair)
    arm2 = cell.arm(b)
    config = DistanceModelConfig(
        cell.arm(a).robot.name, arm2.robot.name, arm2.base.xyz, arm2.base.rpy
    )
    model = PairDistanceModel(config)
    generator = torch.Generator().manual_seed(seed)
    linears = [m for m in model.mlp if isinstance(m, torch.nn.Linear)]
    with torch.no_grad():
        for layer in linears:
            layer.weight.normal_(0.0, 0.01, generator=generator)
            layer.bias.zero_()
        first = linears[0]
        first.weight[0].zero_()
        first.weight[0, -1] = 1.0  # the last feature: softmin with the largest beta
        first.bias[0] = _LINEAR_OFFSET
        for layer in linears[1:-1]:
            layer.weight[0].zero_()
            layer.weight[0, 0] = 1.0
        last = linears[-1]
        last.weight.zero_()
        last.weight[0, 0] = 1.0
        last.bias[0] = -_LINEAR_OFFSET - radius
    return model.eval()


def planning_distance_model(pair: str) -> tuple[PairDistanceModel, str]:
    """``(model, source)``: the shipped distance of ``pair`` (``"shipped"``) or the proxy."""
    try:
        return load_distance_model(pair), "shipped"
    except ModelFileError:
        return proxy_distance_model(pair), "proxy"


def _train_region(n1: int, sign: float, offset: float) -> JointInterval:
    """Half of arm 2's first joint range that the mirror map sends onto the other half."""
    if math.isclose(abs(offset), math.pi) and sign < 0:
        return JointInterval(n1, -math.pi / 2, math.pi / 2)  # q → π − q
    return JointInterval(n1, 0.0, math.pi)  # q → −q


def arm_pair_system(pair: str, distance: PairDistanceModel | None = None) -> ArmPairSystem:
    """The HJI system of a named pair, ``ū = d̄ = 0.5`` rad/s, ``T = 0.6`` s."""
    model = distance if distance is not None else planning_distance_model(pair)[0]
    cell, a, b = pair_cell(pair)
    mirror = robot_mirror_map(cell.arm(a).robot.name) + robot_mirror_map(cell.arm(b).robot.name)
    n1 = cell.arm(a).robot.dof
    return ArmPairSystem(
        boundary_fn=model,
        n1=n1,
        n2=cell.arm(b).robot.dof,
        symmetry_sign=np.array(mirror.sign),
        symmetry_offset=np.array(mirror.offset),
        train_region=_train_region(n1, mirror.sign[n1], mirror.offset[n1]),
        system_name=f"{pair}_pair",
        joint_periodic=mirror.periodic,
    )


def random_value_function(
    pair: str,
    variant: str,
    settings: NetworkSettings | None = None,
    residual_scale: float = 0.05,
    seed: int = 0,
    distance: PairDistanceModel | None = None,
) -> ValueFunction:
    """A float64 value function with random SIREN weights (output layer × ``residual_scale``)."""
    system = arm_pair_system(pair, distance)
    generator = torch.Generator().manual_seed(seed)
    network = ValueNetwork(system, variant, settings, generator)
    with torch.no_grad():
        network.siren.output.weight.mul_(residual_scale)
        network.siren.output.bias.mul_(residual_scale)
    return ValueFunction(network.double())
