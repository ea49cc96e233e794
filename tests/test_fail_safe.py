"""The maximin fail-safe: the LP optimum over every critical peer, the paper's command for one,
a critical set with hysteresis, and in closed loop an arm between two peers that push toward it
(exact geometry) chatters less and never collides where the single-pair fail-safe does not."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.optimize import linprog

from nehmo_core.errors import UnknownNameError
from nehmo_core.planning.fail_safe import MaximinFailSafe, maximin_command, worst_case_rates
from nehmo_core.planning.models import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.cell_sim import CellSimulator

U, D = 0.5, 0.5


TAU = 0.1


def _lp_optimum(own: np.ndarray, peer: np.ndarray, values: np.ndarray) -> float:
    """max_u min_i (V_i + τ·rate_i(u)) over the box, by scipy's HiGHS (an independent solver)."""
    k, n = own.shape
    cost = np.zeros(n + 1)
    cost[n] = -1.0
    rows = np.hstack([-TAU * own, np.ones((k, 1))])
    limits = values - TAU * D * np.abs(peer).sum(axis=1)
    res = linprog(cost, A_ub=rows, b_ub=limits, bounds=[(-U, U)] * n + [(None, None)])
    assert res.success
    return float(-res.fun)


@pytest.mark.parametrize("seed", range(8))
def test_maximin_reaches_the_lp_optimum_and_beats_each_single_pair_command(seed: int) -> None:
    rng = np.random.default_rng(seed)
    k = 2 + seed % 3
    own, peer = rng.normal(size=(k, 6)), 0.2 * rng.normal(size=(k, 6))
    own[1] = -own[0] + 0.2 * rng.normal(size=6)  # two peers on opposite sides
    values = rng.uniform(0.0, 0.1, size=k)

    def predicted(u: np.ndarray) -> float:
        return float((values + TAU * worst_case_rates(u, own, peer, D)).min())

    u = maximin_command(own, peer, U, D, values, TAU)
    assert np.all(np.abs(u) <= U + 1e-12)
    assert predicted(u) == pytest.approx(_lp_optimum(own, peer, values), abs=2e-4)
    for g in own:  # the paper's command for any one pair does no better on the worst pair
        assert predicted(u) >= predicted(U * np.sign(g)) - 1e-9


def test_with_one_pair_it_is_the_papers_command() -> None:
    g = np.array([0.3, -0.1, 0.0, 2.0, -0.5, 0.01])
    np.testing.assert_array_equal(maximin_command(g[None], np.ones((1, 6)), U, D), U * np.sign(g))


def test_the_critical_set_holds_a_member_until_twice_the_band() -> None:
    chooser = MaximinFailSafe(band=0.05)
    ids = ["a", "b"]
    assert chooser.critical(ids, np.array([0.10, 0.14])) == [0, 1]
    assert chooser.critical(ids, np.array([0.10, 0.18])) == [0, 1]  # b stays (within 0.10)
    assert chooser.critical(ids, np.array([0.10, 0.21])) == [0]  # b leaves beyond 2·band
    assert chooser.critical(ids, np.array([0.10, 0.18])) == [0]  # and joins only within band


def test_an_unknown_fail_safe_is_rejected() -> None:
    with pytest.raises(UnknownNameError, match="fail_safe"):
        PlannerSettings(fail_safe="both")


# ------------------------------------------------------------------------- closed loop
CELL = load_cell("triple_ur5")
PEERS = ("ur5_0", "ur5_2")


@pytest.fixture(scope="module")
def planners() -> dict[str, NehmoPlanner]:
    models = ModelRegistry().models_for("nehmo", CELL)
    return {
        kind: NehmoPlanner(
            CELL, "ur5_1", models, PlannerSettings(fail_safe=kind, self_clearance=False)
        )
        for kind in ("single", "maximin")
    }


def _sandwiched_states(planner: NehmoPlanner, seed: int, count: int) -> list[dict]:
    """Collision-free states where the centre arm's values to both outer arms are low and
    close, and the two pairs' gradients in the centre arm's joints oppose each other."""
    rng = np.random.default_rng(seed)
    robot = CELL.arm("ur5_1").robot
    lo, hi = np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi)
    sim = CellSimulator(CELL, substeps=1, self_collision=False)
    found: list[dict] = []
    for _ in range(200_000):
        q = {a: rng.uniform(lo, hi) for a in CELL.arm_ids}
        now = planner._current(q["ur5_1"], {p: q[p] for p in PEERS})
        v = now.values
        if not (v.min() > 0.02 and v.max() < 0.25 and abs(v[0] - v[1]) < 0.05):
            continue
        if float(now.grads[0][:6] @ now.grads[1][:6]) >= 0:
            continue
        sim.reset(q)
        if not sim.collisions():
            found.append(q)
            if len(found) == count:
                break
    return found


def _episode(planner: NehmoPlanner, q0: dict, ticks: int = 25, dt: float = 0.04) -> tuple:
    """The centre arm on its fail-safe, both outer arms on the worst case against it, 1 s:
    (collided, ticks whose command flipped sign on 3 or more joints)."""
    planner.reset()
    sim = CellSimulator(CELL, substeps=4, self_collision=False)
    sim.reset(q0)
    flips, previous = 0, None
    for _ in range(ticks):
        q = sim.positions()
        now = planner._current(q["ur5_1"], {p: q[p] for p in PEERS})
        u = planner._hji_fail_safe(now, planner.settings.u_max)
        commands = {"ur5_1": u}
        for i, peer in enumerate(now.ids):
            commands[peer] = -D * np.sign(now.grads[i][6:])
        if previous is not None and np.sum(np.sign(u) != np.sign(previous)) >= 3:
            flips += 1
        previous = u
        if any("ur5_1" in (c.arm_a, c.arm_b) for c in sim.step(commands, dt).collisions):
            return True, flips
    return False, flips


def test_an_arm_between_two_pushing_peers_chatters_less_and_never_collides_more(
    planners: dict[str, NehmoPlanner],
) -> None:
    states = _sandwiched_states(planners["single"], seed=5, count=12)
    assert len(states) == 12
    results = {k: [_episode(p, q) for q in states] for k, p in planners.items()}
    single, maximin = results["single"], results["maximin"]
    for (hit_single, _), (hit_maximin, _) in zip(single, maximin, strict=True):
        assert hit_single or not hit_maximin  # no collision the single-pair fail-safe avoids
    assert sum(f for _, f in maximin) < 0.5 * sum(f for _, f in single)
