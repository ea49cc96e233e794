"""The control loop's own input checks: bad control settings name the parameter, an unknown
stale policy lists the valid ones, a goal outside the joint limits is rejected."""

from __future__ import annotations

import pytest
from _control_helpers import CELL, NAMES, SETTINGS, RecordingPlanner

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_ros.control import ArmController, ControlSettings


def test_goal_outside_joint_limits_is_rejected() -> None:
    c = ArmController(CELL, "ur5_0", RecordingPlanner(), SETTINGS)  # type: ignore[arg-type]
    try:
        with pytest.raises(InvalidValueError, match="joint limits"):
            c.set_goal(NAMES, [10.0] * 6)
        assert c.goal is None
    finally:
        c.stop()


@pytest.mark.parametrize(
    ("changes", "name"),
    [
        ({"rate": 0.0}, "rate"),
        ({"jump_margin": 0.0}, "jump_margin"),
        ({"peer_timeout": -1}, "peer"),
    ],
)
def test_bad_control_settings_name_the_parameter(changes: dict[str, float], name: str) -> None:
    with pytest.raises(InvalidValueError, match=f"`{name}"):
        ControlSettings(**changes)  # type: ignore[arg-type]


def test_unknown_stale_policy_lists_the_valid_ones() -> None:
    with pytest.raises(UnknownNameError, match="fail_safe"):
        ControlSettings(stale_policy="ignore")
