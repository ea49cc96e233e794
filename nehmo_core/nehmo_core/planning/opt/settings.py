"""Settings of the NeHMO planner (problem Opt, its solvers and the fail-safe)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from numbers import Integral
from typing import Any

from nehmo_core.errors import InvalidValueError, UnknownNameError

__all__ = ["PAPER_OPT", "SOLVERS", "PlannerSettings"]

SOLVERS = ("sqp", "ipopt")
FAIL_SAFES = ("single", "maximin")
"""``sqp``: the exact active-set SQP of :mod:`nehmo_core.planning.solvers.sqp` (fast);
``ipopt``: IPOPT through CasADi, the authors' setting (the reference)."""

PAPER_OPT: dict[str, Any] = {
    "self_clearance": False,
    "escape": False,
    "fail_safe": "single",
    "hold_bound": 1.0,
    "exact_guard": 0.0,
    "silent_lookahead": 0.0,
    "certified_epsilon": False,
}
"""What the paper's Opt leaves out of NeHMO's defaults (the ``paper`` preset, ``nehmo_paper``)."""

_PRESETS: dict[str, dict[str, Any]] = {
    "default": {},
    "paper": PAPER_OPT,
    "ipopt": {"solver": "ipopt"},
    "wrapped_goal": {"wrap_goal": True},
}


@dataclass(frozen=True)
class PlannerSettings:
    """Problem Opt (paper § III-C) and how it is solved.

    Times are [s], joint speeds [rad/s], values [m]. ``t_plan < t_safe ≤`` the value function's
    horizon is checked when a planner is built (the horizon belongs to the model).
    """

    epsilon: float = 0.05  # safety margin on V
    # certified margins (``nehmo verify`` cards, ``planning/models/margins.py``): epsilon is raised
    # to the largest δ certified at t_safe by the pair models in use; rows against a peer that
    # announced a bound keep max(epsilon as given, their model's δ at hold_bound·t_safe), at most
    # the raised epsilon. False keeps epsilon as given for every row (the paper's fixed margin)
    certified_epsilon: bool = True
    # with certified margins, the floor [m] of rows against a peer that announced a speed bound:
    # they keep min(raised epsilon, max(settled_epsilon, their model's δ at hold_bound·t_safe));
    # 1 cm, the exact guard's gap (0.05 m before the guard: a learned distance may read 3 cm at
    # contact; 2 cm until five-UR5 goal sets 1-2 cm apart were seen to end stuck)
    settled_epsilon: float = 0.01
    t_plan: float = 0.1  # planning horizon: the command is held this long
    t_safe: float = 0.3  # time-to-go at which V must stay ≥ epsilon after the step
    u_max: float = 0.5  # ū: own joint speed bound
    d_max: float = 0.5  # d̄: peers' joint speed bound (worst case)
    wrap_goal: bool = False  # wrap continuous joints in the goal cost (the paper does not)
    solver: str = "sqp"
    deadline: float = 0.04  # a solve longer than this (one 25 Hz tick) triggers the fail-safe
    reach_margin: float = 0.3  # peers farther than reach_own + reach_peer + margin are skipped
    # fail-safe joints whose |∂V/∂q_j| is below this share of the largest stay still (0: every
    # joint at full speed, the paper's fail-safe)
    fail_safe_deadband: float = 0.0
    # "single": the paper's ū·sign(∂V/∂q¹) of the most critical peer; "maximin": the command
    # that maximizes the smallest worst-case V rate over every peer within fail_safe_band [m] of
    # the smallest V (planning/stages/fail_safe.py)
    fail_safe: str = "maximin"
    fail_safe_band: float = 0.05
    # the maximin fail-safe is lexicographic: it may lower the worst pair's predicted V by up to
    # fail_safe_slack [m] below its best to raise the next pairs' (0: plain maximin)
    fail_safe_slack: float = 0.005
    # ... and its own motion may lower no critical pair's V faster than fail_safe_harm [m/s]
    # (0: it never trades one peer for another; 100, above any rate: no limit)
    fail_safe_harm: float = 0.0
    # announced speed bounds (not in the paper; planning/stages/speed_bounds.py): an arm within
    # hold_tolerance [rad] (L2) of its goal announces hold_bound (a fraction of ū) and keeps its
    # commands within it until it leaves hold_release, gets a new goal or a peer breaks
    # V(hold_bound·t_plan) ≥ ε with it (half its settled margin for a peer that announces),
    # announcing the withdrawal bound_release_ticks commands ahead; peers that keep their
    # announcement are planned against V(k·t_safe). hold_bound = 1: announce nothing (the paper)
    hold_bound: float = 0.2
    hold_tolerance: float = 0.05
    # a holding arm pushed off its goal keeps its bound up to hold_release [rad] (L2) from it, so
    # the pushing peer can pass; 2·hold_tolerance withdrew it early and both arms fled in turns
    hold_release: float = 0.4
    bound_release_ticks: int = 2
    # commands are shortened so that the arm's real geometry (PyBullet) stays exact_guard [m]
    # from every peer that holds at its goal under an announced bound, and a holding arm flees a
    # full-speed peer closer than that (planning/stages/exact_guard.py; 0: both off)
    exact_guard: float = 0.01
    # a peer that announces nothing is extrapolated silent_lookahead [s] along its observed joint
    # velocity (its motion over one tick [s] between plan() calls); when V(t_plan) at a point of
    # that path is below silent_clearance [m] and the peer is approaching, the step's target is
    # up ∂V/∂q_own there instead of the goal; the V rows are unchanged
    # (planning/stages/silent_peers.py; silent_lookahead = 0: off)
    silent_lookahead: float = 2.0
    silent_clearance: float = 0.2
    tick: float = 0.04
    # self-collision velocity dampers on the step and the fail-safe (not in the paper's Opt):
    # link pairs closer than self_influence [m] may close at most self_gain of their distance
    # above self_safety [m] per planned step (planning/stages/self_clearance.py)
    self_clearance: bool = True
    self_influence: float = 0.10
    self_safety: float = 0.005
    self_gain: float = 0.5
    # stall escape (not in the paper's Opt): after stall_ticks plan() calls in which the goal
    # error fell by less than stall_progress·t_plan·ū while a V row was within stall_margin [m]
    # of ε, the arm follows a random direction tangent to the critical pair's level set of V
    # for escape_ticks calls (longer if it stalls again before a new lowest goal error), then
    # heads for the goal again; an arm held at its goal that long yields: it steps up V's
    # gradient for yield_ticks calls
    escape: bool = True
    stall_ticks: int = 12
    escape_ticks: int = 25
    yield_ticks: int = 12
    stall_progress: float = 0.1
    stall_margin: float = 0.01
    escape_seed: int = 0
    backend: str = "auto"  # evaluation of V, ∇V: generated C ("compiled") or CasADi's "vm"
    # SQP
    sqp_max_iter: int = 30
    # converged when a step is below sqp_tol [rad] (in step units t_plan·u) at a point that
    # breaks no constraint by more than 1e-7 m
    sqp_tol: float = 1e-4
    # with several peers the iterations carry only the V rows below sqp_screen [m] at the naive
    # step; the rest are checked at the solution and join if broken (inf: every row throughout).
    # 3 cm: in the planning-speed bench's closed loops a row above it at the naive step rarely
    # binds at the solution (a few rejoins per thousand solves), and at two peers the p95 step
    # evaluates 10 V rows instead of the 14 of a 10 cm margin
    sqp_screen: float = 0.03
    sqp_warm_hessian: bool = True  # start BFGS from the previous tick's Hessian estimate
    # run the SQP iterations in C when every pair model has generated code (same algorithm and
    # answers as the Python loop, less overhead per iteration); False: the Python loop
    sqp_native: bool = True
    # IPOPT (authors' settings)
    ipopt_tol: float = 1e-3
    ipopt_max_iter: int = 30

    def __post_init__(self) -> None:
        for name in (
            "epsilon",
            "settled_epsilon",
            "t_plan",
            "t_safe",
            "u_max",
            "d_max",
            "deadline",
            "tick",
            "sqp_tol",
            "sqp_screen",
        ):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        if not self.t_plan < self.t_safe:
            raise InvalidValueError("t_plan", f"must be < t_safe ({self.t_safe})", self.t_plan)
        if not 0.0 <= self.fail_safe_deadband < 1.0:
            raise InvalidValueError(
                "fail_safe_deadband", "must lie in [0, 1)", self.fail_safe_deadband
            )
        if self.fail_safe not in FAIL_SAFES:
            raise UnknownNameError("fail_safe", self.fail_safe, FAIL_SAFES)
        if not 0.0 <= self.hold_bound <= 1.0:
            raise InvalidValueError(
                "hold_bound", "must lie in [0, 1] (a fraction of ū)", self.hold_bound
            )
        if not self.hold_tolerance > 0.0:
            raise InvalidValueError("hold_tolerance", "must be > 0 [rad]", self.hold_tolerance)
        if not self.hold_release >= self.hold_tolerance:
            raise InvalidValueError(
                "hold_release",
                f"must be >= hold_tolerance ({self.hold_tolerance}) [rad]",
                self.hold_release,
            )
        if not self.fail_safe_band >= 0.0:
            raise InvalidValueError("fail_safe_band", "must be >= 0 [m]", self.fail_safe_band)
        if not self.fail_safe_slack >= 0.0:
            raise InvalidValueError("fail_safe_slack", "must be >= 0 [m]", self.fail_safe_slack)
        if not self.fail_safe_harm >= 0.0:
            raise InvalidValueError("fail_safe_harm", "must be >= 0 [m/s]", self.fail_safe_harm)
        for name in ("silent_lookahead", "silent_clearance"):
            if not getattr(self, name) >= 0.0:
                raise InvalidValueError(name, "must be >= 0 (0: off)", getattr(self, name))
        if not self.exact_guard >= 0.0:
            raise InvalidValueError("exact_guard", "must be >= 0 [m] (0: off)", self.exact_guard)
        if not self.self_safety >= 0.0:
            raise InvalidValueError("self_safety", "must be >= 0", self.self_safety)
        if not self.self_influence > self.self_safety:
            raise InvalidValueError(
                "self_influence", f"must be > self_safety ({self.self_safety})", self.self_influence
            )
        if not 0.0 < self.self_gain <= 1.0:
            raise InvalidValueError("self_gain", "must lie in (0, 1]", self.self_gain)
        for name in ("stall_progress", "stall_margin"):
            if not getattr(self, name) >= 0:
                raise InvalidValueError(name, "must be >= 0", getattr(self, name))
        if not self.reach_margin >= 0:
            raise InvalidValueError("reach_margin", "must be >= 0", self.reach_margin)
        counts = (
            "sqp_max_iter",
            "ipopt_max_iter",
            "stall_ticks",
            "escape_ticks",
            "yield_ticks",
            "bound_release_ticks",
        )
        for name in (*counts, "escape_seed"):
            value = getattr(self, name)
            low = 0 if name == "escape_seed" else 1
            if not isinstance(value, Integral) or isinstance(value, bool):  # not 2.5, NaN, True
                raise InvalidValueError(name, f"must be an int >= {low}", value)
            if value < low:
                raise InvalidValueError(name, f"must be >= {low}", value)
        if not self.ipopt_tol > 0:
            raise InvalidValueError("ipopt_tol", "must be > 0", self.ipopt_tol)
        if self.solver not in SOLVERS:
            raise UnknownNameError("solver", self.solver, SOLVERS)
        if self.backend not in ("auto", "compiled", "vm"):
            raise UnknownNameError("backend", self.backend, ("auto", "compiled", "vm"))

    @classmethod
    def preset(cls, name: str, **overrides: Any) -> PlannerSettings:
        """Named settings: ``default``; ``paper`` (the paper's Opt: no self-clearance rows, no
        stall escape);
        ``ipopt``; ``wrapped_goal``."""
        if name not in _PRESETS:
            raise UnknownNameError("planner preset", name, _PRESETS)
        return cls(**{**_PRESETS[name], **overrides})

    def replace(self, **changes: Any) -> PlannerSettings:
        return replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
