"""The QP step of the SQP (``numerics.qp``): KKT conditions at its answer, infeasibility."""

from __future__ import annotations

import numpy as np

from nehmo_core.planning.numerics.qp import qp_step


def test_qp_step_meets_kkt_conditions() -> None:
    rng = np.random.default_rng(2)
    solved = 0
    for _ in range(300):
        n, m = 6, int(rng.integers(1, 5))
        M = rng.normal(size=(n, n))
        B = 2.0 * np.eye(n) + 0.1 * M @ M.T
        grad, J = rng.normal(size=n) * 0.1, rng.normal(size=(m, n))
        c = rng.normal(size=m) * 0.02
        y = rng.uniform(-0.05, 0.05, n)
        lo, hi = -0.05 - y, 0.05 - y
        r = qp_step(B, grad, c, J, lo, hi)
        if not r.feasible:
            continue
        solved += 1
        p, lam = r.p, r.lam
        assert np.all(c + J @ p >= -1e-9) and np.all(p >= lo - 1e-12) and np.all(p <= hi + 1e-12)
        assert np.all(lam >= 0.0)
        np.testing.assert_allclose(lam * (c + J @ p), 0.0, atol=1e-9)
        # stationarity up to the bound multipliers: free coordinates have zero reduced gradient
        reduced = B @ p + grad - J.T @ lam
        free = (p > lo + 1e-9) & (p < hi - 1e-9)
        np.testing.assert_allclose(reduced[free], 0.0, atol=1e-8)
        assert np.all(reduced[p <= lo + 1e-9] >= -1e-8)  # at a lower bound: pushing down
        assert np.all(reduced[p >= hi - 1e-9] <= 1e-8)
    assert solved > 250


def test_qp_step_reports_infeasibility() -> None:
    # p1 ≥ 1 from the linearization, p1 ≤ 0.5 from the box
    r = qp_step(
        2.0 * np.eye(2),
        np.zeros(2),
        np.array([-1.0]),
        np.array([[1.0, 0.0]]),
        np.full(2, -0.5),
        np.full(2, 0.5),
    )
    assert r.flag == -1 and not r.feasible
