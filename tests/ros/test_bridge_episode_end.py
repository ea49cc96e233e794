"""When the bridge ends an episode: success, collision and time limit, each as configured."""

from __future__ import annotations

import logging
from types import SimpleNamespace

import numpy as np
import pytest

from nehmo_core.robots import load_cell
from sim_bridge.bridge import SimBridgeNode
from sim_bridge.settings import DEFAULTS, BridgeSettings


def _bridge(at_goal: bool, t: float, **changes: object) -> SimpleNamespace:
    """The state ``SimBridgeNode._check_done`` reads, with every arm at (or off) its goal."""
    cell = load_cell("dual_ur5")
    names = BridgeSettings.__dataclass_fields__
    s = BridgeSettings(**{k: v for k, v in {**DEFAULTS, **changes}.items() if k in names})
    goal = {a: np.full(6, 0.3) for a in cell.arm_ids}
    q = {a: goal[a] + (0.0 if at_goal else 0.5) for a in cell.arm_ids}
    return SimpleNamespace(
        s=s,
        t_ns=int(t * 1e9),
        cell=cell,
        sim=SimpleNamespace(q=q),
        scenario=SimpleNamespace(goal=goal),
        outcome="",
        done=False,
        _done_at=0.0,
        dropped={a: 0 for a in cell.arm_ids},
        watchdog_trips={a: 0 for a in cell.arm_ids},
        expired_steps={a: 0 for a in cell.arm_ids},
        get_logger=lambda: logging.getLogger("bridge"),
    )


@pytest.mark.parametrize(
    ("at_goal", "collided", "t", "changes", "outcome"),
    [
        (True, False, 1.0, {}, "success"),
        (True, False, 1.0, {"stop_on_success": False}, ""),  # a load run goes on at the goals
        (True, False, 25.0, {"stop_on_success": False}, "time_limit"),
        (False, True, 1.0, {}, "collision"),
        (False, True, 1.0, {"stop_on_collision": False}, ""),
        (False, False, 1.0, {}, ""),
    ],
)
def test_episode_ends_as_configured(
    at_goal: bool, collided: bool, t: float, changes: dict, outcome: str
) -> None:
    bridge = _bridge(at_goal, t, **changes)
    SimBridgeNode._check_done(bridge, collided)  # type: ignore[arg-type]
    assert bridge.outcome == outcome and bridge.done == bool(outcome)
