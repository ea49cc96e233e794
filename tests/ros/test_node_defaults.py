"""The arm_planner's parameter defaults have one source: PlannerSettings and ControlSettings.

The node derives its defaults from the settings dataclasses; the shipped parameter file
``nehmo_ros/config/arm_planner.yaml`` restates them for ROS users, so it must not drift.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import pytest
import yaml

from nehmo_core.planning.opt.settings import PlannerSettings
from nehmo_ros.arm_planner import PARAMS
from nehmo_ros.control import ControlSettings

CONFIG = Path(__file__).resolve().parents[2] / "nehmo_ros" / "config" / "arm_planner.yaml"
NODE_ONLY = {"deadline"}  # node semantics: 0 means 75 % of the period


def _yaml_params() -> dict:
    return yaml.safe_load(CONFIG.read_text())["/**"]["ros__parameters"]


def _same(a: object, b: object) -> bool:
    if isinstance(a, float) and isinstance(b, float) and math.isinf(a) and math.isinf(b):
        return a == b
    return a == b


@pytest.mark.parametrize("settings", [PlannerSettings(), ControlSettings()])
def test_node_defaults_are_the_settings_defaults(settings: object) -> None:
    fields = {f.name for f in dataclasses.fields(settings)}  # type: ignore[arg-type]
    shared = (fields & set(PARAMS)) - NODE_ONLY
    assert shared, "the node takes no parameter from these settings"
    for name in sorted(shared):
        assert _same(PARAMS[name].default, getattr(settings, name)), name


def test_parameter_file_states_the_node_defaults() -> None:
    params = _yaml_params()
    assert set(params) == set(PARAMS) - {"arm_id", "cell"}
    for name, value in params.items():
        assert _same(value, PARAMS[name].default), (
            f"{name}: file {value!r}, node {PARAMS[name].default!r}"
        )
