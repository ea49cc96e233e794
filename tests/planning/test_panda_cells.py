"""The Panda (7 joints, every joint limited) and the Kinova through the planner with the pair
models that ``nehmo pair build`` made: every cell of built pairs (two Pandas, a UR5 and a Panda,
two Kinovas, a UR5, a Kinova and a Panda, a UR5 and a Kinova 1.8 m apart) stays apart in closed
loop."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.eval.setups import get_setup
from nehmo_core.hjr import load_value_function
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell, load_robot, registry
from nehmo_core.sim.scenarios import generate_scenario_set

SEED = 7  # scenarios of this test only (evaluation seeds: docs/adding-a-robot.md)


CELL_PAIRS = {
    "dual_panda": {"panda_panda_any"},
    "ur5_panda": {"ur5_panda_any", "panda_ur5_any"},
    "dual_kinova": {"kinova_gen3_6dof_kinova_gen3_6dof_any"},
    "mixed_three": {"kinova_gen3_6dof_panda_any", "panda_kinova_gen3_6dof_any"},
    "triangle_ur5_kinova": {"ur5_kinova_gen3_6dof_far", "kinova_gen3_6dof_ur5_far"},
}
"""Cells of built pairs and the pairs each needs."""


def _cells() -> list[str]:
    have = set(registry.PAIR_NAMES)
    return [cell for cell, pairs in CELL_PAIRS.items() if pairs <= have]


def test_the_pairs_of_every_such_cell_ship() -> None:
    assert _cells() == list(CELL_PAIRS)


def test_the_panda_pairs_ship() -> None:
    assert "panda_panda_any" in registry.PAIR_NAMES
    assert registry.arm_pair("panda_panda_any").domain == "limits"
    low, high = registry.pair_base_range("panda_panda_any")
    assert low <= 0.3 and high >= 1.95  # two Pandas touch up to 2 x 0.96 m apart


def test_limited_joints_span_their_limits_and_the_base_yaw_wraps() -> None:
    """The Panda's joints are limited: its models span each joint's limits widened by 0.3 rad,
    except joint 1, which also turns with the layout (the pair frame shifts it) and wraps; the
    compiled model wraps it as the torch model does."""
    vf = load_value_function("panda_panda_any", variant="bc")
    system, robot = vf.system, load_robot("panda")
    periodic = np.array(system.periodic[:14])
    assert periodic[[0, 7]].all() and not periodic[[1, 2, 3, 4, 5, 6, 8, 13]].any()
    np.testing.assert_allclose(system.lower[1:7], robot.lower[1:] - 0.3)
    np.testing.assert_allclose(system.upper[1:7], robot.upper[1:] + 0.3)
    assert system.upper[5] > np.pi  # joint 6 reaches 3.75 rad
    model = PairValueModel.from_value_function(vf, "panda_test", backend="vm")
    rng = np.random.default_rng(0)
    x = rng.uniform(system.lower, system.upper, size=(6, system.state_dim))
    turned = x.copy()
    turned[:, 0] += 2 * np.pi
    turned[:, 7] -= 2 * np.pi
    v, _ = model.evaluate(0.3, x)
    np.testing.assert_allclose(model.evaluate(0.3, turned)[0], v, atol=1e-9)
    np.testing.assert_allclose(vf.value(np.full(6, 0.3), x), v, atol=1e-5)


def test_the_built_value_function_is_capped_at_its_boundary() -> None:
    """The card asks for the residual cap: V = l + min(W − l, 0) never exceeds l, in torch and in
    the compiled model; without the cap this network exceeds l by more than 1 cm at some states
    (what the card's value check records)."""
    vf = load_value_function("panda_panda_any", variant="bc")
    assert vf.card["cap_residual"] and vf.network.cap_residual
    system = vf.system
    rng = np.random.default_rng(1)
    x = rng.uniform(system.lower, system.upper, size=(400, system.state_dim))
    tau = np.full(len(x), system.horizon)
    with torch.no_grad():
        lx = system.boundary(torch.as_tensor(x, dtype=torch.float32)).numpy()
    assert np.all(vf.value(tau, x) <= lx + 1e-4)
    model = PairValueModel.from_value_function(vf, "panda_capped", backend="vm")
    v, g = model.evaluate(system.horizon, x[:20])
    v_t, g_t = vf.value_and_gradient(tau[:20], x[:20])
    np.testing.assert_allclose(v, v_t, atol=1e-5)
    np.testing.assert_allclose(g, g_t, atol=5e-3, rtol=5e-3)  # torch runs it in float32
    vf.network.cap_residual = False
    assert np.mean(vf.value(tau, x) > lx + 0.01) > 0.0


@pytest.mark.parametrize("cell_name", _cells())
def test_episodes_in_closed_loop_stay_apart_and_mostly_arrive(cell_name: str) -> None:
    cell = load_cell(cell_name)
    has_panda = any(a.robot.name == "panda" for a in cell.arms)
    assert max(a.robot.dof for a in cell.arms) == (7 if has_panda else 6)
    scenarios = generate_scenario_set(cell, seed=SEED, count=3).scenarios
    unhurried = PlannerSettings().override({"opt.deadline": 3600.0})
    episode = EpisodeSettings(time_limit=get_setup(cell_name).time_limit)
    registry_ = ModelRegistry()
    reached = 0
    for scenario in scenarios:
        planners = build_planners(
            cell, {a: "nehmo" for a in cell.arm_ids}, scenario, 0.04, registry_, unhurried
        )
        result = run_episode(cell, scenario, planners, episode)
        assert not [c for c in result.collisions if c.arm_a != c.arm_b]
        assert all(np.isfinite(e) for e in result.final_errors.values())
        reached += result.outcome == "success"
    assert reached >= 2
