"""The SQP's C loop against its Python loop: the same iterations step for step, several
models, two threads, model handles loaded up front, the fallback and the deadline."""

from __future__ import annotations

import threading
import time
from dataclasses import replace

import _opt_helpers
import numpy as np
import pytest
from _opt_helpers import CELL, OWN, PEER, UNHURRIED, _multi_peer_problems, _near_contact

from nehmo_core.hjr.networks import NetworkSettings
from nehmo_core.planning.models.synthetic import random_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.solvers import native, sqp
from nehmo_core.planning.solvers.base import SqpSolver, make_solver
from nehmo_core.planning.solvers.sqp import SolveResult, solve_sqp

# the module-scoped fixtures of the Opt tests, bound here under their names for pytest
value_function = _opt_helpers.value_function
model = _opt_helpers.model


def test_c_and_python_loops_agree_from_the_naive_step_and_on_shared_constraints(model) -> None:
    """Starting at the naive step hands its rows to the loop (both loops, screened or not);
    the C loop keeps per-constraints arguments, so two costs over the same constraints must
    each get their own answer."""
    problems = _multi_peer_problems(model, 14, 12, two_contacts=True)
    solved = 0
    for problem in problems:
        other = replace(problem, error0=-problem.error0[::-1].copy())
        for p in (problem, other, problem):  # the C loop's cached arguments are reused
            for screen in (None, 0.1):
                naive = p.naive_step()
                py = solve_sqp(p, naive, screen=screen, native=False)
                _assert_same_solve(solve_sqp(p, naive, screen=screen), py)
                if py.status == "optimal":
                    assert py.constraint.min() >= -1e-7
                    solved += 1
            # the rows handed over are those the loop would have evaluated itself
            c, J = p.constraints.evaluate(naive)
            keep = c[: p.constraints.value_count] < 0.1
            for in_c in (True, False):
                args = (p, naive, 2.0 * np.eye(6), keep, 30, 1e-5, np.inf, 1e-7, 0.1, in_c)
                _assert_same_solve(sqp._screened(*args, (c, J)), sqp._screened(*args, None))
    assert solved >= 10


def _assert_same_solve(a: SolveResult, b: SolveResult) -> None:
    assert a.status == b.status
    assert a.iterations == b.iterations
    np.testing.assert_allclose(a.y, b.y, rtol=0, atol=1e-9)
    np.testing.assert_allclose(a.constraint, b.constraint, rtol=0, atol=1e-9)
    assert (a.hessian is None) == (b.hessian is None)
    if a.hessian is not None:  # BFGS divides by sᵀBs, so its rounding grows with small steps
        np.testing.assert_allclose(a.hessian, b.hessian, rtol=1e-4, atol=1e-6)


def test_c_loop_returns_the_python_loops_answers(model) -> None:
    """The C iterations are the Python ones step for step: same statuses, iteration counts,
    steps, constraint values and Hessian estimates (up to rounding), with and without the
    self-clearance rows, with one peer and with four (screened)."""
    loop = native.loop()
    assert loop is not None, "the C loop must build and pass its DAQP check here"
    assert loop.model(model) is not None  # so the solves below do run in C
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    problems = []
    for q1, q2, goal in _near_contact(model, 5, 15):
        now = planner.current(q1, {PEER: q2})
        problems.append(planner.problem(q1 - goal, now))
        problems.append(planner.problem(q1 - goal, now, planner.rows(q1)))
    problems += _multi_peer_problems(model, 11, 15, two_contacts=True)
    statuses = set()
    for problem in problems:
        for hessian in (None, 3.0 * np.eye(6)):
            py = solve_sqp(problem, np.zeros(6), hessian=hessian, native=False)
            c = solve_sqp(problem, np.zeros(6), hessian=hessian)
            _assert_same_solve(c, py)
            statuses.add(c.status)
    assert "optimal" in statuses


@pytest.fixture(scope="module")
def other(model) -> PairValueModel:
    """A second pair model for the same pair (other random weights)."""
    return PairValueModel.from_value_function(
        random_value_function(
            "ur5_ur5", "bc+sym", NetworkSettings(width=64, hidden_layers=2), seed=1
        ),
        "test_opt_bcsym_seed1",
    )


def test_c_loop_evaluates_several_models_like_the_python_loop(model, other) -> None:
    """Peers split between two pair models (two groups of rows, two generated functions), each
    group at its own time-to-go (as for a peer that keeps an announced speed bound) and with its
    own margin (each model's certified level)."""
    loop = native.loop()
    assert loop is not None and loop.model(model) is not None and loop.model(other) is not None
    optimal = 0
    for problem in _multi_peer_problems(model, 12, 10):
        ((_, states),) = problem.constraints.groups
        groups = [(0, states[:2]), (1, states[2:])]
        split = replace(
            problem,
            constraints=replace(
                problem.constraints,
                models=[model, other],
                groups=groups,
                horizons=(0.3, 0.12),
                margins=(0.05, 0.08),
            ),
        )
        for screen in (None, 0.1):
            py = solve_sqp(split, np.zeros(6), screen=screen, native=False)
            _assert_same_solve(solve_sqp(split, np.zeros(6), screen=screen), py)
            optimal += py.status == "optimal"
            if py.status == "optimal":  # each group keeps its own margin, not the other's
                values, _ = split.constraints.evaluate(py.y)
                assert values.min() >= -1e-7
    assert optimal >= 4


def test_c_solves_in_two_threads_get_the_answers_they_get_alone(model, other) -> None:
    """ctypes lets go of the interpreter lock during a C solve, so two planners (each with its
    own pair model) may solve at the same time in two threads: each thread has its own input and
    output buffers, and every answer equals the one the same solve gives alone."""
    problems = {"a": _multi_peer_problems(model, 31, 6), "b": _multi_peer_problems(other, 32, 6)}
    alone = {k: [solve_sqp(p, np.zeros(6)) for p in ps] for k, ps in problems.items()}
    assert any(r.status == "optimal" for rs in alone.values() for r in rs)
    answers: dict[str, list[SolveResult]] = {}

    def run(key: str) -> None:
        answers[key] = [solve_sqp(p, np.zeros(6)) for _ in range(40) for p in problems[key]]

    threads = [threading.Thread(target=run, args=(key,)) for key in problems]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for key, results in answers.items():
        assert len(results) == 40 * len(problems[key])
        for i, result in enumerate(results):
            _assert_same_solve(result, alone[key][i % len(problems[key])])


def test_a_planner_loads_its_models_c_handles_before_its_first_tick(model) -> None:
    """Building the C loop and loading a model's library take far longer than a tick: the
    planner does both when it is made, not inside its first constrained tick's deadline."""
    fresh = replace(model, _calls={})  # a model object the C loop has not seen
    assert fresh not in native.loop()._models
    NehmoPlanner(CELL, OWN, [fresh])
    assert native.loop()._models[fresh] is not None
    on_ipopt = replace(model, _calls={})
    NehmoPlanner(CELL, OWN, [on_ipopt], PlannerSettings().override({"solver.name": "ipopt"}))
    assert on_ipopt not in native.loop()._models


def test_c_loop_steps_aside_for_models_without_generated_code(model) -> None:
    """A model evaluated on CasADi's VM has no C function to call: the Python loop runs."""
    on_vm = replace(model, library=None)
    assert native.loop() is not None
    assert native.loop().model(on_vm) is None
    planner = NehmoPlanner(CELL, OWN, [on_vm], UNHURRIED)
    q1, q2, goal = _near_contact(model, 6, 1)[0]
    problem = planner.problem(q1 - goal, planner.current(q1, {PEER: q2}))
    _assert_same_solve(
        solve_sqp(problem, np.zeros(6)), solve_sqp(problem, np.zeros(6), native=False)
    )


def test_c_loop_reports_a_passed_deadline(model) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    q1, q2, goal = _near_contact(model, 7, 1)[0]
    problem = planner.problem(q1 - goal, planner.current(q1, {PEER: q2}))
    late = solve_sqp(problem, np.zeros(6), deadline=time.perf_counter() - 1.0)
    assert late.status == "timeout"
    assert late.iterations == 1
    assert make_solver(PlannerSettings().override({"solver.sqp_native": False})) == SqpSolver(
        native=False
    )
