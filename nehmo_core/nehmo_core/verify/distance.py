"""False-safe rates of a learned distance on a stated distribution, with their binomial bound.

A configuration is *false-safe* when the learned distance calls it clear (``> 0``) while the
exact geometry is in contact (``≤ 0``). The rate is taken over the colliding configurations
(the convention of the distance models' own cards); its upper bound at confidence ``1 − β``
uses :func:`~nehmo_core.verify.bound.violation_bound`. Besides the planner's visited pair
states (which rarely touch), the states near them — each joint perturbed by Gaussian noise —
put the learned distance to the test where the planner operates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.distance_model import PairDistanceModel
from nehmo_core.robots.model import wrap_angle
from nehmo_core.verify.bound import violation_bound
from nehmo_core.verify.truth import ExactMargin


@dataclass(frozen=True)
class FalseSafe:
    """False-safe count over a sample: ``false_safe`` of ``colliding`` states."""

    distribution: str
    states: int
    colliding: int
    false_safe: int
    rate: float  # false_safe / colliding (nan without colliding states)
    bound: float  # upper bound on the rate at confidence 1 - beta (1 without colliding states)
    beta: float
    mean_abs_error_near_m: float  # |learned - exact| over states with exact < 0.1 m

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def jittered(states: np.ndarray, sigma: float, rng: np.random.Generator) -> np.ndarray:
    """Each state with every joint moved by ``N(0, sigma²)`` [rad], wrapped to ``(−π, π]``."""
    if not sigma > 0:
        raise InvalidValueError("sigma", "must be > 0 [rad]", sigma)
    return np.asarray(wrap_angle(states + rng.normal(0.0, sigma, states.shape)))


def false_safe(
    model: PairDistanceModel,
    margin: ExactMargin,
    states: np.ndarray,
    distribution: str,
    beta: float = 1e-3,
) -> FalseSafe:
    """The false-safe rate of ``model`` over ``states (N, n)`` against the exact ``margin``."""
    learned = model.distance(states)
    exact = margin(states, 1.0)
    colliding = exact <= 0.0
    k = int((colliding & (learned > 0.0)).sum())
    n = int(colliding.sum())
    near = exact < 0.1
    return FalseSafe(
        distribution=distribution,
        states=int(states.shape[0]),
        colliding=n,
        false_safe=k,
        rate=k / n if n else float("nan"),
        bound=violation_bound(n, k, beta) if n else 1.0,
        beta=beta,
        mean_abs_error_near_m=float(np.abs(learned - exact)[near].mean())
        if near.any()
        else float("nan"),
    )
