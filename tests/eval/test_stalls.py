"""Stalled planner processes in the batch runner: what a late arm publishes and what it does."""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.stalls import Stalls, StallSchedule, parse_stalls
from nehmo_core.planning.opt.interface import PlanResult, Telemetry, WithoutValues
from nehmo_core.robots import load_cell
from nehmo_core.sim.cell_sim import CellSimulator, StepResult
from nehmo_core.sim.scenarios import generate_scenario_set

CELL = load_cell("five_ur5")
SCENARIO = generate_scenario_set(CELL, seed=3, count=1).scenarios[0]
SPEED = 0.01  # [rad/s] every plan's command on every joint: the arms never meet


class Counting(WithoutValues):
    """Commands SPEED on every joint and notes the simulator tick of every plan."""

    def __init__(self, arm_id: str, sim: Recording) -> None:
        self.arm_id, self.sim, self.ticks = arm_id, sim, []  # type: ignore[misc]

    def reset(self) -> None:
        self.ticks.clear()

    def plan(self, q_self, peers, q_goal, peer_bounds=None) -> PlanResult:  # type: ignore[no-untyped-def]
        self.ticks.append(len(self.sim.applied))
        return PlanResult(np.full(6, SPEED), Telemetry(0.0, "constant"))


class Recording(CellSimulator):
    """Notes whether each arm moved in each tick."""

    applied: list[dict[str, bool]]

    def reset(self, start, seed=None) -> None:  # type: ignore[no-untyped-def]
        super().reset(start, seed)
        self.applied = []

    def step(self, commands: Mapping[str, np.ndarray], dt: float) -> StepResult:
        self.applied.append({a: bool(np.any(u)) for a, u in commands.items()})
        return super().step(commands, dt)


def _run(stalls: Stalls) -> tuple[dict[str, list[int]], list[dict[str, bool]]]:
    settings = EpisodeSettings(time_limit=4.0, stalls=stalls)
    with Recording(CELL, settings.substeps, settings.self_collision) as sim:
        planners = {a: Counting(a, sim) for a in CELL.arm_ids}
        run_episode(CELL, SCENARIO, planners, settings, simulator=sim)
        return {a: p.ticks for a, p in planners.items()}, sim.applied


def test_without_stalls_every_arm_plans_every_tick_and_moves_from_the_second() -> None:
    planned, applied = _run(Stalls())
    assert all(ticks == list(range(100)) for ticks in planned.values())
    assert [any(m.values()) for m in applied] == [False] + [True] * 99


@pytest.mark.parametrize("expire", [False, True])
@pytest.mark.parametrize("hold", [1, 5])
def test_a_stalled_arm_moves_only_on_a_command_within_its_validity(hold: int, expire: bool) -> None:
    """A process stalled at a tick plans nothing then; an arm moves in tick k only when the
    command last published (at the latest tick j <= k its process ran) is younger than
    ``hold_ticks`` periods and is a plan: with ``expire`` only one made at tick j - 1."""
    stalls = Stalls(rate=0.2, max_ticks=6, processes=2, hold_ticks=hold, expire_stale=expire)
    planned, applied = _run(stalls)
    for a in CELL.arm_ids:
        ran = set(planned[a])
        assert 40 < len(ran) < 90  # it did stall, and not always
        for k, moved in enumerate(m[a] for m in applied):
            j = max(t for t in range(k + 1) if t in ran or t == 0)
            plan_before = (j - 1 in ran) if expire else any(t < j for t in ran)
            assert moved == (k - j < hold and j in ran and plan_before), (a, k)
    # arms of one process (round robin over two) stall together
    ids = CELL.arm_ids
    assert planned[ids[0]] == planned[ids[2]] == planned[ids[4]] != planned[ids[1]]


def test_the_schedule_is_seeded_and_groups_arms_round_robin() -> None:
    stalls = Stalls(rate=0.3, max_ticks=3, processes=2)
    one = StallSchedule(stalls, ["a", "b", "c"], seed=7)
    two = StallSchedule(stalls, ["a", "b", "c"], seed=7)
    first = [one.at(k) for k in range(50)]
    assert first == [two.at(k) for k in range(50)]
    assert all(("a" in s) == ("c" in s) for s in first)
    assert one.stalled_ticks["a"] > 0
    assert all(not StallSchedule(Stalls(), ["a"], 7).at(k) for k in range(50))


def test_parse_stalls_reads_the_option_and_rejects_bad_text() -> None:
    assert parse_stalls("0.05") == Stalls(rate=0.05, hold_ticks=1, expire_stale=True)
    assert parse_stalls("0.03,8,2,1,expire") == Stalls(0.03, 8, 2, 1, True)
    assert parse_stalls("0.03,8,2,5,send") == Stalls(0.03, 8, 2, 5, False)
    with pytest.raises(InvalidValueError, match="`--stalls` must be RATE"):
        parse_stalls("0.1,2,3,4,5")
    with pytest.raises(InvalidValueError, match="`--stalls` must be a rate then integers"):
        parse_stalls("often")
    with pytest.raises(InvalidValueError, match="`--stalls` must be a rate then integers"):
        parse_stalls("0.1,2,late")
    with pytest.raises(InvalidValueError, match=r"`stalls\.rate` must be in \[0, 1\]"):
        parse_stalls("1.5")
    with pytest.raises(InvalidValueError, match=r"`stalls\.hold_ticks` must be >= 1"):
        parse_stalls("0.1,5,0,0")


@pytest.mark.parametrize(
    ("rules", "collides"),
    [(Stalls(0.08, 8, 2, 5, False), True), (Stalls(0.08, 8, 2, 1, True), False)],
    ids=["before_late_tick_rules", "with_them"],
)
def test_stalled_processes_collide_without_the_late_tick_rules_and_not_with_them(
    rules: Stalls, collides: bool
) -> None:
    """Five NeHMO UR5s in two stalled processes (scenario 48 of seed 99, whose stalls the
    closed loop draws from its start): an arm kept on its last command for five periods and
    then on a plan made before the stall hits a peer within a second; with the bridge's
    command validity and the planner's ``late_plan`` rule the episode ends without collision.
    (Solves have no wall-clock deadline here, so the run does not depend on the machine.)"""
    from nehmo_core.eval.planners import build_planners
    from nehmo_core.eval.scenario_sets import scenario_set_for
    from nehmo_core.eval.setups import get_setup
    from nehmo_core.planning.models.registry import ModelRegistry
    from nehmo_core.planning.settings import PlannerSettings

    setup = get_setup("five_ur5")
    scenario = scenario_set_for(setup, seed=99, count=49).scenarios[48]
    settings = PlannerSettings().override({"opt.deadline": 3600.0})
    kinds = dict.fromkeys(CELL.arm_ids, "nehmo")
    planners = build_planners(CELL, kinds, scenario, 0.04, ModelRegistry(), settings)
    result = run_episode(CELL, scenario, planners, EpisodeSettings.for_setup(setup, stalls=rules))
    assert (result.outcome == "collision") == collides, (result.outcome, result.ticks)
    assert result.outcome != "collision" or result.ticks < 50
