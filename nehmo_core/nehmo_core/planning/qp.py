"""A tiny exact QP: projection onto a polytope, by the dual active-set method.

``project(w0, N, h)`` solves ``min ½‖w − w0‖²  s.t.  N w ≥ h`` (rows of ``N`` are constraint
normals) with the Goldfarb-Idnani dual method specialised to an identity Hessian: start at the
unconstrained minimum ``w0``, add the most violated constraint, and move primal and dual
variables along the directions given by the active normals (dropping a constraint whose
multiplier would turn negative) until it is satisfied. Each iteration is exact linear algebra on
the handful of active normals, so the result is exact up to rounding. A general positive
definite Hessian ``B = L Lᵀ`` is handled by the caller through ``w = Lᵀ p``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["QPResult", "project"]

_TINY = 1e-14


@dataclass(frozen=True)
class QPResult:
    """``w`` (n,), multipliers ``lam`` (m,) ≥ 0 (zero off the active set), ``feasible``."""

    w: np.ndarray
    lam: np.ndarray
    feasible: bool
    iterations: int


def _directions(N: np.ndarray, active: list[int], normal: np.ndarray) -> tuple[np.ndarray, ...]:
    """Primal step ``z`` (``normal`` projected off the active normals) and dual step ``r``."""
    if not active:
        return normal.copy(), np.zeros(0)
    A = N[active]  # (k, n)
    try:
        r = np.linalg.solve(A @ A.T, A @ normal)
    except np.linalg.LinAlgError:  # numerically dependent normals: least-squares multipliers
        r = np.linalg.lstsq(A.T, normal, rcond=None)[0]
    return normal - A.T @ r, r


def project(
    w0: np.ndarray, N: np.ndarray, h: np.ndarray, tol: float = 1e-12, max_iter: int = 100
) -> QPResult:
    """Solve ``min ½‖w − w0‖² s.t. N w ≥ h``; ``feasible`` is False if no point satisfies it."""
    m = N.shape[0]
    w = np.array(w0, dtype=np.float64)
    lam = np.zeros(m)
    active: list[int] = []
    scale = np.maximum(np.linalg.norm(N, axis=1), _TINY)
    for iteration in range(max_iter):
        slack = (N @ w - h) / scale
        slack[active] = np.inf
        p = int(np.argmin(slack))
        if slack[p] >= -tol:
            return QPResult(w, lam, True, iteration)
        while True:  # add p, dropping constraints whose multipliers reach zero on the way
            z, r = _directions(N, active, N[p])
            zn = float(z @ N[p])
            full = (h[p] - N[p] @ w) / zn if zn > _TINY * scale[p] ** 2 else np.inf
            partial, drop = np.inf, -1
            for j, rj in enumerate(r):
                if rj > _TINY and lam[active[j]] / rj < partial:
                    partial, drop = lam[active[j]] / rj, j
            step = min(full, partial)
            if not np.isfinite(step):
                return QPResult(w, lam, False, iteration)
            if np.isfinite(full):
                w = w + step * z
            for j, rj in enumerate(r):
                lam[active[j]] -= step * rj
            lam[p] += step
            if full <= partial:
                active.append(p)
                break
            lam[active[drop]] = 0.0
            active.pop(drop)
    return QPResult(w, lam, False, max_iter)
