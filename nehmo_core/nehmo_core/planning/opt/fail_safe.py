"""The paper's fail-safe: the HJI optimal control ``u = ū·sign(∂V/∂q¹)`` of the most critical
pair (the smallest ``V``), applied when Opt fails, is infeasible or misses its deadline.

``deadband`` (setting ``fail_safe.deadband``: 0.2 by default, 0 in the ``paper`` preset) keeps
still the joints whose ``|∂V/∂q_j|`` is below that share of the largest: they change V little,
and sweeping them at full speed (the sign of a slope near zero) drives an arm off its goal or
folds it into itself.
"""

from __future__ import annotations

import numpy as np

from nehmo_core.planning.opt.tick import PeerValues

__all__ = ["HjiFailSafe"]


class HjiFailSafe:
    """The fallback of the paper's Algorithm 1 for an arm with ``dof`` joints."""

    name = "fail_safe"

    def __init__(self, dof: int, deadband: float = 0.0) -> None:
        self.dof = dof
        self.deadband = deadband

    def reset(self) -> None:
        """It keeps no state."""

    def close(self) -> None:
        """It holds nothing."""

    def command(self, now: PeerValues, u_max: float) -> np.ndarray:
        g = now.grads[now.critical][: self.dof]
        u = u_max * np.sign(g)
        if self.deadband > 0.0:
            # joints that barely change V need not sweep at full speed (they cost V at most
            # ū·Σ|g_j| over the dead joints, and may fold the arm into itself)
            u[np.abs(g) < self.deadband * np.abs(g).max()] = 0.0
        return u
