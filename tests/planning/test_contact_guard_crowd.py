"""The contact guard among several peers: each near peer is checked on its own.

Two generated tasks (tasks seed 78) ended in a collision between arms when the guard checked
only the nearest peer and only within its clearance: three UR5s inside one another's margins,
each on the paper's fail-safe against its most critical peer, stepped into a third arm
(``gen_4arm_s78_096``, 1.9 mm at 1.52 s), and two UR5s 4.1 cm apart closed 2.8 cm in one tick
and then touched (``gen_7arm_s78_049``, 0.3 mm at 17.56 s). Both replays are deterministic and
both collide with ``contact.approach`` 0 (the first one also with each peer checked on its own).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.ha_tasks import load_task
from nehmo_core.eval.planners import build_planners
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.pipeline import read_tick
from nehmo_core.planning.settings import PlannerSettings

SANDWICHED = Path(__file__).parents[1] / "data" / "sandwiched"
UNHURRIED = {"opt.deadline": 3600.0}
# gen_4arm_s78_096 at 1.28 s in the run that collided: ur5_1 is 2.4 cm from ur5_0 and 2.2 cm
# from ur5_3, both inside the guard's clearance
BETWEEN_TWO = {
    "ur5_0": [-2.21017458, -0.89675708, 1.69257465, -1.84475451, -0.70196049, -0.25420899],
    "ur5_1": [-1.92981757, -1.36877761, 1.63612368, -1.82351194, -1.90897209, 0.0749495],
    "ur5_2": [-1.91084007, -2.50307703, 1.23951751, -1.41845754, -1.17152908, -0.00006543],
    "ur5_3": [-3.17335908, -0.89964854, 1.38932505, -1.69089905, -0.38162393, -0.30000692],
}


@pytest.fixture(scope="module")
def registry() -> ModelRegistry:
    return ModelRegistry()


@pytest.mark.parametrize(
    ("name", "seconds"), [("gen_4arm_s78_096", 3.0), ("gen_7arm_s78_049", 18.0)]
)
def test_arms_in_one_anothers_margins_stay_apart(
    name: str, seconds: float, registry: ModelRegistry
) -> None:
    task = load_task(SANDWICHED / f"{name}.json")
    settings = PlannerSettings().override(UNHURRIED)
    kinds = {a: "nehmo" for a in task.cell.arm_ids}
    planners = build_planners(task.cell, kinds, task.scenario, 0.04, registry, settings)
    result = run_episode(task.cell, task.scenario, planners, EpisodeSettings(time_limit=seconds))
    assert not [c for c in result.collisions if c.arm_a != c.arm_b]


def test_between_two_peers_no_command_closes_either_gap(registry: ModelRegistry) -> None:
    """Random commands for ur5_1 between two near peers (the peers still): the guarded step
    brings neither peer closer than it is now, and some commands are changed."""
    task = load_task(SANDWICHED / "gen_4arm_s78_096.json")
    cell, arm = task.cell, "ur5_1"
    peers = {a: np.array(q) for a, q in BETWEEN_TWO.items() if a != arm}
    q = np.array(BETWEEN_TWO[arm])
    settings = PlannerSettings().override(UNHURRIED)
    planner = NehmoPlanner(cell, arm, registry.models_for("nehmo", cell), settings)
    guard = next(f for f in planner._filters if f.name == "contact")
    tick = read_tick(planner, q, peers, task.scenario.goal[arm], dict.fromkeys(peers, 1.0), None)
    tick.rows = planner.rows(q)
    now_values = planner.current(tick.q, tick.peers, tick.bounds)
    rng = np.random.default_rng(5)
    changed = 0
    with CellWorld(cell) as world:
        world.set_configuration({**peers, arm: q})
        gaps = {p: world.distance(arm, p) for p in ("ur5_0", "ur5_3")}
        assert max(gaps.values()) < settings.contact.clearance
        for _ in range(16):
            u = rng.uniform(-1.0, 1.0, cell.arm(arm).robot.dof)
            out = guard.filter(tick, now_values, u)
            changed += not np.array_equal(out, u)
            world.set_joint_positions(arm, q + settings.opt.t_plan * out)
            for p, gap in gaps.items():
                assert world.distance(arm, p) >= gap - 1e-9, p
    assert changed > 0
