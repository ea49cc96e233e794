"""Problem Opt, its solvers and the fail-safe: fast code vs slow obvious references."""

from __future__ import annotations

import itertools
import math
import re
import threading
import time
from dataclasses import replace

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.hjr.networks import NetworkSettings
from nehmo_core.planning.baselines.naive import NaivePlanner, TrajectoryTracker, retime
from nehmo_core.planning.models.synthetic import random_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.numerics.qp import qp_step
from nehmo_core.planning.opt.problem import Constraints, OptProblem, worst_case_disturbance
from nehmo_core.planning.opt.settings import PlannerSettings
from nehmo_core.planning.solvers import native, sqp
from nehmo_core.planning.solvers.base import SqpSolver, make_solver
from nehmo_core.planning.solvers.ipopt import IpoptSolver
from nehmo_core.planning.solvers.sqp import SolveResult, solve_sqp
from nehmo_core.planning.stages.self_clearance import SelfClearanceRows
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import sample_configuration

CELL = load_cell("dual_ur5")
UNHURRIED = PlannerSettings(deadline=3600.0)  # statuses never depend on the machine's load
OWN, PEER = "ur5_0", "ur5_1"


@pytest.fixture(scope="module")
def value_function():
    return random_value_function("ur5_ur5", "bc+sym", NetworkSettings(width=64, hidden_layers=2))


@pytest.fixture(scope="module")
def model(value_function) -> PairValueModel:
    # double-precision products: several tests here solve to 1e-8 rad and compare solvers
    # step for step, below the ~1e-8 rounding of the planner's float products (the default)
    return PairValueModel.from_value_function(value_function, "test_opt_bcsym", single=False)


def _near_contact(model: PairValueModel, seed: int, count: int) -> list[tuple[np.ndarray, ...]]:
    """States and goals where the naive step breaks the constraint but staying still does not.

    The goal pushes the own arm down the value's gradient, so the constraint is active.
    """
    rng = np.random.default_rng(seed)
    robot = CELL.arm(OWN).robot
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    out = []
    while len(out) < count:
        q1, q2 = sample_configuration(robot, rng), sample_configuration(robot, rng)
        v, g = model.evaluate(0.1, np.concatenate([q1, q2])[None])
        if not 0.06 <= v[0] <= 0.2:
            continue
        goal = q1 - rng.uniform(0.3, 1.5) * np.sign(g[0, :6]) + rng.normal(0, 0.2, 6)
        problem = planner.problem(q1 - goal, planner.current(q1, {PEER: q2}))
        c_naive, _ = problem.constraints.evaluate(problem.naive_step())
        c_still, _ = problem.constraints.evaluate(np.zeros(6))
        if c_naive[0] < 0 < c_still[0]:
            out.append((q1, q2, goal))
    return out


def test_worst_case_disturbance_is_the_box_corner_minimizer() -> None:
    rng = np.random.default_rng(0)
    corners = np.array(list(itertools.product([-0.5, 0.5], repeat=6)))
    for _ in range(50):
        grad = rng.normal(size=6)
        d = worst_case_disturbance(grad, 0.5)
        brute = corners[np.argmin(corners @ grad)]
        np.testing.assert_array_equal(d, brute)
        assert grad @ d == pytest.approx((corners @ grad).min())


def test_planner_predicts_peers_with_the_brute_force_worst_case(model: PairValueModel) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    q1, q2, goal = _near_contact(model, 1, 1)[0]
    now = planner.current(q1, {PEER: q2})
    problem = planner.problem(q1 - goal, now)
    predicted = problem.constraints.groups[0][1][0]
    corners = np.array(list(itertools.product([-0.5, 0.5], repeat=6)))
    worst = corners[np.argmin(corners @ now.grads[0][6:])]
    np.testing.assert_allclose(predicted[6:], q2 + 0.1 * worst, atol=1e-12)


def test_evaluating_with_an_own_step_equals_evaluating_the_shifted_states(model) -> None:
    x = np.random.default_rng(3).uniform(-2.0, 2.0, size=(3, 12))
    step = np.linspace(-0.05, 0.05, 6)
    shifted, before = x.copy(), x.copy()
    shifted[:, :6] += step
    for rows in (x[:1], x):  # the single-state and the mapped call
        v, g = model.evaluate(0.3, rows, own_step=step)
        v_ref, g_ref = model.evaluate(0.3, shifted[: len(rows)])
        np.testing.assert_array_equal(v, v_ref)
        np.testing.assert_array_equal(g, g_ref)
    np.testing.assert_array_equal(x, before)  # the input is left alone


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


def test_safe_unconstrained_step_equals_the_naive_step(model: PairValueModel) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    naive = NaivePlanner(CELL, OWN)
    q1 = np.array([0.0, -2.4, 1.5, -1.6, -1.5, 0.0])  # arms folded away from each other
    q2 = q1.copy()
    goal = q1 + np.array([0.3, 0.01, -0.02, 0.2, -0.6, 0.004])
    result = planner.plan(q1, {PEER: q2}, goal)
    assert result.telemetry.status == "naive"
    assert result.telemetry.min_value > 0.3
    np.testing.assert_array_equal(result.velocity, naive.plan(q1, {}, goal).velocity)


@pytest.mark.parametrize("in_c", [True, False])
def test_a_nan_row_at_the_naive_step_is_not_taken_for_a_safe_one(model, in_c) -> None:
    """A row that evaluates to NaN (here a linear row with a NaN bound; a network could
    overflow) is not satisfied: the naive step is not returned, whatever the other rows say."""
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    q1 = np.array([0.0, -2.4, 1.5, -1.6, -1.5, 0.0])  # the V row far from active
    problem = planner.problem(np.full(6, -0.01), planner.current(q1, {PEER: q1.copy()}))
    assert solve_sqp(problem, np.zeros(6), native=in_c).status == "naive"
    rows = SelfClearanceRows(np.eye(6)[:1], np.array([np.nan]), np.array([0.05]), (("a", "b"),))
    poisoned = replace(problem, constraints=replace(problem.constraints, linear=rows))
    assert solve_sqp(poisoned, np.zeros(6), native=in_c).status != "naive"


def test_constraint_holds_at_the_solution_against_an_adversarial_peer(
    model: PairValueModel, value_function
) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], PlannerSettings(deadline=1.0))
    solved = 0
    for q1, q2, goal in _near_contact(model, 3, 12):
        for _ in range(5):  # the peer plays its worst case every step
            result = planner.plan(q1, {PEER: q2}, goal)
            _, grad = value_function.value_and_gradient(0.1, np.concatenate([q1, q2]))
            d = worst_case_disturbance(grad[6:], 0.5)
            if not result.telemetry.fail_safe:
                solved += 1
                x_next = np.concatenate([q1 + 0.1 * result.velocity, q2 + 0.1 * d])
                assert value_function.value(0.3, x_next) >= 0.05 - 1e-6  # independent torch check
            assert np.all(np.abs(result.velocity) <= 0.5 + 1e-12)
            q1, q2 = q1 + 0.1 * result.velocity, q2 + 0.1 * d
    assert solved >= 10


def test_sqp_returns_the_ipopt_solution(model: PairValueModel) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    reference = IpoptSolver(tol=1e-10, max_iter=300)
    compared = 0
    for q1, q2, goal in _near_contact(model, 4, 40):
        problem = planner.problem(q1 - goal, planner.current(q1, {PEER: q2}))
        fast = solve_sqp(problem, np.zeros(6), tol=1e-9)
        if fast.status != "optimal":
            continue
        ref = reference.solve(problem, np.zeros(6))
        assert ref.status == "optimal"
        np.testing.assert_allclose(fast.y, ref.y, atol=2e-6)  # step [rad]; ū·t_plan = 0.05
        # IPOPT ends ~1e-8 inside the infeasible side of its bound; the costs agree to that.
        assert abs(problem.cost(fast.y) - problem.cost(ref.y)) <= 1e-6 * (1.0 + problem.cost(ref.y))
        assert fast.constraint.min() >= -1e-9
        # the default tolerance (1e-4 rad on the last step) lands within it of the solution
        default = solve_sqp(problem, np.zeros(6), tol=PlannerSettings().sqp_tol)
        assert default.status == "optimal"
        np.testing.assert_allclose(default.y, fast.y, atol=PlannerSettings().sqp_tol)
        assert default.constraint.min() >= -1e-7
        compared += 1
    assert compared >= 5


def _multi_peer_problems(
    model: PairValueModel, seed: int, count: int, two_contacts: bool = False
) -> list[OptProblem]:
    """Centre arm of the five-UR5 cell (four peers), the naive step breaking a V row while
    another row holds at it. The goal pushes the arm down the gradient of its most critical
    pair, or (``two_contacts``) of its two most critical pairs at once, so the solution may
    slide along one level set into the other."""
    five = load_cell("five_ur5")
    planner = NehmoPlanner(five, "ur5_0", [model], UNHURRIED)
    assert len(planner.pairs) == 4
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(20000):
        q = {a: sample_configuration(five.arm(a).robot, rng) for a in five.arm_ids}
        now = planner.current(q["ur5_0"], q)
        first, second = np.argsort(now.values)[:2]
        if now.values[first] < 0.06 or now.values[second if two_contacts else first] > 0.25:
            continue
        g = now.grads[first][:6] / np.linalg.norm(now.grads[first][:6])
        if two_contacts:
            g = g + now.grads[second][:6] / np.linalg.norm(now.grads[second][:6])
        problem = planner.problem(rng.uniform(0.3, 1.5) * g / np.abs(g).max(), now)
        c, _ = problem.constraints.evaluate(problem.naive_step())
        if c.min() < 0.0 and c.max() >= 0.0:
            out.append(problem)
            if len(out) == count:
                return out
    raise AssertionError(f"found only {len(out)} of {count} multi-peer problems")


@pytest.mark.parametrize(("screen", "two_contacts"), [(0.1, False), (0.1, True), (1e-9, True)])
def test_screened_sqp_returns_the_solution_of_the_whole_problem(
    model, screen, two_contacts
) -> None:
    """Rows far from active at the naive step are left out of the iterations and checked at the
    end; with a near-zero margin only the rows broken at the naive step are carried, so the
    check must bring others back. Either way the answer is that of the whole problem. (tol 1e-8:
    at 1e-9 an iteration count is at the mercy of rounding, e.g. of the vector math library.)"""
    rejoined = compared = 0
    for problem in _multi_peer_problems(model, 9, 80 if two_contacts else 40, two_contacts):
        whole = solve_sqp(problem, np.zeros(6), tol=1e-8, screen=None)
        screened = solve_sqp(problem, np.zeros(6), tol=1e-8, screen=screen)
        assert screened.status == whole.status
        if whole.status != "optimal":
            continue
        compared += 1
        np.testing.assert_allclose(screened.y, whole.y, atol=1e-6)
        assert len(screened.constraint) == problem.constraints.count
        assert screened.constraint.min() >= -1e-7
        # would the rows carried at first have sufficed? (solve only those, check the rest)
        c_naive, _ = problem.constraints.evaluate(problem.naive_step())
        rows = problem.constraints.value_count
        kept = c_naive[:rows] < screen
        alone = solve_sqp(
            replace(problem, constraints=problem.constraints.subset(kept)),
            np.zeros(6),
            tol=1e-8,
            screen=None,
        )
        c_alone, _ = problem.constraints.evaluate(alone.y)
        rejoined += bool((c_alone[:rows][~kept] < -1e-7).any())
    assert compared >= 20
    if screen < 0.01:
        assert rejoined >= 1  # the check after the reduced solve had rows to bring back


def test_ipopt_solves_the_multi_peer_problem_the_sqp_solves(model) -> None:
    """Several peers under one model enter IPOPT as one parameter block; its constraint values
    must be those of :meth:`Constraints.evaluate` at its answer, and its answer the SQP's."""
    reference = IpoptSolver(tol=1e-10, max_iter=300)
    compared = 0
    for problem in _multi_peer_problems(model, 13, 8, two_contacts=True):
        assert problem.constraints.groups[0][1].shape[0] == 4  # four peers, one model
        ref = reference.solve(problem, np.zeros(6))
        c, _ = problem.constraints.evaluate(ref.y)
        np.testing.assert_allclose(ref.constraint, c, atol=1e-9)
        fast = solve_sqp(problem, np.zeros(6), tol=1e-9, screen=None)
        if fast.status == "optimal" and ref.status == "optimal":
            np.testing.assert_allclose(fast.y, ref.y, atol=2e-6)
            compared += 1
    assert compared >= 4


def test_an_infeasible_linearization_at_the_warm_start_is_not_taken_for_an_infeasible_opt(
    model,
) -> None:
    """From a warm start at a corner of the box (where the last tick's fail-safe leaves it) the
    linearized QP may have no feasible point while Opt has a solution. The SQP must then start
    again (from the naive step, then from y = 0) and return Opt's solution, not ``infeasible``."""
    corners = np.array(list(itertools.product([-1.0, 1.0], repeat=6)))
    rescued = 0
    # tol 1e-7 rad: at 1e-9 the damped BFGS tail of one of these problems needs 30 to 60
    # iterations, depending on the CPU's rounding of the generated kernels
    for problem in _multi_peer_problems(model, 22, 30):
        ymax = problem.y_max
        reference = solve_sqp(problem, np.zeros(6), tol=1e-7, screen=None)
        for y0 in corners * ymax:
            c, J = problem.constraints.evaluate(y0)
            first = qp_step(
                2.0 * np.eye(6), 2.0 * (problem.error0 + y0), c, J, -ymax - y0, ymax - y0
            )
            if first.flag != -1:
                continue
            result = solve_sqp(problem, y0, tol=1e-7, screen=None)
            assert result.status == reference.status == "optimal"
            assert result.iterations > 1  # the infeasible first start counts
            np.testing.assert_allclose(result.y, reference.y, atol=1e-6)
            assert result.constraint.min() >= -1e-7
            rescued += 1
    assert rescued >= 5


def test_an_infeasible_opt_is_reported_after_every_start(model) -> None:
    """No step reaches ``V ≥ ε`` when ε exceeds any value: every start's first QP is infeasible."""
    problem = _multi_peer_problems(model, 12, 1)[0]
    hopeless = replace(
        problem, constraints=replace(problem.constraints, epsilon=50.0, margins=None)
    )
    warm = np.full(6, 0.5 * problem.y_max)
    result = solve_sqp(hopeless, warm)
    assert result.status == "infeasible"
    assert result.iterations == 3  # the warm start, the naive step and y = 0, one QP each
    # a warm start equal to the naive step is not tried twice
    assert solve_sqp(hopeless, hopeless.naive_step()).iterations == 2


def test_the_naive_steps_rows_are_evaluated_once(model, monkeypatch) -> None:
    """The naive step's rows, evaluated for the safety check, serve a start from the naive step
    (the first start or a restart): an infeasible Opt costs one evaluation per distinct start."""
    problem = _multi_peer_problems(model, 12, 1)[0]
    hopeless = replace(
        problem, constraints=replace(problem.constraints, epsilon=50.0, margins=None)
    )
    calls = []
    evaluate = Constraints.evaluate
    monkeypatch.setattr(
        Constraints, "evaluate", lambda self, y: calls.append(y.copy()) or evaluate(self, y)
    )
    warm = np.full(6, 0.5 * problem.y_max)
    for start, starts in ((warm, 3), (hopeless.naive_step(), 2)):
        calls.clear()
        result = solve_sqp(hopeless, start, native=False)
        assert result.status == "infeasible"
        assert len(calls) == starts  # naive (the check), the warm start if apart, y = 0
        np.testing.assert_array_equal(calls[0], hopeless.naive_step())


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


def test_a_subset_of_the_constraints_is_made_once_per_choice_of_rows(model) -> None:
    """A solve's restarts ask for the same screened rows again: they get the same object (with
    what the C loop prepared on it), and its rows are those asked for."""
    cons = _multi_peer_problems(model, 12, 1)[0].constraints
    keep = np.array([True, False, True, False])
    first = cons.subset(keep)
    assert cons.subset(keep.copy()) is first
    assert cons.subset(~keep) is not first
    y = np.full(6, 0.01)
    np.testing.assert_array_equal(first.evaluate(y)[0][:2], cons.evaluate(y)[0][[0, 2]])


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
    NehmoPlanner(CELL, OWN, [on_ipopt], PlannerSettings(solver="ipopt"))
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
    assert make_solver(PlannerSettings(sqp_native=False)) == SqpSolver(native=False)


def test_sqp_screen_setting_is_validated() -> None:
    with pytest.raises(InvalidValueError, match="sqp_screen"):
        PlannerSettings(sqp_screen=0.0)
    assert SqpSolver().screen == PlannerSettings().sqp_screen
    assert SqpSolver().tol == PlannerSettings().sqp_tol


def test_default_ipopt_settings_agree_with_sqp_within_their_tolerance(model) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED)
    paper = IpoptSolver()  # tol 1e-3, max_iter 30, limited-memory Hessian
    compared = 0
    for q1, q2, goal in _near_contact(model, 5, 10):
        problem = planner.problem(q1 - goal, planner.current(q1, {PEER: q2}))
        fast = solve_sqp(problem, np.zeros(6))
        ref = paper.solve(problem, np.zeros(6))
        if fast.status == "optimal" and ref.status == "optimal":
            compared += 1
            assert abs(problem.cost(fast.y) - problem.cost(ref.y)) <= 1e-2 * problem.cost(ref.y)
    assert compared >= 8  # both optimal on all 10 now: the check compares, not skips


class _Failing:
    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        return SolveResult(np.zeros(6), "failed", 1, np.zeros(1))


class _Crashing:
    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        raise RuntimeError("injected")


class _Slow:
    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        time.sleep(0.06)
        return SqpSolver()(problem, y_start, np.inf)


def _stalled_case(model: PairValueModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A state whose goal lies straight through the peer's level set: Opt stops at it."""
    q1, q2, _ = _near_contact(model, 5, 1)[0]
    _, g = model.evaluate(0.1, np.concatenate([q1, q2])[None])
    return q1, q2, q1 - 1.5 * g[0, :6] / np.abs(g[0, :6]).max()


def _closed_loop(planner: NehmoPlanner, q1, q2, goal, ticks: int) -> list:
    """The own arm integrates its commands over 0.04 s ticks; the peer stands still."""
    out = []
    for _ in range(ticks):
        result = planner.plan(q1, {PEER: q2}, goal)
        out.append((q1.copy(), result))
        q1 = q1 + 0.04 * result.velocity
    return out


def test_stall_escape_moves_along_the_level_set_and_keeps_the_constraint(model) -> None:
    q1, q2, goal = _stalled_case(model)
    settings = PlannerSettings(deadline=1.0, stall_ticks=5, escape_ticks=10)
    stuck = _closed_loop(
        NehmoPlanner(CELL, OWN, [model], settings.replace(escape=False)), q1, q2, goal, 60
    )
    tail = np.array([q for q, _ in stuck[-20:]])
    assert np.abs(tail - tail[-1]).max() < 1e-3  # without the escape the arm stops for good
    assert np.linalg.norm(tail[-1] - goal) > 0.1
    assert not any(r.telemetry.escaping for _, r in stuck)
    planner = NehmoPlanner(CELL, OWN, [model], settings)
    run = _closed_loop(planner, q1, q2, goal, 60)
    escaping = [i for i, (_, r) in enumerate(run) if r.telemetry.escaping]
    assert escaping, "the stall was not detected"
    first = escaping[0]
    assert escaping[:10] == list(range(first, first + 10))  # one escape lasts escape_ticks
    moved = np.linalg.norm(run[first + 9][0] - run[first][0])
    assert moved > 0.05  # [rad]: it left the stall point
    for _, r in run:
        if not r.telemetry.fail_safe:
            assert r.telemetry.min_constraint >= -1e-6  # every step, escaping or not, is safe
    # deterministic, and reset() clears the escape state
    planner.reset()
    again = _closed_loop(planner, q1, q2, goal, 60)
    np.testing.assert_array_equal(
        np.array([r.velocity for _, r in again]), np.array([r.velocity for _, r in run])
    )


def test_escape_length_doubles_until_the_goal_error_reaches_a_new_low(model) -> None:
    settings = PlannerSettings(stall_ticks=3, escape_ticks=4, stall_progress=0.1)
    planner = NehmoPlanner(CELL, OWN, [model], settings)
    assert settings.t_plan * settings.u_max == pytest.approx(0.05)  # progress: > 0.005 rad/call

    def feed(errors: list[float]) -> list[int]:
        left = []
        for e in errors:
            planner.stage("escape").track(np.array([e, 0, 0, 0, 0, 0]), pressed=True)
            left.append(planner.stage("escape").escape_left)
        return left

    feed([1.0, 0.9])  # progress toward a new low
    assert feed([0.9, 0.9, 0.9]) == [0, 0, 4]  # stalled for stall_ticks calls: escape 4 calls
    assert feed([1.0, 1.1, 1.2, 1.2]) == [3, 2, 1, 0]
    # back to the trap, making progress on the way but never below the best error (0.9)
    assert feed([1.1, 1.0, 0.9, 0.9, 0.9, 0.9]) == [0, 0, 0, 0, 0, 8]  # same trap: 2× longer
    feed([1.2] * 8)
    assert feed([1.1, 1.0, 0.9, 0.9, 0.9, 0.9]) == [0, 0, 0, 0, 0, 16]  # 4×, the cap
    feed([1.2] * 16)
    feed([1.0, 0.8, 0.7])  # a new low: the next trap starts over
    assert feed([0.7, 0.7, 0.7]) == [0, 0, 4]


def test_an_arm_held_at_its_goal_against_a_peer_yields_then_returns(model) -> None:
    rng = np.random.default_rng(7)
    robot = CELL.arm(OWN).robot
    settings = PlannerSettings(deadline=1.0, stall_ticks=5, yield_ticks=8)
    planner = NehmoPlanner(CELL, OWN, [model], settings)
    while True:  # the own arm at its goal, the peer pressing it (V row within stall_margin)
        q1, q2 = sample_configuration(robot, rng), sample_configuration(robot, rng)
        problem = planner.problem(np.zeros(6), planner.current(q1, {PEER: q2}))
        c_still, _ = problem.constraints.evaluate(np.zeros(6))
        if 0.0 <= c_still[0] < 0.005:
            break
    run = _closed_loop(planner, q1, q2, q1.copy(), 40)
    flags = [r.telemetry.escaping for _, r in run]
    assert not any(flags[:5]) and flags[5:13] == [True] * 8  # yields after stall_ticks
    v = [model.evaluate(0.1, np.concatenate([q, q2])[None])[0][0] for q, _ in run]
    assert v[13] > v[5] + 0.005  # it made room: V against the peer grew while yielding
    assert np.linalg.norm(run[-1][0] - q1) < np.linalg.norm(run[13][0] - q1)  # and went back


def test_paper_preset_and_kind_have_no_escape(model) -> None:
    assert PlannerSettings().escape
    assert not PlannerSettings.preset("paper").escape
    from nehmo_core.planning.factory import make_planner

    planner = make_planner("nehmo_paper", CELL, OWN, [model])
    assert isinstance(planner, NehmoPlanner) and not planner.settings.escape


@pytest.mark.parametrize(
    ("solver", "status"), [(_Failing(), "failed"), (_Crashing(), "failed (RuntimeError)")]
)
def test_fail_safe_fires_on_solver_failure(model, value_function, solver, status) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED, solver=solver)
    q1, q2, goal = _near_contact(model, 6, 1)[0]
    result = planner.plan(q1, {PEER: q2}, goal)
    assert result.telemetry.fail_safe and result.telemetry.status == status
    _, grad = value_function.value_and_gradient(0.1, np.concatenate([q1, q2]))
    np.testing.assert_array_equal(result.velocity, 0.5 * np.sign(grad[:6]))
    assert result.telemetry.critical_peer == PEER


class _Recording:
    """The SQP, recording each call's start; fails the calls listed in ``fail``."""

    def __init__(self, fail: set[int]) -> None:
        self.fail, self.starts, self.naive = fail, [], []

    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        self.starts.append(y_start.copy())
        self.naive.append(problem.naive_step())
        if len(self.starts) - 1 in self.fail:
            return SolveResult(np.zeros(6), "failed", 1, np.zeros(1))
        return SqpSolver()(problem, y_start, np.inf, hessian)


def test_a_solve_starts_at_the_last_solution_or_after_a_fail_safe_at_the_naive_step(model) -> None:
    solver = _Recording(fail={1})
    planner = NehmoPlanner(CELL, OWN, [model], UNHURRIED, solver=solver)
    q1, q2, goal = _near_contact(model, 6, 1)[0]
    results = []
    for _ in range(4):
        results.append(planner.plan(q1, {PEER: q2}, goal))
        q1 = q1 + 0.1 * results[-1].velocity
    assert [r.telemetry.fail_safe for r in results] == [False, True, False, False]
    np.testing.assert_array_equal(solver.starts[0], solver.naive[0])  # after reset()
    np.testing.assert_allclose(solver.starts[1], 0.1 * results[0].velocity, atol=1e-12)
    np.testing.assert_array_equal(solver.starts[2], solver.naive[2])  # not the fail-safe's corner
    np.testing.assert_allclose(solver.starts[3], 0.1 * results[2].velocity, atol=1e-12)


def test_fail_safe_fires_on_a_missed_deadline(model, value_function) -> None:
    planner = NehmoPlanner(CELL, OWN, [model], PlannerSettings(deadline=0.04), solver=_Slow())
    q1, q2, goal = _near_contact(model, 7, 1)[0]
    result = planner.plan(q1, {PEER: q2}, goal)
    assert result.telemetry.fail_safe and result.telemetry.status == "timeout"
    assert result.telemetry.solve_time > 0.04
    _, grad = value_function.value_and_gradient(0.1, np.concatenate([q1, q2]))
    np.testing.assert_array_equal(result.velocity, 0.5 * np.sign(grad[:6]))


def test_fail_safe_deadband_stills_only_the_joints_that_barely_change_v(
    model, value_function
) -> None:
    settings = PlannerSettings(fail_safe_deadband=0.3)
    planner = NehmoPlanner(CELL, OWN, [model], settings, solver=_Failing())
    q1, q2, goal = _near_contact(model, 6, 1)[0]
    result = planner.plan(q1, {PEER: q2}, goal)
    _, grad = value_function.value_and_gradient(0.1, np.concatenate([q1, q2]))
    g = grad[:6]
    dead = np.abs(g) < 0.3 * np.abs(g).max()
    assert dead.any() and not dead.all()
    np.testing.assert_array_equal(result.velocity[dead], 0.0)
    np.testing.assert_array_equal(result.velocity[~dead], 0.5 * np.sign(g[~dead]))
    # the first-order rate of V under the deadband fail-safe stays positive (it still evades)
    assert float(g @ result.velocity) > 0.0
    with pytest.raises(InvalidValueError, match="fail_safe_deadband"):
        PlannerSettings(fail_safe_deadband=1.0)


def test_fail_safe_picks_the_most_critical_of_several_peers(model) -> None:
    cell = load_cell("triple_ur5")
    planner = NehmoPlanner(cell, "ur5_0", [model], UNHURRIED, solver=_Failing())
    rng = np.random.default_rng(8)
    robot = cell.arm("ur5_0").robot
    q = {a: sample_configuration(robot, rng) for a in cell.arm_ids}
    result = planner.plan(q["ur5_0"], {a: q[a] for a in ("ur5_1", "ur5_2")}, q["ur5_0"] + 1.0)
    values = {
        p: model.evaluate(0.1, m.state(q["ur5_0"], q[p])[None]) for p, m in planner.pairs.items()
    }
    critical = min(planner.pairs, key=lambda p: values[p][0][0])
    assert result.telemetry.critical_peer == critical
    np.testing.assert_array_equal(result.velocity, 0.5 * np.sign(values[critical][1][0, :6]))


@pytest.mark.parametrize(
    ("changes", "parameter"),
    [
        ({"epsilon": -0.1}, "epsilon"),
        ({"t_plan": 0.0}, "t_plan"),
        ({"t_plan": 0.4}, "t_plan"),
        ({"u_max": 0.0}, "u_max"),
        ({"d_max": -1.0}, "d_max"),
        ({"deadline": 0.0}, "deadline"),
        ({"sqp_max_iter": 0}, "sqp_max_iter"),
        ({"reach_margin": -1.0}, "reach_margin"),
        ({"stall_ticks": 0}, "stall_ticks"),
        ({"escape_ticks": 0}, "escape_ticks"),
        ({"stall_progress": -0.1}, "stall_progress"),
    ],
)
def test_bad_settings_are_rejected_naming_the_parameter(changes, parameter) -> None:
    with pytest.raises(InvalidValueError, match=f"`{parameter}`"):
        PlannerSettings(**changes)


def test_unknown_choices_list_the_valid_ones(model) -> None:
    with pytest.raises(UnknownNameError, match="ipopt"):
        PlannerSettings(solver="snopt")
    with pytest.raises(UnknownNameError, match="paper"):
        PlannerSettings.preset("fast")
    with pytest.raises(InvalidValueError, match="`t_safe`"):
        NehmoPlanner(CELL, OWN, [model], PlannerSettings(t_safe=0.7))
    with pytest.raises(InvalidValueError, match="`q_self`"):
        NehmoPlanner(CELL, OWN, [model], UNHURRIED).plan(
            np.zeros(5), {PEER: np.zeros(6)}, np.zeros(6)
        )
    with pytest.raises(InvalidValueError, match="`peers`"):
        NehmoPlanner(CELL, OWN, [model], UNHURRIED).plan(np.zeros(6), {}, np.zeros(6))


class _Switchable:
    """The SQP solver until ``fail`` is set, then a failing one."""

    def __init__(self) -> None:
        self.fail = False

    def __call__(
        self, problem: OptProblem, y_start: np.ndarray, deadline: float, hessian=None
    ) -> SolveResult:
        if self.fail:
            return SolveResult(np.zeros(6), "failed", 1, np.zeros(1))
        return SqpSolver()(problem, y_start, np.inf, hessian)


def _into_an_escape(planner: NehmoPlanner, q1, q2, goal) -> np.ndarray:
    """Run the closed loop until the first escaping tick; the own state after that tick."""
    for _ in range(60):
        result = planner.plan(q1, {PEER: q2}, goal)
        q1 = q1 + 0.04 * result.velocity
        if result.telemetry.escaping:
            assert planner.stage("escape").escape_left > 0  # the escape goes on for more calls
            return q1
    raise AssertionError("the stall was not detected")


def test_a_new_goal_ends_an_escape_and_is_followed_at_once(model) -> None:
    q1, q2, goal = _stalled_case(model)
    settings = PlannerSettings(deadline=1.0, stall_ticks=5, escape_ticks=10)
    planner = NehmoPlanner(CELL, OWN, [model], settings)
    # the same goal (equal values, another object) keeps a running escape going
    q = _into_an_escape(planner, q1, q2, goal)
    assert planner.plan(q, {PEER: q2}, goal.tolist()).telemetry.escaping
    planner.reset()
    q = _into_an_escape(planner, q1, q2, goal)
    # a goal up V's gradient (away from the peer): the unconstrained step toward it is safe
    _, g = model.evaluate(0.1, np.concatenate([q, q2])[None])
    new_goal = q + 0.3 * np.sign(g[0, :6])
    result = planner.plan(q, {PEER: q2}, new_goal)
    assert not result.telemetry.escaping and not result.telemetry.fail_safe
    toward = new_goal - q
    cosine = result.velocity @ toward / np.linalg.norm(result.velocity) / np.linalg.norm(toward)
    assert cosine > 0.9
    # the stall and escape state restarted from the new goal
    escape = planner.stage("escape")
    assert escape.escape_left == 0 and escape.stall == 0 and escape.escapes == 0  # type: ignore[attr-defined]
    assert escape.best_error == pytest.approx(np.linalg.norm(q - new_goal))  # type: ignore[attr-defined]


def test_fail_safe_ticks_during_an_escape_are_not_reported_as_escaping(model) -> None:
    q1, q2, goal = _stalled_case(model)
    solver = _Switchable()
    settings = PlannerSettings(deadline=1.0, stall_ticks=5, escape_ticks=10)
    planner = NehmoPlanner(CELL, OWN, [model], settings, solver=solver)
    q = _into_an_escape(planner, q1, q2, goal)
    solver.fail = True
    result = planner.plan(q, {PEER: q2}, goal)
    assert result.telemetry.fail_safe and not result.telemetry.escaping
    assert (
        planner.stage("escape").escape_left > 0
    )  # the escape itself goes on after the fail-safe tick


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
        ({"self_safety": -0.01}, "self_safety", "must be >= 0"),
        ({"self_safety": math.nan}, "self_safety", "must be >= 0"),
        ({"self_influence": 0.004}, "self_influence", "must be > self_safety (0.005)"),
        ({"escape_seed": -1}, "escape_seed", "must be >= 0"),
        ({"escape_seed": 1.5}, "escape_seed", "must be an int >= 0"),
        ({"sqp_max_iter": 2.5}, "sqp_max_iter", "must be an int >= 1"),
        ({"sqp_max_iter": math.nan}, "sqp_max_iter", "must be an int >= 1"),
        ({"sqp_max_iter": True}, "sqp_max_iter", "must be an int >= 1"),
        ({"ipopt_max_iter": 30.0}, "ipopt_max_iter", "must be an int >= 1"),
        ({"stall_ticks": 2.5}, "stall_ticks", "must be an int >= 1"),
        ({"stall_ticks": math.nan}, "stall_ticks", "must be an int >= 1"),
        ({"escape_ticks": 2.5}, "escape_ticks", "must be an int >= 1"),
        ({"yield_ticks": math.inf}, "yield_ticks", "must be an int >= 1"),
    ],
)
def test_bad_counts_and_self_clearance_settings_name_their_own_rule(
    changes, parameter, rule
) -> None:
    with pytest.raises(InvalidValueError, match=re.escape(f"`{parameter}` {rule}; got")):
        PlannerSettings(**changes)


def test_whole_counts_and_seeds_are_accepted() -> None:
    s = PlannerSettings(sqp_max_iter=1, stall_ticks=3, escape_seed=0, self_safety=0.0)
    assert (s.sqp_max_iter, s.stall_ticks, s.escape_seed, s.self_safety) == (1, 3, 0, 0.0)
    assert PlannerSettings(escape_seed=2**40).escape_seed == 2**40


def test_the_fail_safe_and_the_solve_of_one_state_share_one_evaluation(model) -> None:
    """A node asks for the fail-safe ahead of each solve from the same state: the solve reuses
    that evaluation of V at t_plan and answers as a planner that was not asked first."""
    planner, fresh = (
        NehmoPlanner(CELL, OWN, [model], UNHURRIED),
        NehmoPlanner(CELL, OWN, [model], UNHURRIED),
    )
    q1, q2, goal = _near_contact(model, 8, 1)[0]
    evaluations = []
    evaluate = planner.opt.evaluate

    def counted(*args):  # type: ignore[no-untyped-def]
        evaluations.append(args)
        return evaluate(*args)

    planner.opt.evaluate = counted  # type: ignore[method-assign]
    planner.fail_safe(q1, {PEER: q2})
    first = planner.plan(q1, {PEER: q2}, goal)
    assert len(evaluations) == 1
    alone = fresh.plan(q1, {PEER: q2}, goal)
    np.testing.assert_array_equal(first.velocity, alone.velocity)
    assert first.telemetry.status == alone.telemetry.status
    planner.plan(q1, {PEER: q2 + 0.01}, goal)  # the peer moved: a new state
    planner.plan(q1 + 0.01, {PEER: q2 + 0.01}, goal)  # this arm moved
    assert len(evaluations) == 3
