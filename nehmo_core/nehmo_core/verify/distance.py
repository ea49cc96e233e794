"""False-safe rates of a learned distance on a stated distribution, with their binomial bound.

A configuration is *false-safe* when the learned distance calls it clear (``> 0``) while the
exact geometry is in contact (``≤ 0``). The rate is taken over the colliding configurations
(the convention of the distance models' own cards); its upper bound at confidence ``1 − β``
uses :func:`~nehmo_core.verify.bound.violation_bound`. Besides the planner's visited pair
states (which rarely touch), the states near them — each joint perturbed by Gaussian noise —
put the learned distance to the test where the planner operates.

A *certificate* (:func:`certify_distance`) turns this around: over ``N`` i.i.d. contact states of
a distribution it finds the smallest level ``c`` such that the share of contacts the learned
distance places above ``c`` is at most ``α`` with confidence ``1 − β`` (the same binomial bound
as the value-function certificates). A planner whose margin is at least ``c`` keeps that promise.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.geometry.distance_model import PairDistanceModel
from nehmo_core.robots.model import wrap_angle
from nehmo_core.verify.bound import max_violations, violation_bound
from nehmo_core.verify.distributions import StateDistribution, VisitedStates
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


def jittered(
    states: np.ndarray, sigma: float | np.ndarray, rng: np.random.Generator, joints: int = 0
) -> np.ndarray:
    """Each state with every joint moved by ``N(0, sigma²)`` [rad], wrapped to ``(−π, π]``.

    ``joints`` > 0 moves only the first ``joints`` columns (the rest are conditions such as a
    base distance); ``sigma`` may be one value or one per state ``(N, 1)``.
    """
    if not np.all(np.asarray(sigma) > 0):
        raise InvalidValueError("sigma", "must be > 0 [rad]", sigma)
    n = joints or states.shape[1]
    out = np.array(states, dtype=np.float64)
    noise = rng.normal(0.0, 1.0, (states.shape[0], n)) * sigma
    out[:, :n] = wrap_angle(out[:, :n] + noise)
    return out


@dataclass(frozen=True)
class NearVisited:
    """Visited pair states with every joint moved by ``N(0, σ²)``, ``σ ~ U[low, high]`` per state.

    Conditions (the base distance of a conditioned pair) are kept; this is where the planner
    operates, pushed toward the contacts it avoids.
    """

    visited: VisitedStates
    joints: int
    low: float = 0.1
    high: float = 0.5

    def describe(self) -> dict[str, Any]:
        return {
            "name": "near_visited",
            "what": f"visited pair states, joints + N(0, σ²), σ ~ U[{self.low}, {self.high}] rad",
            "pool_size": int(self.visited.states.shape[0]),
        }

    def draw(self, count: int, rng: np.random.Generator) -> np.ndarray:
        sigma = rng.uniform(self.low, self.high, (count, 1))
        return jittered(self.visited.draw(count, rng), sigma, rng, self.joints)


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


@dataclass(frozen=True)
class DistanceCertificate:
    """The smallest level ``c`` at which the learned distance is certified on a distribution.

    Over ``colliding`` i.i.d. contact states, ``false_safe`` have a learned distance above
    ``level_m``; with confidence ``1 − beta`` the probability that a contact state reads above
    ``level_m`` is at most ``bound`` (≤ ``alpha`` when ``certified``). A planner whose margin is
    at least ``level_m`` therefore never calls a certified-unsafe contact clear.
    """

    distribution: str
    states: int  # drawn in all
    colliding: int  # N: the contact states the certificate is taken over
    level_m: float
    false_safe: int
    bound: float
    alpha: float
    beta: float
    false_safe_at_zero: int  # contact states the learned distance calls clear (> 0)
    certified: bool

    def to_dict(self) -> dict[str, Any]:
        return dict(self.__dict__)


def certified_level(learned_on_contacts: np.ndarray, alpha: float, beta: float) -> float:
    """The smallest level ``c ≥ 0`` with ``#(learned > c)`` within the count certifying ``alpha``.

    ``learned_on_contacts`` is the learned distance on i.i.d. contact states; ``inf`` when no
    count certifies ``alpha`` at that sample size.
    """
    values = np.sort(np.asarray(learned_on_contacts, dtype=np.float64))[::-1]
    k = max_violations(values.size, alpha, beta)
    if k < 0:
        return float("inf")
    if k >= values.size:
        return 0.0
    return max(0.0, float(values[k]))


def contact_states(
    distribution: StateDistribution,
    margin: ExactMargin,
    count: int,
    rng: np.random.Generator,
    batch: int = 20000,
    max_draws: int = 2_000_000,
    progress: bool = False,
) -> tuple[np.ndarray, int]:
    """``count`` i.i.d. states of ``distribution`` restricted to exact contact, by rejection.

    Returns the states and how many were drawn in all. A margin with a ``lower_bound`` (the arm
    pairs' ball covers, :meth:`~nehmo_core.verify.truth.PairDistance.lower_bound`) has the exact
    geometry queried only where that bound allows contact; the states kept are the same, found
    faster where contacts are rare.
    """
    prefilter = getattr(margin, "lower_bound", None)
    kept: list[np.ndarray] = []
    have = drawn = 0
    bar = tqdm(total=count, desc="contact states", unit="state", disable=not progress)
    while have < count:
        if drawn >= max_draws:
            bar.close()
            raise NehmoError(
                f"only {have} of {drawn} drawn states are in contact; need count = {count}"
            )
        x = distribution.draw(batch, rng)
        drawn += x.shape[0]
        if prefilter is not None:
            x = x[prefilter(x) <= 0.0]
        hit = x[margin(x, 1e-3) <= 0.0] if x.shape[0] else x
        kept.append(hit)
        have += hit.shape[0]
        bar.update(min(hit.shape[0], count - bar.n))
        bar.set_postfix(drawn=drawn)
    bar.close()
    return np.concatenate(kept)[:count], drawn


def certify_distance(
    model: PairDistanceModel,
    margin: ExactMargin,
    distribution: StateDistribution,
    rng: np.random.Generator,
    samples: int = 3000,
    alpha: float = 0.01,
    beta: float = 1e-3,
    max_draws: int = 4_000_000,
    progress: bool = False,
) -> DistanceCertificate:
    """Certify ``model`` on ``samples`` contact states of ``distribution`` (see
    :class:`DistanceCertificate`)."""
    if samples < 1:
        raise InvalidValueError("samples", "must be >= 1", samples)
    states, drawn = contact_states(
        distribution, margin, samples, rng, max_draws=max_draws, progress=progress
    )
    learned = np.asarray(model.distance(states), dtype=np.float64)
    level = certified_level(learned, alpha, beta)
    k = int((learned > level).sum()) if np.isfinite(level) else samples
    return DistanceCertificate(
        distribution=str(distribution.describe()["name"]),
        states=drawn,
        colliding=samples,
        level_m=level,
        false_safe=k,
        bound=violation_bound(samples, k, beta),
        alpha=alpha,
        beta=beta,
        false_safe_at_zero=int((learned > 0.0).sum()),
        certified=bool(np.isfinite(level)),
    )
