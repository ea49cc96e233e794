"""The ``actuator`` stage: every command is reachable from the last one under the joints'
acceleration limits (Opt's step, the fail-safe and the unconstrained step alike); off by
default and in the paper preset."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import generate_scenario_set

CELL = load_cell("dual_ur5")
A, B = CELL.arm_ids
AWARE = PlannerSettings().override({"actuator.enabled": True, "opt.deadline": 3600.0})


@pytest.fixture(scope="module")
def registry() -> ModelRegistry:
    return ModelRegistry()


def test_off_by_default_and_in_the_paper_preset() -> None:
    assert not PlannerSettings().actuator.enabled
    assert not PlannerSettings.preset("paper").actuator.enabled


def test_the_fail_safe_becomes_the_best_reachable_command(registry: ModelRegistry) -> None:
    """Moving at +0.5 rad/s, a full reversal is out of reach in one tick: the projected command
    is 0.5 − a·tick on every joint (a = 5 rad/s², tick 0.04 s)."""
    planner = NehmoPlanner(CELL, A, registry.models_for("nehmo", CELL), AWARE)
    stage = planner.stage("actuator")
    stage.last = np.full(6, 0.5)  # type: ignore[attr-defined]
    q = np.zeros(6)
    u = planner.keep_rows(np.full(6, -0.5), planner.rows(q))
    np.testing.assert_allclose(u, 0.5 - 5.0 * 0.04, atol=1e-6)


def test_closed_loop_commands_change_within_the_limits(registry: ModelRegistry) -> None:
    limit = np.asarray(CELL.arm(A).robot.facts.accel_limits) * AWARE.opt.tick
    scenarios = generate_scenario_set(CELL, seed=5, count=2).scenarios
    changed = 0
    for scenario in scenarios:
        planners = build_planners(CELL, {A: "nehmo", B: "nehmo"}, scenario, 0.04, registry, AWARE)
        sent: dict[str, list[np.ndarray]] = {A: [np.zeros(6)], B: [np.zeros(6)]}
        for arm, planner in planners.items():
            original = planner.plan

            def recording(*args, _p=original, _arm=arm, _sent=sent, **kw):  # type: ignore[no-untyped-def]
                result = _p(*args, **kw)
                _sent[_arm].append(np.asarray(result.velocity, dtype=float))
                return result

            planner.plan = recording  # type: ignore[method-assign]
        run_episode(CELL, scenario, planners, EpisodeSettings(time_limit=6.0))
        for commands in sent.values():
            steps = np.abs(np.diff(np.array(commands), axis=0))
            assert np.all(steps <= limit + 1e-9)
            changed += int(np.any(steps > 0))
    assert changed > 0
