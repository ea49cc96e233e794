"""The ``actuator`` stage's braking check: an arm that cannot stop at once brakes before the
pose it would come to rest at, braking at its limits, reaches a near peer (real geometry)."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.pipeline import read_tick
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import Scenario

DUAL = load_cell("dual_ur5")
A, B = DUAL.arm_ids


def test_off_with_the_stage_and_in_the_paper_preset() -> None:
    assert not PlannerSettings().actuator.enabled
    assert not PlannerSettings.preset("paper").actuator.enabled
    assert PlannerSettings.preset("real_actuators").actuator.brake_clearance > 0


def test_a_command_whose_rest_pose_reaches_a_near_peer_is_braked() -> None:
    """Moving at 0.5 rad/s, a UR5 (5 rad/s²) travels 0.045 rad per joint before it stops: a
    command that keeps the arm clear now but not at rest is replaced by the hardest braking
    (0.2 rad/s less on every joint); moving away, or with the check off, it is kept. In the
    slow game (both arms hold, the command within the hold's speed) the clearance is 1 cm."""
    registry = ModelRegistry()
    settings = PlannerSettings().override({"actuator.enabled": True, "opt.deadline": 3600.0})
    planner = NehmoPlanner(DUAL, A, registry.models_for("nehmo", DUAL), settings)
    stage = planner.stage("actuator")
    q = np.array([0.44, -1.2, 1.0, 0.0, 0.0, 0.0])  # facing the peer, 7 cm apart
    peers = {B: np.array([0.52 + np.pi, -1.2, 1.0, 0.0, 0.0, 0.0])}
    now = planner.current(q, peers, {B: 1.0})
    g = now.grads[0][:6]
    toward = -0.5 * np.sign(g)
    tick = read_tick(planner, q, peers, q, {B: 1.0}, None)
    stage.last = toward.copy()  # type: ignore[attr-defined]
    braked = stage.filter(tick, now, toward)  # type: ignore[attr-defined]
    np.testing.assert_allclose(braked, toward - np.sign(toward) * 0.2)
    stage.last = -toward  # type: ignore[attr-defined]
    np.testing.assert_allclose(stage.filter(tick, now, -toward), -toward)  # type: ignore[attr-defined]
    # at full speed the clearance stays 4 cm against a peer that holds, too
    holding = read_tick(planner, q, peers, q, {B: 0.2}, {B: 0.2})
    assert holding.holds(B)
    holding.announced = 0.2
    stage.last = toward.copy()  # type: ignore[attr-defined]
    braked = stage.filter(holding, now, toward)  # type: ignore[attr-defined]
    np.testing.assert_allclose(braked, toward - np.sign(toward) * 0.2)
    # the slow game: 3.4 cm apart, creeping closer at the hold's speed (0.1 rad/s) to a rest
    # pose 3.0 cm away: against a peer that holds while this arm holds too, the clearance is
    # the contact guard's holding clearance (1 cm) and the command stands; announcing full
    # speed, or against a peer at full speed, it brakes (to a stop: the band reaches zero)
    near_q = q + 0.04 * np.sign(toward)
    creep = 0.1 * np.sign(toward)
    near_now = planner.current(near_q, peers, {B: 1.0})
    for bound, own, kept in ((0.2, 0.2, True), (0.2, 1.0, False), (1.0, 0.2, False)):
        tick = read_tick(planner, near_q, peers, near_q, {B: bound}, {B: bound})
        tick.announced = own
        stage.last = creep.copy()  # type: ignore[attr-defined]
        out = stage.filter(tick, near_now, creep)  # type: ignore[attr-defined]
        np.testing.assert_allclose(out, creep if kept else np.zeros(6))
    off = NehmoPlanner(
        DUAL,
        A,
        registry.models_for("nehmo", DUAL),
        settings.override({"actuator.brake_clearance": 0.0}),
    )
    off_stage = off.stage("actuator")
    off_stage.last = toward.copy()  # type: ignore[attr-defined]
    np.testing.assert_allclose(off_stage.filter(tick, now, toward), toward)  # type: ignore[attr-defined]


def test_a_fail_safe_with_no_peer_near_brakes_instead_with_far_brake() -> None:
    """With ``far_brake``, Opt infeasible on its linear rows with the peer far (V ≥ brake_near):
    the fail-safe's full-speed step up V's gradient is replaced by the hardest braking; with the
    peer near, the fail-safe stands (within the band). Without it (the default) the fail-safe
    stands either way."""
    registry = ModelRegistry()
    base = {"actuator.enabled": True, "opt.deadline": 3600.0}
    models = registry.models_for("nehmo", DUAL)
    default = NehmoPlanner(DUAL, A, models, PlannerSettings().override(base)).stage("actuator")
    settings = PlannerSettings().override({**base, "actuator.far_brake": True})
    planner = NehmoPlanner(DUAL, A, models, settings)
    stage = planner.stage("actuator")
    peer = np.array([0.52 + np.pi, -1.2, 1.0, 0.0, 0.0, 0.0])
    moving = np.full(6, 0.5)
    for q, far in (
        (np.array([-1.5, -1.2, 1.0, 0.0, 0.0, 0.0]), True),
        (np.array([0.44, -1.2, 1.0, 0.0, 0.0, 0.0]), False),
    ):
        now = planner.current(q, {B: peer}, {B: 1.0})
        assert (float(now.values.min()) >= settings.actuator.brake_near) == far
        tick = read_tick(planner, q, {B: peer}, q, {B: 1.0}, None)
        tick.fail_safe = True
        stage.last = moving.copy()  # type: ignore[attr-defined]
        out = stage.filter(tick, now, -moving)  # type: ignore[attr-defined]
        np.testing.assert_allclose(out, moving - 0.2)  # at speed, either way: the band's edge
        stage.last = np.zeros(6)  # type: ignore[attr-defined]
        out = stage.filter(tick, now, np.full(6, 0.5))  # type: ignore[attr-defined]
        # at rest: far, it stays still; near, the fail-safe starts as fast as the band allows
        np.testing.assert_allclose(out, np.zeros(6) if far else np.full(6, 0.2))
        default.last = np.zeros(6)  # type: ignore[attr-defined]
        out = default.filter(tick, now, np.full(6, 0.5))  # type: ignore[attr-defined]
        np.testing.assert_allclose(out, np.full(6, 0.2))  # the fail-safe, within the band


# five UR5, development seed 60, scenario 32 (full precision: the closed loop is chaotic): a
# holding arm in its fail-safe and a peer closing at 0.5 rad/s, whose learned V reads 2 cm above
# the real distance, touch at 6.36 s under realistic tracking unless the peer brakes in time
FIVE = load_cell("five_ur5")
CLOSING = Scenario(
    start={
        "ur5_0": np.array(
            [
                -2.7599204085019853,
                -1.5853091750496642,
                1.6413321901521056,
                -1.613978363464109,
                -0.7859682625901239,
                -7.530053754223331e-05,
            ]
        ),
        "ur5_1": np.array(
            [
                -2.824721003816725,
                -2.206895193891281,
                1.017784779699202,
                -1.122433305337708,
                -1.8203048202314367,
                -1.7633099901548377e-05,
            ]
        ),
        "ur5_2": np.array(
            [
                2.772085612685691,
                -1.817696761084905,
                1.714187325441265,
                -1.1652059041925176,
                -1.230153400163637,
                -1.5190904947726125e-05,
            ]
        ),
        "ur5_3": np.array(
            [
                -1.5952810678438532,
                -1.8369771014737655,
                1.6468299451155533,
                -1.485028695745278,
                -0.5750949579256996,
                -3.635701480986242e-05,
            ]
        ),
        "ur5_4": np.array(
            [
                2.1787232881520726,
                -2.018689016919727,
                1.547143260986183,
                -1.1964918660328792,
                -2.0336448051960616,
                -5.057723714907425e-05,
            ]
        ),
    },
    goal={
        "ur5_0": np.array(
            [
                -2.9470217642975793,
                -2.444865854587447,
                1.7062943518261258,
                -0.8705151451767996,
                -1.0472393237127289,
                -6.274166449093954e-05,
            ]
        ),
        "ur5_1": np.array(
            [
                2.742042518867432,
                -2.205821132351173,
                1.9227710781113352,
                -1.6867716161538633,
                -2.2907394276447954,
                -6.945580851658306e-05,
            ]
        ),
        "ur5_2": np.array(
            [
                -1.5499839642392832,
                -2.059106796000955,
                1.2512971089060225,
                -1.2629704763489187,
                -1.753845714823214,
                -8.182157839486948e-05,
            ]
        ),
        "ur5_3": np.array(
            [
                -2.6218291985728293,
                -1.7939436219166076,
                1.6109796444542512,
                -1.309591061438713,
                -2.277102071084924,
                -8.759628796228824e-05,
            ]
        ),
        "ur5_4": np.array(
            [
                -2.0045763262463394,
                -1.1281567851592937,
                1.9887796569903966,
                -0.8816884857185796,
                -0.5317348632604855,
                -3.2050451903131716e-05,
            ]
        ),
    },
)


@pytest.mark.parametrize("brake", [0.0, None])
def test_a_peer_closing_on_a_holder_brakes_in_time_under_realistic_tracking(
    brake: float | None,
) -> None:
    """Closed loop under the ``realistic`` actuator model (its noise is seeded by the start):
    the ``real_actuators`` preset without the braking check (and without the contact guard's
    approach band, which also parts these arms) touches; with it, no contact."""
    # found with the hold announced within 0.05 rad of the goal (also when a peer presses) and
    # the paper's fail-safe sweeping every joint (the defaults then); at today's 0.09, or with
    # the deadband, these arms meet otherwise
    overrides = {
        "opt.deadline": 3600.0,
        "hold.tolerance": 0.05,
        "hold.pressed_tolerance": 0.05,
        "fail_safe.deadband": 0.0,
    }
    if brake is not None:
        overrides["actuator.brake_clearance"] = brake
        overrides["contact.approach"] = 0.0
    settings = PlannerSettings.preset("real_actuators", overrides)
    kinds = dict.fromkeys(FIVE.arm_ids, "nehmo")
    planners = build_planners(FIVE, kinds, CLOSING, 0.04, ModelRegistry(), settings)
    result = run_episode(
        FIVE, CLOSING, planners, EpisodeSettings(time_limit=7.0, actuators="realistic")
    )
    if brake == 0.0:
        assert result.outcome == "collision"  # the test can fail: without the check it touches
    else:
        assert not result.collisions
