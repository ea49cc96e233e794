"""The SQP's QP subproblem: one small dense QP solved exactly by DAQP.

Shared by the SQP (:mod:`.sqp`), the native loop's self-check (:mod:`.native`), the fail-safe
(:mod:`.fail_safe`) and the self-clearance projection (:mod:`.self_clearance`); it imports no
other planning module, so none of them import each other through it.
"""

from __future__ import annotations

from dataclasses import dataclass

import daqp
import numpy as np

__all__ = ["QPStep", "qp_step"]


@dataclass(frozen=True)
class QPStep:
    """The SQP's QP subproblem answer: step ``p``, multipliers of ``c + Jp ≥ 0``, DAQP's flag."""

    p: np.ndarray
    lam: np.ndarray  # ≥ 0, one per linearized constraint
    flag: int  # DAQP exit flag: 1 optimal, -1 infeasible, other < 0 solver trouble

    @property
    def feasible(self) -> bool:
        return self.flag >= 1


def qp_step(
    B: np.ndarray, grad: np.ndarray, c: np.ndarray, J: np.ndarray, lo: np.ndarray, hi: np.ndarray
) -> QPStep:
    """``min ½pᵀBp + gradᵀp s.t. c + Jp ≥ 0, lo ≤ p ≤ hi`` by DAQP's dual active-set method.

    DAQP solves small dense QPs exactly (up to rounding) and treats the step box as simple
    bounds. ``B`` must be positive definite; the SQP keeps it so by damped BFGS.
    """
    n, m = len(grad), len(c)
    upper = np.empty(n + m)
    lower = np.empty(n + m)
    upper[:n], upper[n:] = hi, np.inf
    lower[:n], lower[n:] = lo, -c
    p, _, flag, info = daqp.solve(B, grad, J, upper, lower)
    # DAQP's multipliers satisfy Bp + grad + [I; J]ᵀ lam = 0 with lam ≤ 0 on active lower bounds
    lam = np.maximum(0.0, -np.asarray(info["lam"], dtype=np.float64)[n:])
    return QPStep(np.asarray(p, dtype=np.float64), lam, int(flag))
