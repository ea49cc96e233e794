"""The scenario-optimization bound on a violation probability (binomial tail, Clopper-Pearson).

``N`` states are drawn i.i.d. from a distribution and ``k`` of them violate. With confidence
``1 − β`` the true violation probability is at most the ``ε`` that solves
``P[Binomial(N, ε) ≤ k] = β`` — the one-sided Clopper-Pearson upper limit, which is what split
conformal prediction and scenario optimization give for a fixed level set (Lin & Bansal). For
``k = 0`` it is ``1 − β^(1/N)``: 3000 samples at ``β = 1e-3`` bound it by 0.23 %.
"""

from __future__ import annotations

from scipy.stats import beta as beta_distribution

from nehmo_core.errors import InvalidValueError


def _check(samples: int, violations: int, confidence_beta: float) -> None:
    if samples < 1:
        raise InvalidValueError("samples", "must be >= 1", samples)
    if not 0 <= violations <= samples:
        raise InvalidValueError("violations", f"must lie in [0, samples = {samples}]", violations)
    if not 0.0 < confidence_beta < 1.0:
        raise InvalidValueError("beta", "must lie in (0, 1)", confidence_beta)


def violation_bound(samples: int, violations: int, beta: float) -> float:
    """Upper bound on the violation probability at confidence ``1 − beta``."""
    _check(samples, violations, beta)
    if violations == samples:
        return 1.0
    return float(beta_distribution.ppf(1.0 - beta, violations + 1, samples - violations))


def max_violations(samples: int, alpha: float, beta: float) -> int:
    """The most violations among ``samples`` that still certify ``alpha`` (−1 if none do)."""
    _check(samples, 0, beta)
    if not 0.0 < alpha < 1.0:
        raise InvalidValueError("alpha", "must lie in (0, 1)", alpha)
    k = -1
    while k + 1 <= samples and violation_bound(samples, k + 1, beta) <= alpha:
        k += 1
    return k
