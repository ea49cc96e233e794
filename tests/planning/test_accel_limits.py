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
from nehmo_core.sim.scenarios import Scenario, generate_scenario_set

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


def test_closing_on_a_peer_slows_down_as_the_gap_closes(registry: ModelRegistry) -> None:
    """With ``approach_rate`` γ, the step keeps ``∇V·y ≥ −γ·t_plan·(V − margin)``: a goal behind
    a holding peer (small margin, short horizon) is approached no faster than that, where the V
    rows alone let the arm close at full speed; the row costs nothing moving away."""
    models = registry.models_for("nehmo", CELL)
    planner = NehmoPlanner(CELL, A, models, AWARE)
    stage = planner.stage("actuator")
    rate, t = AWARE.actuator.approach_rate, AWARE.opt.t_plan
    q = np.array([0.52, -1.2, 1.0, 0.0, 0.0, 0.0])  # facing the peer: V ≈ 0.10 m
    peers = {B: np.array([0.52 + np.pi, -1.2, 1.0, 0.0, 0.0, 0.0])}
    now = planner.current(q, peers, {B: 0.2})
    rows = stage.peer_rows(None, now)  # type: ignore[attr-defined]
    g = now.grads[0][:6]
    gap = float(now.values[0]) - planner.group_margin(now.model_index[0], 0.2)
    assert 0.0 < gap < 0.1
    np.testing.assert_allclose(rows.b, [-rate * t * gap])
    toward, away = -t * 0.5 * np.sign(g), t * 0.5 * np.sign(g)
    assert rows.satisfied(np.zeros(6)) and rows.satisfied(away)
    assert not rows.satisfied(toward)
    # heading in at 0.3 rad/s toward a goal behind the holding peer
    goal, heading = q - 2.0 * np.sign(g), -0.3 * np.sign(g)
    stage.last = heading  # type: ignore[attr-defined]
    result = planner.plan(q, peers, goal, {B: 0.2})
    assert float(g @ (t * result.velocity)) >= -rate * t * gap - 1e-6
    free = NehmoPlanner(CELL, A, models, AWARE.override({"actuator.approach_rate": 0}))
    free.stage("actuator").last = heading  # type: ignore[attr-defined]
    fast = free.plan(q, peers, goal, {B: 0.2})
    assert float(g @ (t * fast.velocity)) < -rate * t * gap  # without it, it closes faster


# three UR5 (seed 65, scenario 35, rounded to 0.1 mrad): with acceleration-limited tracking,
# today's planner reverses a joint it cannot reverse in time and two arms touch at about 8 s
TRIPLE = load_cell("triple_ur5")
REVERSAL = Scenario(
    start={
        "ur5_0": np.array([2.3208, -1.3603, 1.6059, -1.4591, -1.7351, -0.0001]),
        "ur5_1": np.array([2.9689, -1.2745, 1.0112, -0.8398, -2.2354, -0.0001]),
        "ur5_2": np.array([-2.3006, -2.0291, 1.6926, -1.7109, -1.9433, -0.0001]),
    },
    goal={
        "ur5_0": np.array([2.5851, -1.4049, 1.4149, -1.1617, -1.0523, -0.0001]),
        "ur5_1": np.array([-1.8018, -1.4313, 1.6578, -0.8231, -2.108, 0.0]),
        "ur5_2": np.array([-2.9632, -2.3742, 1.8954, -0.8045, -0.6462, 0.0]),
    },
)


@pytest.mark.parametrize("preset", ["default", "real_actuators"])
def test_a_fail_safe_reversal_under_acceleration_limits_is_kept_clear(
    registry: ModelRegistry, preset: str
) -> None:
    """Closed loop under the ``limits`` actuator model (acceleration limits, no latency or noise:
    deterministic): today's planner collides; with the ``real_actuators`` preset every command
    is one the joints can follow, and the episode ends without contact."""
    # the scenario was found with the hold announced within 0.05 rad of the goal (also when a
    # peer presses) and the paper's fail-safe sweeping every joint (the defaults then); at
    # today's 0.09, or with the deadband, the arms meet elsewhere and the ideal planner does not
    # collide here
    then = {
        "opt.deadline": 3600.0,
        "hold.tolerance": 0.05,
        "hold.pressed_tolerance": 0.05,
        "fail_safe.deadband": 0.0,
    }
    settings = PlannerSettings.preset(preset, then)
    kinds = dict.fromkeys(TRIPLE.arm_ids, "nehmo")
    planners = build_planners(TRIPLE, kinds, REVERSAL, 0.04, registry, settings)
    result = run_episode(
        TRIPLE, REVERSAL, planners, EpisodeSettings(time_limit=12.0, actuators="limits")
    )
    if preset == "default":
        assert result.outcome == "collision"  # the test can fail: today's planner does not hold
    else:
        assert result.outcome in ("success", "stuck") and not result.collisions
