"""The hold's pressed tolerance: an arm held 0.09-0.15 rad short of its goal by a peer's V row
announces the hold's bound (its peer then plans the slow game against it); in open space it
announces only within ``hold.tolerance``, so its last tenth of a radian is not slowed."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.peer_bounds import FULL_SPEED
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell

DUAL = load_cell("dual_ur5")
A, B = DUAL.arm_ids
Q = np.array([0.44, -1.2, 1.0, 0.0, 0.0, 0.0])  # facing the peer, a few cm apart
NEAR = np.array([0.52 + np.pi, -1.2, 1.0, 0.0, 0.0, 0.0])
FAR = NEAR - np.array([1.2, 0.0, 0.0, 0.0, 0.0, 0.0])  # turned away: V reads 0.27 m
GOAL = Q + np.array([0.12, 0.0, 0.0, 0.0, 0.0, 0.0])  # 0.12 rad on, toward the peer


def _said(peer: np.ndarray, **overrides: object) -> float:
    settings = PlannerSettings().override({"opt.deadline": 3600.0, **overrides})
    planner = NehmoPlanner(DUAL, A, ModelRegistry().models_for("nehmo", DUAL), settings)
    result = planner.plan(Q, {B: peer}, GOAL, {B: FULL_SPEED})
    assert np.abs(result.velocity).max() <= planner.speed_cap * settings.opt.u_max + 1e-9
    return result.telemetry.speed_bound


def test_a_pressed_arm_announces_from_the_pressed_tolerance() -> None:
    k = PlannerSettings().hold.bound
    assert _said(NEAR) == k
    assert _said(FAR) == FULL_SPEED  # open space: only within hold.tolerance
    assert _said(NEAR, **{"hold.pressed_tolerance": 0.09}) == FULL_SPEED
    assert _said(FAR, **{"hold.tolerance": 0.15}) == k


def test_the_release_must_cover_the_pressed_tolerance() -> None:
    with pytest.raises(InvalidValueError, match=r"hold\.release.*pressed_tolerance"):
        PlannerSettings().override({"hold.pressed_tolerance": 0.5})
