"""The planners' markers and the Foxglove layout that shows them."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from nehmo_core.logs.topics import ros_topics
from nehmo_core.robots import load_cell
from nehmo_ros.foxglove_layout import layout_text
from nehmo_ros.markers import AMBER, GREEN, RED, PlannerMarkers, value_colour

REPO = Path(__file__).resolve().parents[2]
CELL = load_cell("dual_ur5")


def test_colour_follows_value_against_the_margin() -> None:
    assert value_colour(0.2, 0.05) == GREEN
    assert value_colour(0.1, 0.05) == GREEN
    assert value_colour(0.07, 0.05) == AMBER
    assert value_colour(0.05, 0.05) == AMBER
    assert value_colour(0.01, 0.05) == RED
    assert value_colour(-0.1, 0.05) == RED


def test_the_line_joins_the_closest_link_origins_of_the_critical_pair() -> None:
    markers = PlannerMarkers(CELL, "ur5_0", 0.05)
    q0 = np.array([0.0, -1.2, 1.0, -1.4, -1.57, 0.0])
    states = {"ur5_0": q0, "ur5_1": q0.copy()}
    out = markers.build(None, states, q0, "planning", "ur5_1", 0.03)
    line, goal, text = out.markers
    a, b = markers.points("ur5_0", q0), markers.points("ur5_1", q0)
    gaps = np.linalg.norm(a[:, None] - b[None], axis=-1)
    p, q = (
        (line.points[0].x, line.points[0].y, line.points[0].z),
        (
            line.points[1].x,
            line.points[1].y,
            line.points[1].z,
        ),
    )
    assert math.dist(p, q) == np.min(gaps) or math.isclose(math.dist(p, q), np.min(gaps))
    assert (line.color.r, line.color.g, line.color.b) == RED  # V 0.03 < ε 0.05
    # the goal sphere sits at the tip of the goal configuration, in the cell frame
    np.testing.assert_allclose(
        [goal.pose.position.x, goal.pose.position.y, goal.pose.position.z], a[-1]
    )
    assert text.text == "ur5_0: planning, V 0.030 m"
    # no critical peer: the line is deleted, the text says so
    none = markers.build(None, states, None, "waiting", None, math.inf).markers
    assert none[0].action == 2 and none[1].action == 2  # DELETE
    assert none[2].text == "ur5_0: waiting, V no peer"


def test_the_committed_layout_is_generated_and_shows_recorded_topics() -> None:
    committed = (REPO / "nehmo_ros" / "config" / "foxglove_layout.json").read_text()
    assert committed == layout_text("dual_ur5"), (
        "foxglove_layout.json drifted: ./run python -m nehmo_ros.foxglove_layout dual_ur5 "
        "nehmo_ros/config/foxglove_layout.json"
    )
    layout = json.loads(committed)
    config = layout["configById"]
    recorded = set(ros_topics(list(CELL.arm_ids)))
    shown = set(config["3D!markers"]["topics"])
    for panel in config.values():
        shown |= {p["value"].split(".")[0] for p in panel.get("paths", [])}
        if "topicPath" in panel:
            shown.add(panel["topicPath"])
    assert shown <= recorded, shown - recorded
    # every panel the arrangement names is configured, and every configured panel is placed

    def placed(node: object) -> set[str]:
        if isinstance(node, str):
            return {node}
        assert isinstance(node, dict)
        return placed(node["first"]) | placed(node["second"])

    assert placed(layout["layout"]) == set(config)
