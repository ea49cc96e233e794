"""Stepping out of the way of a peer that announces nothing: the observed velocities, the escape
target from a toy value function, and in closed loop (exact geometry) UR5-Kinova scenarios
where the reckless Kinova drove into the UR5 before and no longer does."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.planners import build_planners
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.settings import PAPER_OPT, PlannerSettings, SilentWatchSettings
from nehmo_core.planning.stages.silent_peers import SilentPathWatch
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import load_scenario_set

SCENARIOS = Path(__file__).parents[1] / "data" / "silent_peers"


class _Gap:
    """A toy pair value: V = ‖q_own − q_peer‖ − 0.1 [m] for two 2-joint points."""

    n2 = 2

    def evaluate(self, tau: float, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        del tau
        d = x[:, :2] - x[:, 2:4]
        r = np.linalg.norm(d, axis=1)
        grads = np.hstack([d / r[:, None], -d / r[:, None]])
        return r - 0.1, grads


def _target(watch: SilentPathWatch, own, peer, velocity) -> np.ndarray | None:
    state = np.concatenate([own, peer])
    value, _ = _Gap().evaluate(0.1, state[None, :])
    return watch.target(
        [_Gap()], ["p"], [0], [state], value, {"p": np.asarray(velocity)}, 2, 0.1, 0.05
    )  # type: ignore[list-item]


def test_velocities_are_the_motion_between_calls_of_silent_peers_only() -> None:
    watch = SilentPathWatch(lookahead=2.0, clearance=0.2, tick=0.04, d_max=0.5)
    q = {"a": np.zeros(6), "b": np.zeros(6)}
    assert watch.velocities(q, participants=()) == {}  # first sight: no velocity yet
    moved = {"a": np.full(6, 0.02), "b": np.full(6, -0.01)}
    v = watch.velocities(moved, participants={"b"})
    assert set(v) == {"a"}  # b takes part in the announcements: not watched
    np.testing.assert_allclose(v["a"], 0.5)
    watch.reset()
    assert watch.velocities(moved, participants=()) == {}


def test_velocities_wrap_continuous_joints_and_stay_within_the_speed_bound() -> None:
    kinova = load_cell("ur5_kinova").arm("kinova_0").robot  # joints 0, 3, 5 continuous
    watch = SilentPathWatch(2.0, 0.2, 0.04, d_max=0.5, robots={"k": kinova})
    q = np.zeros(6)
    q[0] = np.pi - 0.005
    watch.velocities({"k": q}, participants=())
    q2 = q.copy()
    q2[0] = -np.pi + 0.005  # 0.01 rad across ±π, not −2π + 0.01
    q2[1] = 0.1  # 2.5 rad/s over one tick: more than any peer may move (a skipped tick)
    v = watch.velocities({"k": q2}, participants=())["k"]
    np.testing.assert_allclose(v, [0.25, 0.5, 0.0, 0.0, 0.0, 0.0], atol=1e-9)


def test_an_approaching_peer_turns_the_target_up_the_value_at_its_path() -> None:
    watch = SilentPathWatch(lookahead=2.0, clearance=0.2, tick=0.04, d_max=0.5)
    own, peer = np.array([0.0, 0.0]), np.array([0.5, 0.0])  # V = 0.4 now
    # coming straight at the arm at 0.2 /s: V = 0.0 two seconds ahead, pushing along −x
    target = _target(watch, own, peer, [-0.2, 0.0])
    assert target is not None
    # minus a step of 0.05 at the largest joint up V's gradient at that point (−x for the arm)
    np.testing.assert_allclose(target, [0.05, 0.0], atol=1e-12)
    # a peer at rest, moving away, or passing by farther than the clearance changes nothing
    assert _target(watch, own, peer, [0.0, 0.0]) is None
    assert _target(watch, own, peer, [0.2, 0.0]) is None
    assert _target(watch, own, peer, [0.0, 0.2]) is None  # V grows along the path
    assert _target(watch, own, np.array([2.0, 0.0]), [-0.2, 0.0]) is None  # stays above 0.2
    # an approach smaller than silent_watch.approach is not one
    approach = SilentWatchSettings().approach
    slow = approach / 2.0 / 2.0  # V falls by approach / 2 over the lookahead
    assert _target(SilentPathWatch(2.0, 0.5, 0.04, 0.5), own, peer, [-slow, 0.0]) is None
    assert _target(SilentPathWatch(0.0, 0.2, 0.04, 0.5), own, peer, [-0.2, 0.0]) is None  # off


@pytest.mark.parametrize(
    "name",
    ["silent_watch.lookahead", "silent_watch.clearance", "silent_watch.approach", "opt.tick"],
)
def test_bad_watch_settings_are_rejected_by_name(name: str) -> None:
    with pytest.raises(InvalidValueError, match=f"`{name}`"):
        PlannerSettings().override({name: -1.0})


def test_the_papers_opt_does_not_watch() -> None:
    assert PlannerSettings().override(PAPER_OPT).silent_watch.lookahead == 0.0


@pytest.mark.parametrize("index", [0, 1, 2])
def test_stepping_out_of_a_reckless_peers_path_avoids_collisions(index: int) -> None:
    """Development-seed 31 UR5-Kinova scenarios (70, 249 and 308) where the reckless Kinova,
    driving straight to its goal, hit the UR5 while the UR5 planned only against its worst case
    (the paper's rows, here ``silent_lookahead = 0``). The collision is reproduced, so the test
    can fail; with the watch on the UR5 leaves the Kinova's path and reaches its goal."""
    scenarios = load_scenario_set(SCENARIOS / "ur5_kinova_challenging_seed31.json")
    cell = load_cell("ur5_kinova")
    scenario = scenarios.scenarios[index]
    kinds = {"ur5_0": "nehmo", "kinova_0": "reckless"}
    outcomes = {}
    for lookahead in (0.0, PlannerSettings().silent_watch.lookahead):
        unhurried = PlannerSettings().override(
            {"opt.deadline": 3600.0, "silent_watch.lookahead": lookahead}
        )
        planners = build_planners(cell, kinds, scenario, 0.04, ModelRegistry(), unhurried)
        result = run_episode(cell, scenario, planners, EpisodeSettings(time_limit=30.0))
        between = [c for c in result.collisions if c.arm_a != c.arm_b]
        outcomes[lookahead] = (result.outcome, bool(between))
    assert outcomes[0.0] == ("collision", True), "the scenario no longer reproduces the collision"
    assert outcomes[PlannerSettings().silent_watch.lookahead] == ("success", False)
