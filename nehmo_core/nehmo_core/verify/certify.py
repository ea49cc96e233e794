"""Certify a value function's level set: search δ, then bound the violation rate on fresh states.

Procedure (scenario optimization ≡ split conformal prediction, Lin & Bansal):

1. **Search.** Draw ``search_samples`` states of the distribution with ``V(τ, x) ≥ 0``, roll each
   out against every adversary (:mod:`~nehmo_core.verify.rollout`) and bisect ``δ ∈ [0,
   delta_max]`` for the smallest level whose own states (``V ≥ δ``) promise to pass: at most
   ``alpha / 3`` of them violate (the certificate then has room for its own sampling noise).
2. **Certify.** Draw ``samples`` *fresh* states with ``V(τ, x) ≥ δ`` and count the violations
   ``k``; the certificate is the upper bound on the violation probability at confidence
   ``1 − beta/attempts``. If it exceeds ``alpha``, raise ``δ`` by ``delta_step`` and certify
   again on fresh states, at most ``attempts`` times (the split of ``beta`` keeps the overall
   confidence at ``1 − beta`` whichever attempt passes).

The search states never enter the certificate, so choosing ``δ`` from them costs no confidence.
"""

from __future__ import annotations

import itertools
import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
from tqdm import tqdm

from nehmo_core.errors import InvalidValueError
from nehmo_core.sim.actuators import ActuatorModel
from nehmo_core.verify.adversaries import (
    DEFAULT_ADVERSARIES,
    check_adversaries,
    make_adversaries,
)
from nehmo_core.verify.bound import violation_bound
from nehmo_core.verify.distributions import StateDistribution, draw_level_set
from nehmo_core.verify.rollout import ValueModel, rollout_worst
from nehmo_core.verify.truth import ExactMargin

BANDS = (0.0, 0.05, 0.1, 0.2, float("inf"))
"""Value bands [m] in which the search pool's violation rates are reported."""


@dataclass(frozen=True)
class VerifySettings:
    """What a certificate claims and how it is earned."""

    tau: float  # time-to-go of the level set [s]
    alpha: float = 0.01  # target violation probability
    beta: float = 1e-3  # 1 - confidence
    samples: int = 3000  # N of the certificate
    search_samples: int = 500
    delta_max: float = 0.3  # [m]
    delta_step: float = 0.01  # [m], the raise after a failed attempt
    attempts: int = 3
    bisection_steps: int = 12
    dt: float = 0.01  # rollout step [s]
    adversaries: tuple[str, ...] = DEFAULT_ADVERSARIES
    seed: int = 0
    chunk: int = 250  # states per rollout batch
    # how the controlled arm follows its control in the rollouts (None: ideal, q̇ = u)
    actuator: ActuatorModel | None = None

    def __post_init__(self) -> None:
        positive = ("tau", "dt", "delta_max", "delta_step")
        for name in positive:
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        for name in ("alpha", "beta"):
            if not 0 < getattr(self, name) < 1:
                raise InvalidValueError(name, "must lie in (0, 1)", getattr(self, name))
        for name in ("samples", "search_samples", "attempts", "bisection_steps", "chunk"):
            if not getattr(self, name) >= 1:
                raise InvalidValueError(name, "must be >= 1", getattr(self, name))
        check_adversaries(self.adversaries)
        if violation_bound(self.samples, 0, self.beta / self.attempts) > self.alpha:
            need = math.ceil(math.log(self.beta / self.attempts) / math.log(1.0 - self.alpha))
            raise InvalidValueError(
                "samples", f"must be >= {need} to certify alpha = {self.alpha} at all", self.samples
            )


@dataclass
class Certificate:
    """The outcome of :func:`certify`, JSON-ready through :meth:`to_dict`."""

    system: str
    model: str
    tau: float
    distribution: dict[str, Any]
    settings: dict[str, Any]
    delta: float  # [m], the certified level
    samples: int
    violations: int
    epsilon: float  # upper bound on the violation probability
    confidence: float  # 1 - beta
    certified: bool  # epsilon <= alpha
    accepted_share: float  # share of the distribution with V(tau) >= delta
    search: dict[str, Any] = field(default_factory=dict)
    attempts: list[dict[str, Any]] = field(default_factory=list)
    wall_time_s: float = 0.0
    command: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class RemoteRollouts:
    """Rollouts as tasks of an executor (a Ray cluster): each chunk of states is rolled out by
    a worker that loads the value function ``model`` (``variant``) and the exact margin itself.
    The adversaries' random draws are the ones a local run makes, so results are identical."""

    executor: Any  # concurrent.futures.Executor
    model: str
    variant: str | None = None


_WORKER: dict[tuple[str, str | None], tuple[Any, ExactMargin]] = {}


def _chunk_margins(
    model: str,
    variant: str | None,
    chunk: np.ndarray,
    settings: VerifySettings,
    rng_state: dict[str, Any],
    noise_seed: int = 0,
) -> tuple[np.ndarray, list[str]]:
    """One chunk's worst margins on a worker (the value function and margin kept between
    chunks); ``rng_state`` is the driver's generator where this chunk's adversaries are drawn."""
    if (model, variant) not in _WORKER:
        from nehmo_core.hjr import load_value_function
        from nehmo_core.verify.truth import exact_margin

        value = load_value_function(model, variant=variant)
        _WORKER[(model, variant)] = (value, exact_margin(value.system))
    value, margin = _WORKER[(model, variant)]
    rng = np.random.default_rng()
    rng.bit_generator.state = rng_state
    adv = make_adversaries(value.system, settings.adversaries, chunk.shape[0], settings.dt, rng)
    return _rollouts(value, margin, chunk, settings, adv, noise_seed)


def _rollouts(
    value: ValueModel,
    margin: ExactMargin,
    chunk: np.ndarray,
    s: VerifySettings,
    adversaries: list[Any],
    noise_seed: int,
) -> tuple[np.ndarray, list[str]]:
    seed = s.seed * 1_000_003 + noise_seed  # a noise stream per run and chunk
    return rollout_worst(
        value, margin, chunk, s.tau, adversaries, s.dt, actuator=s.actuator, noise_seed=seed
    )


def worst_margins(
    value: ValueModel,
    margin: ExactMargin,
    x: np.ndarray,
    settings: VerifySettings,
    rng: np.random.Generator,
    label: str,
    remote: RemoteRollouts | None = None,
) -> tuple[np.ndarray, list[str]]:
    """The smallest exact margin [m] of each state's rollouts over ``settings.tau`` against
    every adversary, and the adversary that reached it (a contact when ``≤ 0``); on
    ``remote``'s workers when given, with the same result."""
    margins: list[np.ndarray] = []
    names: list[str] = []
    starts = range(0, x.shape[0], settings.chunk)
    if remote is not None:
        futures = []
        for i in starts:
            chunk = x[i : i + settings.chunk]
            state = rng.bit_generator.state
            # draw this chunk's adversaries here too, so the generator moves on as locally
            make_adversaries(value.system, settings.adversaries, chunk.shape[0], settings.dt, rng)
            futures.append(
                remote.executor.submit(
                    _chunk_margins, remote.model, remote.variant, chunk, settings, state, i
                )
            )
        for future in tqdm(futures, desc=label, unit="batch", leave=False):
            m, who = future.result()
            margins.append(m)
            names.extend(who)
        return np.concatenate(margins), names
    for i in tqdm(starts, desc=label, unit="batch", leave=False):
        chunk = x[i : i + settings.chunk]
        adv = make_adversaries(value.system, settings.adversaries, chunk.shape[0], settings.dt, rng)
        m, who = _rollouts(value, margin, chunk, settings, adv, i)
        margins.append(m)
        names.extend(who)
    return np.concatenate(margins), names


SEARCH_SHARE = 1.0 / 3.0  # the search asks for at most this share of alpha


def _meets(values: np.ndarray, violated: np.ndarray, delta: float, s: VerifySettings) -> bool:
    inside = values >= delta
    n = int(inside.sum())
    k = int((violated & inside).sum())
    return k <= SEARCH_SHARE * s.alpha * n  # an empty level set meets it vacuously


def search_delta(values: np.ndarray, violated: np.ndarray, settings: VerifySettings) -> float:
    """Bisect for the smallest ``δ ∈ [0, delta_max]`` whose pool states meet the target."""
    if _meets(values, violated, 0.0, settings):
        return 0.0
    lo, hi = 0.0, settings.delta_max
    if not _meets(values, violated, hi, settings):
        return hi
    for _ in range(settings.bisection_steps):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if _meets(values, violated, mid, settings) else (mid, hi)
    return hi


def band_rates(values: np.ndarray, violated: np.ndarray) -> list[dict[str, Any]]:
    """Violation counts of the search pool per value band (descriptive, not a certificate)."""
    out = []
    for lo, hi in itertools.pairwise(BANDS):
        inside = (values >= lo) & (values < hi)
        n = int(inside.sum())
        k = int((violated & inside).sum())
        out.append({"band": [lo, hi if np.isfinite(hi) else None], "states": n, "violations": k})
    return out


def certify(
    value: ValueModel,
    margin: ExactMargin,
    distribution: StateDistribution,
    settings: VerifySettings,
    model: str = "",
    remote: RemoteRollouts | None = None,
) -> Certificate:
    """Search ``δ`` and certify ``{V(τ, ·) ≥ δ}`` (module docstring); seeded, so repeatable
    (the rollouts on ``remote``'s workers when given, with the same result)."""
    start = time.perf_counter()
    rng = np.random.default_rng(settings.seed)
    s = settings
    x, v, _ = draw_level_set(value, distribution, s.tau, 0.0, s.search_samples, rng)
    m, _ = worst_margins(value, margin, x, s, rng, "search", remote)
    violated = m <= 0.0
    delta = search_delta(v, violated, s)
    search = {
        "states": int(x.shape[0]),
        "violations_at_0": int(violated.sum()),
        "delta": delta,
        "bands": band_rates(v, violated),
    }
    attempts: list[dict[str, Any]] = []
    beta_each = s.beta / s.attempts
    for a in range(s.attempts):
        level = delta + a * s.delta_step
        xc, _, share = draw_level_set(value, distribution, s.tau, level, s.samples, rng)
        mc, who = worst_margins(value, margin, xc, s, rng, f"certify δ={level:.3f}", remote)
        bad = mc <= 0.0
        k = int(bad.sum())
        eps = violation_bound(s.samples, k, beta_each)
        by = sorted({n for n, b in zip(who, bad, strict=True) if b})
        attempts.append(
            {"delta": level, "violations": k, "epsilon": eps, "accepted_share": share, "by": by}
        )
        if eps <= s.alpha:
            break
    last = attempts[-1]
    return Certificate(
        system=value.system.name,
        model=model,
        tau=s.tau,
        distribution=distribution.describe(),
        settings={**asdict(s), "adversaries": list(s.adversaries)},
        delta=last["delta"],
        samples=s.samples,
        violations=last["violations"],
        epsilon=last["epsilon"],
        confidence=1.0 - s.beta,
        certified=last["epsilon"] <= s.alpha,
        accepted_share=last["accepted_share"],
        search=search,
        attempts=attempts,
        wall_time_s=time.perf_counter() - start,
    )
