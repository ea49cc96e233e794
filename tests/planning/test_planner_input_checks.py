"""Input validation of the planner: bad settings, counts and choices name their parameter and
rule; a batch of joint vectors is rejected at every entry."""

from __future__ import annotations

import math
import re

import _opt_helpers
import numpy as np
import pytest
from _opt_helpers import CELL, OWN, PEER, UNHURRIED, _near_contact

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.planning.baselines.naive import NaivePlanner, TrajectoryTracker, retime
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.solvers.base import SqpSolver

# the module-scoped fixtures of the Opt tests, bound here under their names for pytest
value_function = _opt_helpers.value_function
model = _opt_helpers.model


def test_sqp_screen_setting_is_validated() -> None:
    with pytest.raises(InvalidValueError, match="sqp_screen"):
        PlannerSettings().override({"solver.sqp_screen": 0.0})
    assert SqpSolver().screen == PlannerSettings().solver.sqp_screen
    assert SqpSolver().tol == PlannerSettings().solver.sqp_tol


@pytest.mark.parametrize(
    ("changes", "parameter"),
    [
        ({"opt.epsilon": -0.1}, "opt.epsilon"),
        ({"opt.t_plan": 0.0}, "opt.t_plan"),
        ({"opt.t_plan": 0.4}, "opt.t_plan"),
        ({"opt.u_max": 0.0}, "opt.u_max"),
        ({"opt.d_max": -1.0}, "opt.d_max"),
        ({"opt.deadline": 0.0}, "opt.deadline"),
        ({"solver.sqp_max_iter": 0}, "solver.sqp_max_iter"),
        ({"opt.reach_margin": -1.0}, "opt.reach_margin"),
        ({"escape.stall_ticks": 0}, "escape.stall_ticks"),
        ({"escape.escape_ticks": 0}, "escape.escape_ticks"),
        ({"escape.stall_progress": -0.1}, "escape.stall_progress"),
    ],
)
def test_bad_settings_are_rejected_naming_the_parameter(changes, parameter) -> None:
    with pytest.raises(InvalidValueError, match=f"`{parameter}`"):
        PlannerSettings().override(changes)


def test_unknown_choices_list_the_valid_ones(model) -> None:
    with pytest.raises(UnknownNameError, match="ipopt"):
        PlannerSettings().override({"solver.name": "snopt"})
    with pytest.raises(UnknownNameError, match="paper"):
        PlannerSettings.preset("fast")
    with pytest.raises(InvalidValueError, match=r"`opt\.t_safe`"):
        NehmoPlanner(CELL, OWN, [model], PlannerSettings().override({"opt.t_safe": 0.7}))
    with pytest.raises(InvalidValueError, match="`q_self`"):
        NehmoPlanner(CELL, OWN, [model], UNHURRIED).plan(
            np.zeros(5), {PEER: np.zeros(6)}, np.zeros(6)
        )
    with pytest.raises(InvalidValueError, match="`peers`"):
        NehmoPlanner(CELL, OWN, [model], UNHURRIED).plan(np.zeros(6), {}, np.zeros(6))


_PEER_Q = f"peers[{PEER!r}]"


@pytest.mark.parametrize(
    ("entry", "parameter"),
    [
        ("plan", "q_self"),
        ("plan", "q_goal"),
        ("plan", _PEER_Q),
        ("fail_safe", "q_self"),
        ("fail_safe", _PEER_Q),
        ("naive", "q_self"),
        ("naive", "q_goal"),
        ("tracker", "q_self"),
    ],
)
def test_batched_joint_vectors_are_rejected_naming_the_parameter(model, entry, parameter) -> None:
    q1, q2, goal = _near_contact(model, 6, 1)[0]
    args = {"q_self": q1, "q_goal": goal, _PEER_Q: q2}
    args[parameter] = args[parameter][None]  # (1, 6): a batch of one
    q_self, peers, q_goal = args["q_self"], {PEER: args[_PEER_Q]}, args["q_goal"]
    rule = re.escape(f"`{parameter}` must be one joint vector, shape (6,), not a batch; got (1, 6)")
    with pytest.raises(InvalidValueError, match=rule):
        if entry == "plan":
            NehmoPlanner(CELL, OWN, [model], UNHURRIED).plan(q_self, peers, q_goal)
        elif entry == "fail_safe":
            NehmoPlanner(CELL, OWN, [model], UNHURRIED).fail_safe(q_self, peers)
        elif entry == "naive":
            NaivePlanner(CELL, OWN).plan(q_self, peers, q_goal)
        else:
            trajectory = retime({OWN: np.array([q1, goal]), PEER: np.array([q2, q2])}, 0.5)
            TrajectoryTracker(CELL, trajectory, OWN, 0.1).plan(q_self, peers, q_goal)


@pytest.mark.parametrize(
    ("changes", "parameter", "rule"),
    [
        ({"self_clearance.safety": -0.01}, "self_clearance.safety", "must be >= 0"),
        ({"self_clearance.safety": math.nan}, "self_clearance.safety", "must be a number"),
        (
            {"self_clearance.influence": 0.004},
            "self_clearance.influence",
            "must be > self_clearance.safety (0.005)",
        ),
        ({"escape.seed": -1}, "escape.seed", "must be >= 0"),
        ({"escape.seed": 1.5}, "escape.seed", "must be an int >= 0"),
        ({"solver.sqp_max_iter": 2.5}, "solver.sqp_max_iter", "must be an int >= 1"),
        ({"solver.sqp_max_iter": math.nan}, "solver.sqp_max_iter", "must be an int >= 1"),
        ({"solver.sqp_max_iter": True}, "solver.sqp_max_iter", "must be an int >= 1"),
        ({"solver.ipopt_max_iter": 30.0}, "solver.ipopt_max_iter", "must be an int >= 1"),
        ({"escape.stall_ticks": 2.5}, "escape.stall_ticks", "must be an int >= 1"),
        ({"escape.stall_ticks": math.nan}, "escape.stall_ticks", "must be an int >= 1"),
        ({"escape.escape_ticks": 2.5}, "escape.escape_ticks", "must be an int >= 1"),
        ({"escape.yield_ticks": math.inf}, "escape.yield_ticks", "must be an int >= 1"),
    ],
)
def test_bad_counts_and_self_clearance_settings_name_their_own_rule(
    changes, parameter, rule
) -> None:
    with pytest.raises(InvalidValueError, match=re.escape(f"`{parameter}` {rule}; got")):
        PlannerSettings().override(changes)


def test_whole_counts_and_seeds_are_accepted() -> None:
    s = PlannerSettings().override(
        {
            "solver.sqp_max_iter": 1,
            "escape.stall_ticks": 3,
            "escape.seed": 0,
            "self_clearance.safety": 0.0,
        }
    )
    assert (
        s.solver.sqp_max_iter,
        s.escape.stall_ticks,
        s.escape.seed,
        s.self_clearance.safety,
    ) == (1, 3, 0, 0.0)
    assert PlannerSettings().override({"escape.seed": 2**40}).escape.seed == 2**40
