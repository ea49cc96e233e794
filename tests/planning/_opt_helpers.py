"""Shared by the tests of problem Opt and its solvers (``test_opt_*``, ``test_sqp_*``,
``test_planner_*``): the dual-UR5 cell, a random pair value model, and states where the
constraint is active.

The fixtures ``value_function`` and ``model`` are module-scoped; a test module binds them under
their names (``model = _opt_helpers.model``) so that pytest finds them.
"""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.hjr.networks import NetworkSettings
from nehmo_core.planning.models.synthetic import random_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import sample_configuration

CELL = load_cell("dual_ur5")
UNHURRIED = PlannerSettings().override(
    {"opt.deadline": 3600.0}
)  # statuses never depend on the machine's load
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
