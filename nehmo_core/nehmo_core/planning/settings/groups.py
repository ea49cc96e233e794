"""The settings of the paper's problem Opt and of how it is solved.

``opt``: problem Opt (paper § III-C) and Algorithm 1's clock; ``margins``: how the margin ε is
set from the pair models' certificates; ``solver``: which solver and its tolerances;
``fail_safe``: the command when Opt has no answer in time. Times are [s], joint speeds [rad/s],
values of V [m].
"""

from __future__ import annotations

from dataclasses import dataclass

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.settings.spec import check_group, setting

__all__ = ["FailSafeSettings", "MarginSettings", "OptSettings", "SolverSettings"]

SOLVERS = ("sqp", "ipopt")
"""``sqp``: the exact active-set SQP of :mod:`nehmo_core.planning.solvers.sqp` (fast);
``ipopt``: IPOPT through CasADi, the authors' setting (the reference)."""
BACKENDS = ("auto", "compiled", "vm")


@dataclass(frozen=True)
class OptSettings:
    """Problem Opt (paper § III-C) and Algorithm 1's clock.

    ``t_plan < t_safe ≤`` the value function's horizon is checked when a planner is built (the
    horizon belongs to the model).
    """

    epsilon: float = setting(
        0.05, "safety margin on V (the floor when margins are certified)", "m", gt=0
    )
    t_plan: float = setting(0.1, "planning horizon: the command is held this long", "s", gt=0)
    t_safe: float = setting(
        0.3, "time-to-go at which V must stay >= epsilon after the step", "s", gt=0
    )
    u_max: float = setting(0.5, "ū: own joint speed bound", "rad/s", gt=0, lt=float("inf"))
    d_max: float = setting(
        0.5, "d̄: peers' joint speed bound (their worst case)", "rad/s", gt=0, lt=float("inf")
    )
    wrap_goal: bool = setting(False, "wrap continuous joints in the goal cost (the paper does not)")
    reach_margin: float = setting(
        0.0,
        "peers whose bases are farther apart than their arms can touch (both collision reaches, "
        "as the pair models cover them) plus this are not constrained",
        "m",
        ge=0,
    )
    deadline: float = setting(
        0.04, "a solve longer than this triggers the fail-safe (one 25 Hz tick)", "s", gt=0
    )
    tick: float = setting(0.04, "period between two plan() calls", "s", gt=0)

    def __post_init__(self) -> None:
        check_group(self, "opt")
        if not self.t_plan < self.t_safe:
            raise InvalidValueError(
                "opt.t_plan", f"must be < opt.t_safe ({self.t_safe})", self.t_plan
            )


@dataclass(frozen=True)
class MarginSettings:
    """Certified margins (not in the paper; ``planning/models/margins.py``)."""

    # epsilon is raised to the largest δ certified at t_safe by the pair models in use (the
    # ``nehmo verify`` cards); rows against a peer that announced a bound keep max(epsilon as
    # given, their model's δ at hold.bound·t_safe), at most the raised epsilon
    certified: bool = setting(
        True,
        "raise opt.epsilon to the pair models' certified error at t_safe "
        "(false: the paper's fixed margin)",
    )
    # certificates say which actuator model their rollouts assumed (nehmo verify --actuators);
    # a model without one for this model keeps its ideal-tracking certificates
    actuators: str = setting(
        "ideal",
        "the actuator model whose certificates set the margins (nehmo verify --actuators)",
        choices=("ideal", "realistic", "limits"),
    )

    def __post_init__(self) -> None:
        check_group(self, "margins")


@dataclass(frozen=True)
class SolverSettings:
    """How Opt is solved and how V, ∇V are evaluated."""

    name: str = setting(
        "sqp", "sqp (exact active-set SQP, fast) | ipopt (the authors' solver)", choices=SOLVERS
    )
    backend: str = setting(
        "auto", "V, ∇V evaluation: generated C (compiled) or CasADi's vm", choices=BACKENDS
    )
    sqp_max_iter: int = setting(30, "SQP iterations at most", ge=1)
    # converged when a step is below sqp_tol [rad] (in step units t_plan·u) at a point that
    # breaks no constraint by more than 1e-7 m
    sqp_tol: float = setting(
        1e-4, "SQP converges when a step is below this (step units t_plan·u)", "rad", gt=0
    )
    # with several peers the iterations carry only the V rows below sqp_screen [m] at the naive
    # step; the rest are checked at the solution and join if broken (inf: every row throughout).
    # 3 cm: in the planning-speed bench's closed loops a row above it at the naive step rarely
    # binds at the solution (a few rejoins per thousand solves), and at two peers the p95 step
    # evaluates 10 V rows instead of the 14 of a 10 cm margin
    sqp_screen: float = setting(
        0.03, "SQP iterates only on V rows below this at the naive step", "m", gt=0
    )
    sqp_warm_hessian: bool = setting(True, "start BFGS from the previous tick's Hessian estimate")
    sqp_native: bool = setting(
        True, "run the SQP iterations in C when every pair model has generated code (same answers)"
    )
    ipopt_tol: float = setting(1e-3, "IPOPT tolerance (the authors' setting)", gt=0)
    ipopt_max_iter: int = setting(30, "IPOPT iterations at most (the authors' setting)", ge=1)

    def __post_init__(self) -> None:
        check_group(self, "solver")


@dataclass(frozen=True)
class FailSafeSettings:
    """The command when Opt has no answer in time: the paper's ``ū·sign(∂V/∂q¹)`` of the most
    critical pair (``planning/opt/fail_safe.py``)."""

    deadband: float = setting(
        0.2,
        "joints whose |∂V/∂q_j| is below this share of the largest stay still (0: the paper's)",
        ge=0,
        lt=1,
    )

    def __post_init__(self) -> None:
        check_group(self, "fail_safe")
