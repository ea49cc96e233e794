"""The arm_planner's parameters have one source: the settings dataclasses.

Every planner setting is a node parameter under its dotted name (``hold.bound``) with the
default, description and range of its group; the shipped parameter file
``nehmo_ros/config/arm_planner.yaml`` is generated from the declarations and must not drift.
"""

from __future__ import annotations

import math
from pathlib import Path

import yaml

from nehmo_core.planning.settings import RENAMED, PlannerSettings
from nehmo_ros.arm_planner import FROM_RATE, PARAMS
from nehmo_ros.control import ControlSettings
from nehmo_ros.param_file import parameter_file

CONFIG = Path(__file__).resolve().parents[2] / "nehmo_ros" / "config" / "arm_planner.yaml"
NODE_SEMANTICS = {"opt.deadline"}  # 0 means 75 % of the period


def _flatten(tree: dict, prefix: str = "") -> dict:
    out = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(_flatten(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def _same(a: object, b: object) -> bool:
    if isinstance(b, tuple):
        b = list(b)
    if isinstance(a, float) and isinstance(b, float) and math.isinf(a) and math.isinf(b):
        return a == b
    return a == b


def test_every_planner_setting_is_a_node_parameter_with_its_default() -> None:
    flat = PlannerSettings().flat()
    for name, value in flat.items():
        if name in FROM_RATE:
            assert name not in PARAMS, name
            continue
        assert name in PARAMS, f"planner setting {name} is not a node parameter"
        if name not in NODE_SEMANTICS:
            assert _same(PARAMS[name].default, value), name
    assert not set(RENAMED) & set(PARAMS), "a flat name of an earlier release is still declared"


def test_node_parameters_carry_the_settings_rules() -> None:
    """Units and ranges come from the groups: hold.bound is a share in [0, 1]."""
    bound = PARAMS["hold.bound"]
    assert (bound.low, bound.high) == (0.0, 1.0)
    assert PARAMS["opt.t_plan"].description.startswith("[s] ")
    assert bound.descriptor().floating_point_range[0].to_value == 1.0


def test_control_defaults_are_node_defaults() -> None:
    control = ControlSettings()
    for name in ("rate", "peer_timeout", "stale_policy", "jump_margin"):
        assert _same(PARAMS[name].default, getattr(control, name)), name
    assert control.opt == PlannerSettings().opt  # speed bounds from the planner's settings


def test_parameter_file_is_generated_from_the_declarations() -> None:
    assert CONFIG.read_text() == parameter_file(), (
        "arm_planner.yaml drifted: ./run python -m nehmo_ros.param_file "
        "nehmo_ros/config/arm_planner.yaml"
    )
    params = _flatten(yaml.safe_load(CONFIG.read_text())["/**"]["ros__parameters"])
    assert set(params) == set(PARAMS) - {"arm_id", "cell"}
    for name, value in params.items():
        assert _same(value, PARAMS[name].default), name
