"""The maximin fail-safe: the LP optimum over every critical peer, the paper's command for one,
a critical set with hysteresis, and in closed loop an arm between two peers that push toward it
(exact geometry) chatters less and collides no more often than the single-pair fail-safe; the
lexicographic tolerance (``fail_safe_slack``) and the limit on how fast the arm may lower any
pair (``fail_safe_harm``) against an LP, and three five-UR5 scenarios where an earlier fail-safe
drove an arm into a peer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.stages.fail_safe import MaximinFailSafe, maximin_command, worst_case_rates
from nehmo_core.robots import load_cell
from nehmo_core.sim.cell_sim import CellSimulator
from nehmo_core.sim.scenario_files import load_scenario_set

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


def _predicted(u: np.ndarray, own: np.ndarray, peer: np.ndarray, values: np.ndarray) -> np.ndarray:
    return values + TAU * worst_case_rates(u, own, peer, D)


def _lp_second(own: np.ndarray, peer: np.ndarray, values: np.ndarray, floor: float) -> float:
    """max_u V_2 + τ·rate_2(u) s.t. V_1 + τ·rate_1(u) ≥ floor (two pairs; HiGHS)."""
    n = own.shape[1]
    limits = values - TAU * D * np.abs(peer).sum(axis=1)
    res = linprog(-TAU * own[1], A_ub=-TAU * own[:1], b_ub=limits[:1] - floor, bounds=[(-U, U)] * n)
    assert res.success
    return float(-res.fun + limits[1])


SLACK = 0.005  # [m] fail_safe_slack in the lexicographic tests


def _lexicographic_case(
    seed: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float, int, float, float]:
    """Two pairs where the order matters, found by HiGHS alone: the worst pair binds at the
    maximin optimum ``best`` while the other does not (it is free to take more), and giving up
    ``SLACK`` on the worst pair buys the other at least 1 mm more. Returns own, peer, values,
    best, the worst pair's index, the other pair's value at the maximin optimum (``forced``) and
    its lexicographic optimum (``second``)."""
    rng = np.random.default_rng(100 + seed)
    for _ in range(200):
        own, peer = rng.normal(size=(2, 6)), rng.uniform(0.0, 1.0, size=(2, 6))
        own[0] *= rng.uniform(0.01, 1.0)  # a pair the arm can barely move, now and then
        values = rng.uniform(0.0, 0.1, size=2)
        best = _lp_optimum(own, peer, values)
        # each pair's own maximum over the box: V + τ·(ū‖g‖₁ − d̄‖h‖₁)
        alone = values + TAU * (U * np.abs(own).sum(axis=1) - D * np.abs(peer).sum(axis=1))
        worst = int(np.argmin(alone))
        if alone[worst] > best + 1e-6:  # both pairs bind at the optimum: nothing to order
            continue
        order = [worst, 1 - worst]
        forced = _lp_second(own[order], peer[order], values[order], best - 1e-9)
        second = _lp_second(own[order], peer[order], values[order], best - SLACK)
        if forced > best + 1e-3 and second > forced + 1e-3:
            return own, peer, values, best, worst, forced, second
    raise AssertionError(f"seed {seed}: no two-pair case where the order matters")


@pytest.mark.parametrize("seed", range(8))
def test_the_lexicographic_command_gives_up_at_most_slack_on_the_worst_pair(seed: int) -> None:
    own, peer, values, best, worst, forced, second = _lexicographic_case(seed)

    def lexicographic(predicted: np.ndarray) -> bool:
        """The worst pair within SLACK of the maximin optimum, the other at its best then."""
        return bool(
            predicted[worst] >= best - SLACK - 2e-4 and predicted[1 - worst] >= second - 2e-4
        )

    lexi = _predicted(maximin_command(own, peer, U, D, values, TAU, slack=SLACK), own, peer, values)
    assert lexicographic(lexi), (lexi, best, second)
    assert lexi.min() >= best - SLACK - 2e-4
    # plain maximin (the slack ignored) holds the worst pair at the optimum, so the other gets
    # no more than it can have then: the check above tells it apart
    plain = _predicted(maximin_command(own, peer, U, D, values, TAU), own, peer, values)
    assert plain[worst] == pytest.approx(best, abs=2e-4)
    assert plain[1 - worst] <= forced + 2e-4
    assert not lexicographic(plain), (plain, best, second)


def test_an_arm_does_not_sacrifice_a_pair_it_controls_for_one_it_cannot() -> None:
    # seed 35, five-UR5 episode 61, 0.44 s before contact: the centre arm's pair with ur5_4 (V
    # 0.038 m) barely moves with its own joints while ur5_4 can lower it at 0.41 m/s; its pair with
    # ur5_2 (V 0.066 m) is the one its own joints control
    own = np.array(
        [[0.002, 0.009, 0.007, 0.0, -0.002, -0.001], [-0.306, -0.22, -0.327, -0.079, 0.001, 0.0]]
    )
    peer = np.array([[0.83, 0, 0, 0, 0, 0], [0.209, 0, 0, 0, 0, 0]])
    values = np.array([0.0375, 0.0658])
    plain = _predicted(maximin_command(own, peer, U, D, values, TAU), own, peer, values)
    lexi = _predicted(maximin_command(own, peer, U, D, values, TAU, slack=0.005), own, peer, values)
    assert plain[1] < 0.02  # plain maximin spends every joint on 2 mm of the first pair
    assert lexi[0] >= plain[0] - 0.005 - 1e-9
    assert lexi[1] > 0.09


def _lp_limited(own: np.ndarray, peer: np.ndarray, values: np.ndarray, harm: float) -> float:
    """The maximin optimum with every own rate ≥ −harm (HiGHS)."""
    k, n = own.shape
    cost = np.zeros(n + 1)
    cost[n] = -1.0
    rows = np.vstack([np.hstack([-TAU * own, np.ones((k, 1))]), np.hstack([-own, 0 * own[:, :1]])])
    limits = np.concatenate([values - TAU * D * np.abs(peer).sum(axis=1), np.full(k, harm)])
    res = linprog(cost, A_ub=rows, b_ub=limits, bounds=[(-U, U)] * n + [(None, None)])
    assert res.success
    return float(-res.fun)


@pytest.mark.parametrize("seed", range(8))
@pytest.mark.parametrize("harm", [0.0, 0.05])
def test_with_a_harm_limit_no_pair_is_lowered_faster_and_the_rest_is_maximin(
    seed: int, harm: float
) -> None:
    rng = np.random.default_rng(200 + seed)
    k = 2 + seed % 3
    own, peer = rng.normal(size=(k, 6)), 0.2 * rng.normal(size=(k, 6))
    own[1] = -own[0] + 0.2 * rng.normal(size=6)  # two peers on opposite sides
    values = rng.uniform(0.0, 0.1, size=k)
    u = maximin_command(own, peer, U, D, values, TAU, harm=harm)
    assert np.all(np.abs(u) <= U + 1e-12)
    assert np.all(own @ u >= -harm - 1e-6)
    best = _lp_limited(own, peer, values, harm)
    assert _predicted(u, own, peer, values).min() == pytest.approx(best, abs=2e-4)
    # without the limit the same pairs may be traded: the limit is what holds them
    assert _lp_optimum(own, peer, values) >= best - 1e-9


def test_a_negative_harm_is_rejected() -> None:
    with pytest.raises(InvalidValueError, match="harm"):
        maximin_command(np.eye(2, 6), np.ones((2, 6)), U, D, np.zeros(2), TAU, harm=-0.1)
    with pytest.raises(InvalidValueError, match=r"fail_safe\.harm"):
        PlannerSettings().override({"fail_safe.harm": -0.001})


def test_a_negative_slack_is_rejected() -> None:
    with pytest.raises(InvalidValueError, match="slack"):
        maximin_command(np.eye(2, 6), np.ones((2, 6)), U, D, np.zeros(2), TAU, slack=-0.1)
    with pytest.raises(InvalidValueError, match=r"fail_safe\.slack"):
        PlannerSettings().override({"fail_safe.slack": -0.001})


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
        PlannerSettings().override({"fail_safe.kind": "both"})


# ------------------------------------------------------------------------- closed loop
CELL = load_cell("triple_ur5")
PEERS = ("ur5_0", "ur5_2")


@pytest.fixture(scope="module")
def planners() -> dict[str, NehmoPlanner]:
    models = ModelRegistry().models_for("nehmo", CELL)
    return {
        kind: NehmoPlanner(
            CELL,
            "ur5_1",
            models,
            PlannerSettings().override({"fail_safe.kind": kind, "self_clearance.enabled": False}),
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
        now = planner.current(q["ur5_1"], {p: q[p] for p in PEERS})
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
        now = planner.current(q["ur5_1"], {p: q[p] for p in PEERS})
        u = planner.stage("fail_safe").command(now, planner.settings.opt.u_max)
        commands = {"ur5_1": u}
        for i, peer in enumerate(now.ids):
            commands[peer] = -D * np.sign(now.grads[i][6:])
        if previous is not None and np.sum(np.sign(u) != np.sign(previous)) >= 3:
            flips += 1
        previous = u
        if any("ur5_1" in (c.arm_a, c.arm_b) for c in sim.step(commands, dt).collisions):
            return True, flips
    return False, flips


def test_an_arm_between_two_pushing_peers_chatters_less_and_collides_no_more_often(
    planners: dict[str, NehmoPlanner],
) -> None:
    states = _sandwiched_states(planners["single"], seed=5, count=12)
    assert len(states) == 12
    results = {k: [_episode(p, q) for q in states] for k, p in planners.items()}
    single, maximin = results["single"], results["maximin"]
    # against two real adversaries a collision is often unavoidable; the lexicographic
    # tolerance may trade one state for another, but never collides more often in sum
    assert sum(h for h, _ in maximin) <= sum(h for h, _ in single)
    assert sum(f for _, f in maximin) < 0.5 * sum(f for _, f in single)


SANDWICHED = Path(__file__).parents[1] / "data" / "sandwiched"


# the fail-safe each scenario was found with, which drove an arm into a peer (None: none did)
EARLIER = {
    "five_ur5_seed34_0076": None,  # plain maximin, no longer in contact since settled arms
    # tell announcing peers from silent ones
    "five_ur5_seed35_0061": {"fail_safe.slack": 0.0, "fail_safe.harm": 100.0},  # plain maximin
    "five_ur5_seed41_0045": {"fail_safe.harm": 100.0},  # lexicographic, no limit on the trade
}


@pytest.mark.parametrize("name", sorted(EARLIER))
def test_five_arms_where_an_earlier_fail_safe_collided_stay_apart(name: str) -> None:
    """Fresh-seed five-UR5 scenarios (tables of seeds 34, 35 and 41) where an arm between two
    peers drove into one of them on an earlier fail-safe: plain maximin (seeds 34 and 35), and
    the lexicographic one, which lowered the pair with ur5_4 at up to 0.48 m/s to gain 0.09 m/s
    on the pair with ur5_1 (seed 41). The earlier fail-safe still collides where it is given,
    so the test can fail; with the defaults no arm touches another."""
    scenarios = load_scenario_set(SANDWICHED / f"{name}.json")
    cell = load_cell("five_ur5")
    scenario = scenarios.scenarios[0]
    settings = EpisodeSettings(time_limit=10.0)
    variants = {"default": {}, "earlier": EARLIER[name]}
    outcomes = {}
    for kind, changes in variants.items():
        if changes is None:
            continue
        unhurried = PlannerSettings().override({"opt.deadline": 3600.0, **changes})
        planners = build_planners(
            cell, {a: "nehmo" for a in cell.arm_ids}, scenario, 0.04, ModelRegistry(), unhurried
        )
        result = run_episode(cell, scenario, planners, settings)
        outcomes[kind] = [c for c in result.collisions if c.arm_a != c.arm_b]
    if "earlier" in outcomes:
        assert outcomes["earlier"], "the scenario no longer reproduces the earlier collision"
    assert not outcomes["default"]
