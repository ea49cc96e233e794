"""Problem Opt of one planning step, and its closed-form worst-case peer prediction.

In step variables ``y = t_plan·u`` [rad] (the own arm's displacement over the step)::

    min_y ‖e₀ + y‖²   s.t.  V_i(τ_i, x_i + (y, 0)) ≥ ε  for every constrained peer i,
                            |y_j| ≤ t_plan·ū,

plus, when enabled, the arm's self-clearance rows ``A·y ≥ b`` (linear, see
:mod:`nehmo_core.planning.stages.self_clearance`); ``e₀ = q¹ − q_goal`` (continuous joints
optionally wrapped) and ``x_i`` is the pair state in model ``i``'s frame with the peer already
moved by its worst case ``dⁱ = −d̄·sign(∂V/∂qⁱ)`` evaluated at ``τ = t_plan`` from the current state.
``τ_i = t_safe`` unless the peer keeps an announced speed bound (see
:mod:`nehmo_core.planning.stages.speed_bounds`); each group of rows carries its own ``τ``.
Solvers return ``u = y / t_plan``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from typing import cast

import numpy as np

from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.numerics.qp import qp_step

__all__ = [
    "Constraints",
    "LinearRows",
    "OptProblem",
    "project_step",
    "stack_rows",
    "worst_case_disturbance",
]


def worst_case_disturbance(grad_peer: np.ndarray, d_max: float) -> np.ndarray:
    """``d = −d̄·sign(∂V/∂q_peer)`` (…, n2) [rad/s]: minimizes ``⟨∇_{q_peer}V, d⟩`` over the box."""
    return -d_max * np.sign(grad_peer)


@dataclass(frozen=True)
class LinearRows:
    """Linear rows ``A·y ≥ b`` on the step (a row provider's, e.g. self-clearance)."""

    A: np.ndarray  # (k, n)
    b: np.ndarray  # (k,)

    @property
    def count(self) -> int:
        return len(self.b)

    def satisfied(self, y: np.ndarray, tol: float = 1e-9) -> bool:
        return bool(np.all(self.A @ y >= self.b - tol))


def stack_rows(*parts: LinearRows | None) -> LinearRows | None:
    """The rows of every part that is not None, in order (None if there are none)."""
    kept = [p for p in parts if p is not None]
    if len(kept) <= 1:
        return kept[0] if kept else None
    return LinearRows(np.vstack([r.A for r in kept]), np.concatenate([r.b for r in kept]))


def project_step(target: np.ndarray, rows: LinearRows, y_max: float) -> np.ndarray:
    """The step closest to ``target`` that satisfies ``rows`` within the box ``|y_j| ≤ y_max``.

    ``y = 0`` must satisfy the rows (a row provider's promise); this returns zero only if the
    QP solver fails.
    """
    target = np.clip(target, -y_max, y_max)
    if rows.count == 0 or rows.satisfied(target):
        return target
    n = len(target)
    step = qp_step(
        2.0 * np.eye(n), -2.0 * target, -rows.b, rows.A, np.full(n, -y_max), np.full(n, y_max)
    )
    return step.p if step.feasible else np.zeros(n)


@dataclass(frozen=True)
class Constraints:
    """The safety constraints of one step: pair states grouped by model for batched calls."""

    models: Sequence[PairValueModel]
    groups: Sequence[tuple[int, np.ndarray]]  # (model index, base states (k, n)) per model
    t_safe: float
    epsilon: float
    linear: LinearRows | None = None  # a row provider's rows A·y ≥ b, after the V rows
    # time-to-go [s] of each group's V rows; None: t_safe for every group
    horizons: tuple[float, ...] | None = None
    # margin [m] each group's V rows must keep (V ≥ margin); None: epsilon for every group
    margins: tuple[float, ...] | None = None

    def horizon(self, group: int) -> float:
        """The time-to-go [s] at which group ``group``'s V rows are evaluated."""
        return self.t_safe if self.horizons is None else self.horizons[group]

    def margin(self, group: int) -> float:
        """The level [m] group ``group``'s V rows must keep: ``V ≥ margin``."""
        return self.epsilon if self.margins is None else self.margins[group]

    @cached_property
    def scratch(self) -> dict[object, object]:
        """Per-instance memory for solvers (e.g. the C loop's prepared arguments)."""
        return {}

    @cached_property
    def count(self) -> int:
        extra = self.linear.count if self.linear is not None else 0
        return self.value_count + extra

    @cached_property
    def value_count(self) -> int:
        """The number of V rows (they come first, in group order)."""
        return sum(len(states) for _, states in self.groups)

    def subset(self, keep: np.ndarray) -> Constraints:
        """The same constraints with only the V rows where ``keep`` (value_count,) is true
        (the linear rows stay). The same ``keep`` gives the same object (a solve's restarts
        reuse what solvers keep on it, see :attr:`scratch`)."""
        key = ("subset", np.asarray(keep, dtype=bool).tobytes())
        if key in self.scratch:
            return cast(Constraints, self.scratch[key])
        made = self._subset(keep)
        self.scratch[key] = made
        return made

    def _subset(self, keep: np.ndarray) -> Constraints:
        groups, horizons, margins, start = [], [], [], 0
        for g, (index, states) in enumerate(self.groups):
            mine = keep[start : start + len(states)]
            start += len(states)
            if mine.any():
                groups.append((index, states[mine]))
                horizons.append(self.horizon(g))
                margins.append(self.margin(g))
        return replace(
            self,
            groups=groups,
            horizons=None if self.horizons is None else tuple(horizons),
            margins=None if self.margins is None else tuple(margins),
        )

    def evaluate(self, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(c (m,), J (m, n1))``: ``c = V − margin`` and its gradient with respect to ``y``."""
        n = len(y)
        c = np.empty(self.count)
        J = np.empty((len(c), n))
        k = 0
        for group, (index, states) in enumerate(self.groups):
            v, g = self.models[index].evaluate(self.horizon(group), states, own_step=y)
            np.subtract(v, self.margin(group), out=c[k : k + len(v)])
            J[k : k + len(v)] = g[:, :n]
            k += len(v)
        if k < len(c):
            assert self.linear is not None
            np.subtract(self.linear.A @ y, self.linear.b, out=c[k:])
            J[k:] = self.linear.A
        return c, J


@dataclass(frozen=True)
class OptProblem:
    """One step of Opt in step variables ``y`` (see the module docstring)."""

    error0: np.ndarray  # e₀ = q¹ − q_goal (n1,) [rad]
    y_max: float  # t_plan·ū [rad]
    t_plan: float
    constraints: Constraints

    def cost(self, y: np.ndarray) -> float:
        e = self.error0 + y
        return float(e @ e)

    def naive_step(self) -> np.ndarray:
        """The unconstrained minimizer: straight toward the goal, clipped to the box."""
        return np.clip(-self.error0, -self.y_max, self.y_max)

    def velocity(self, y: np.ndarray) -> np.ndarray:
        return y / self.t_plan
