"""The fail-safe against several critical peers at once.

A fallback stage (settings group ``fail_safe``, ``kind = "maximin"``; ``"single"``, the ``paper``
preset, keeps the paper's fail-safe). It changes
only the command applied when Opt fails; with one constrained peer it is the paper's.

The paper's fail-safe ``ū·sign(∂V/∂q¹)`` follows one pair, the most critical. An arm between two
peers whose values are close then switches between two opposite commands from one tick to the
next and can be pushed into either peer. The *maximin* fail-safe takes every peer whose value is
within ``band`` of the smallest and maximizes the smallest value predicted ``τ`` ahead under the
worst-case peer motion:

    max_{u, s} s   s.t.   V_i + τ·(g_iᵀu − d̄·‖h_i‖₁) ≥ s  for every critical peer i,  |u_j| ≤ ū,

with ``g_i = ∂V_i/∂q_own`` and ``h_i = ∂V_i/∂q_peer`` (the peer's worst case ``−d̄·sign(h_i)``
lowers V's rate by ``d̄‖h_i‖₁``, whatever the arm does). Maximizing the smallest *rate* instead
(the same problem without ``V_i``) spent the whole command on a peer with slack: in five-UR5
episodes it let a pair at V = 0.11 m close to contact while serving one at 0.15 m. With one
critical peer the answer is the paper's command. A small quadratic term on ``u`` (``ridge``)
makes the solution unique: joints that do not change any critical V stay still instead of
sweeping at full speed.

Plain maximin is brittle when the arm can barely move the worst pair's value: in two five-UR5
collisions (fresh seeds 34 and 35) the worst pair's peer could lower V at 0.4–0.65 m/s while the
arm could raise it by at most 0.01–0.08 m/s, and maximin spent every joint on that pair, gaining
2–4 mm of predicted V and driving the arm at 0.4 m/s into the other critical peer. So the command
is *lexicographic* with a tolerance (``slack``): after each stage fixes the pairs that bind at the
best smallest value ``s*``, later stages may lower those pairs to ``s* − slack`` but no further,
and maximize the smallest value of the remaining pairs. ``slack = 0`` stops after the first
stage: plain maximin.
Peers join the critical set within ``band`` of the smallest value and leave it only beyond
``2·band``, so a command does not flip when two values cross (:class:`MaximinFailSafe`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.numerics.qp import qp_step
from nehmo_core.planning.opt.fail_safe import HjiFailSafe
from nehmo_core.planning.opt.pipeline import Host
from nehmo_core.planning.opt.tick import PeerValues

__all__ = ["MaximinFailSafe", "MaximinFallback", "maximin_command", "worst_case_rates"]


def worst_case_rates(
    u: np.ndarray, own_grads: np.ndarray, peer_grads: np.ndarray, d_max: float | np.ndarray
) -> np.ndarray:
    """Rate of change of each pair's V [m/s] under command ``u`` and the peers' worst case."""
    return own_grads @ u - d_max * np.abs(peer_grads).sum(axis=1)


def maximin_command(
    own_grads: np.ndarray,
    peer_grads: np.ndarray,
    u_max: float,
    d_max: float | np.ndarray,
    values: np.ndarray | None = None,
    horizon: float = 0.1,
    slack: float = 0.0,
    harm: float | None = None,
    ridge: float = 1e-3,
) -> np.ndarray:
    """The box-bounded command maximizing the smallest worst-case value ``horizon`` [s] ahead,
    then (lexicographically, within ``slack`` [m] of each stage's optimum) the next smallest.

    ``own_grads`` (k, n) and ``peer_grads`` (k, m) are the pairs' gradients of V, ``values``
    (k,) their values now (None: all equal, i.e. the smallest worst-case rate); ``d_max`` the
    peers' speed bound, one for all or one per pair (k,). ``harm`` [m/s] (None: no limit)
    bounds how fast the arm's own motion may lower any pair's V: ``g_i·u ≥ −harm`` for every
    pair (``u = 0`` meets it, so the problem stays feasible). With one pair it is ``ū·sign(g)``
    (joints with a zero gradient stay still).
    """
    own_grads = np.atleast_2d(np.asarray(own_grads, dtype=np.float64))
    peer_grads = np.atleast_2d(np.asarray(peer_grads, dtype=np.float64))
    k, n = own_grads.shape
    if k == 1:
        return u_max * np.sign(own_grads[0])
    if not slack >= 0.0:
        raise InvalidValueError("slack", "must be >= 0 [m]", slack)
    if harm is not None and not harm >= 0.0:
        raise InvalidValueError("harm", "must be >= 0 [m/s] or None", harm)
    # predicted V_i = V_i + τ·(g_i·u − d̄‖h_i‖₁) = τ·(g_i·u − offset_i)
    offset = d_max * np.abs(peer_grads).sum(axis=1)
    if values is not None:
        offset = offset - np.asarray(values, dtype=np.float64) / horizon
    scale = float(np.abs(own_grads).max()) or 1.0  # the problem in units of the largest gradient
    g, offset = own_grads / scale, offset / scale  # rows: g_i·u − offset_i ≥ s (scaled rate)
    limit = None if harm is None else harm / scale  # every pair: g_i·u ≥ −limit
    floor = np.full(k, np.nan)  # fixed pairs: g_i·u − offset_i ≥ floor_i
    free = np.ones(k, dtype=bool)
    u = np.zeros(n)
    while free.any():
        stage, s = _maximin_stage(g, offset, free, floor, u_max, ridge, limit)
        if stage is None:  # cannot happen for this QP (the last stage's u is feasible); be safe
            worst = int(np.argmax(np.where(free, offset, -np.inf)))
            return u_max * np.sign(own_grads[worst])
        u = stage
        rate = g @ u - offset
        binding = free & (rate <= s + 1e-6 * max(1.0, abs(s)))
        if not binding.any():
            binding = free & (rate <= rate[free].min())
        floor[binding] = s - slack / (horizon * scale)
        free &= ~binding
        if slack == 0.0:
            break  # plain maximin: the first stage's command
    return np.clip(u, -u_max, u_max)


def _maximin_stage(
    g: np.ndarray,
    offset: np.ndarray,
    free: np.ndarray,
    floor: np.ndarray,
    u_max: float,
    ridge: float,
    limit: float | None = None,
) -> tuple[np.ndarray | None, float]:
    """max s over (u, s): free rows g_i·u − offset_i ≥ s, fixed rows ≥ floor_i, |u| ≤ ū, and
    (``limit`` given) every row g_i·u ≥ −limit."""
    n = g.shape[1]
    fixed = ~free
    bound = float(np.abs(g).sum(axis=1).max()) * u_max + float(np.abs(offset).max()) + 1.0
    # variables p = (u, s): min −s + ½·ridge·(‖u‖² + s²)
    hessian = ridge * np.eye(n + 1)
    linear = np.zeros(n + 1)
    linear[n] = -1.0
    jac = np.hstack([g, -free[:, None].astype(np.float64)])
    c = -offset - np.where(fixed, floor, 0.0)
    if limit is not None:
        jac = np.vstack([jac, np.hstack([g, np.zeros((len(g), 1))])])
        c = np.concatenate([c, np.full(len(g), limit)])
    lo = np.concatenate([np.full(n, -u_max), [-bound]])
    hi = np.concatenate([np.full(n, u_max), [bound]])
    step = qp_step(hessian, linear, c, jac, lo, hi)
    if step.flag < 1 or not np.all(np.isfinite(step.p)):
        return None, math.nan
    return step.p[:n], float(step.p[n])


class MaximinFailSafe:
    """The maximin fail-safe with a critical set that holds its members (hysteresis)."""

    def __init__(self, band: float) -> None:
        self.band = band
        self._critical: set[str] = set()

    def reset(self) -> None:
        self._critical = set()

    def critical(self, ids: Sequence[str], values: np.ndarray) -> list[int]:
        """Indices of the critical peers: within ``band`` of the smallest value, or within
        ``2·band`` if critical at the last call."""
        low = float(np.min(values))
        chosen = [
            i
            for i, (p, v) in enumerate(zip(ids, values, strict=True))
            if v <= low + self.band or (p in self._critical and v <= low + 2.0 * self.band)
        ]
        self._critical = {ids[i] for i in chosen}
        return chosen


class MaximinFallback:
    """The ``fail_safe`` fallback of one planner: maximin over the critical peers, the paper's
    command when one peer is constrained."""

    name = "fail_safe"

    def __init__(self, host: Host) -> None:
        self.host = host
        s = host.settings
        self.critical = MaximinFailSafe(s.fail_safe.band)
        self.single = HjiFailSafe(host.robot.dof, s.fail_safe.deadband)

    def reset(self) -> None:
        self.critical.reset()

    def close(self) -> None:
        """It holds nothing."""

    def command(self, now: PeerValues, u_max: float) -> np.ndarray:
        if len(now.ids) < 2:
            return self.single.command(now, u_max)
        s, n1, models = self.host.settings, self.host.robot.dof, self.host.models
        chosen = self.critical.critical(now.ids, now.values)
        own = np.array([now.grads[i][:n1] for i in chosen])
        peer = np.array([now.grads[i][n1 : n1 + models[now.model_index[i]].n2] for i in chosen])
        d_max = s.opt.d_max * now.bounds[chosen]
        return maximin_command(
            own,
            peer,
            u_max,
            d_max,
            now.values[chosen],
            s.opt.t_plan,
            s.fail_safe.slack,
            s.fail_safe.harm,
        )
