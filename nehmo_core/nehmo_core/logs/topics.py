"""Topic names and message types of a NeHMO run, shared by batch runs and ROS.

Per arm ``<arm_id>``:

================================================ ==================================
topic                                            type
================================================ ==================================
``/<arm_id>/joint_states``                       sensor_msgs/msg/JointState
``/<arm_id>/velocity_controller/commands``       std_msgs/msg/Float64MultiArray
``/<arm_id>/goal``                               sensor_msgs/msg/JointState
``/<arm_id>/planner/status``                     diagnostic_msgs/msg/DiagnosticStatus
``/<arm_id>/planner/speed_bound``                std_msgs/msg/Float64
================================================ ==================================

``planner/speed_bound`` is the speed bound the arm announces with each command, a fraction of
its top speed (1: none; see :mod:`nehmo_core.planning.stages.speed_bounds`).

A ROS run's bag also holds ``/<arm_id>/planner/markers`` (visualization_msgs/msg/MarkerArray,
what a planner node shows RViz and Foxglove) and ``/<arm_id>/planner/min_value``
(std_msgs/msg/Float64, the smallest V [m], to plot), both at about 5 Hz (:func:`ros_topics`);
batch runs write neither.

Run-wide: ``/clock`` (rosgraph_msgs/msg/Clock), ``/nehmo/collisions``
(diagnostic_msgs/msg/DiagnosticArray, one status per colliding pair, published by the simulator)
and ``/nehmo/scenario`` (std_msgs/msg/String holding the scenario as JSON).
"""

from __future__ import annotations

import re

from nehmo_core.errors import InvalidValueError, UnknownNameError

CLOCK_TOPIC = "/clock"
COLLISIONS_TOPIC = "/nehmo/collisions"
SCENARIO_TOPIC = "/nehmo/scenario"

JOINT_STATE_TYPE = "sensor_msgs/msg/JointState"
COMMAND_TYPE = "std_msgs/msg/Float64MultiArray"
STATUS_TYPE = "diagnostic_msgs/msg/DiagnosticStatus"
COLLISIONS_TYPE = "diagnostic_msgs/msg/DiagnosticArray"
CLOCK_TYPE = "rosgraph_msgs/msg/Clock"
SCENARIO_TYPE = "std_msgs/msg/String"
SPEED_BOUND_TYPE = "std_msgs/msg/Float64"
MARKERS_TYPE = "visualization_msgs/msg/MarkerArray"

_ARM_ID = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")

# Per-arm topic suffix → message type.
_ARM_TOPICS: dict[str, str] = {
    "joint_states": JOINT_STATE_TYPE,
    "velocity_controller/commands": COMMAND_TYPE,
    "goal": JOINT_STATE_TYPE,
    "planner/status": STATUS_TYPE,
    "planner/speed_bound": SPEED_BOUND_TYPE,
}
_RUN_TOPICS: dict[str, str] = {
    CLOCK_TOPIC: CLOCK_TYPE,
    COLLISIONS_TOPIC: COLLISIONS_TYPE,
    SCENARIO_TOPIC: SCENARIO_TYPE,
}


def check_arm_id(arm_id: str) -> str:
    """`arm_id` if it is a valid ROS name token (letter, then letters, digits, underscores)."""
    if not isinstance(arm_id, str) or not _ARM_ID.match(arm_id):
        raise InvalidValueError(
            "arm_id", "must start with a letter and hold only letters, digits and '_'", arm_id
        )
    return arm_id


def joint_states_topic(arm_id: str) -> str:
    """``/<arm_id>/joint_states``: the arm's measured state."""
    return f"/{check_arm_id(arm_id)}/joint_states"


def command_topic(arm_id: str) -> str:
    """``/<arm_id>/velocity_controller/commands``: joint velocity commands [rad/s]."""
    return f"/{check_arm_id(arm_id)}/velocity_controller/commands"


def goal_topic(arm_id: str) -> str:
    """``/<arm_id>/goal``: the goal configuration as a JointState."""
    return f"/{check_arm_id(arm_id)}/goal"


def status_topic(arm_id: str) -> str:
    """``/<arm_id>/planner/status``: planner telemetry."""
    return f"/{check_arm_id(arm_id)}/planner/status"


def speed_bound_topic(arm_id: str) -> str:
    """``/<arm_id>/planner/speed_bound``: the announced speed bound (a fraction of ū)."""
    return f"/{check_arm_id(arm_id)}/planner/speed_bound"


def arm_topics(arm_id: str) -> dict[str, str]:
    """Every per-arm topic of `arm_id` with its message type."""
    check_arm_id(arm_id)
    return {f"/{arm_id}/{suffix}": msgtype for suffix, msgtype in _ARM_TOPICS.items()}


def run_topics(arm_ids: list[str]) -> dict[str, str]:
    """Every topic of a run with arms `arm_ids`, with its message type."""
    topics = dict(_RUN_TOPICS)
    for arm_id in arm_ids:
        topics.update(arm_topics(arm_id))
    return topics


def markers_topic(arm_id: str) -> str:
    """A ROS planner's markers for RViz / Foxglove."""
    return f"/{check_arm_id(arm_id)}/planner/markers"


def min_value_topic(arm_id: str) -> str:
    """A ROS planner's smallest V [m], for plots."""
    return f"/{check_arm_id(arm_id)}/planner/min_value"


def ros_topics(arm_ids: list[str]) -> dict[str, str]:
    """:func:`run_topics` and what only the ROS nodes publish (the planners' markers and V)."""
    extra = {markers_topic(a): MARKERS_TYPE for a in arm_ids}
    extra.update({min_value_topic(a): SPEED_BOUND_TYPE for a in arm_ids})
    return {**run_topics(arm_ids), **extra}


def split_arm_topic(topic: str) -> tuple[str, str] | None:
    """``("ur5_0", "joint_states")`` for ``/ur5_0/joint_states``; None if not a per-arm topic."""
    parts = topic.lstrip("/").split("/", 1)
    if len(parts) == 2 and parts[1] in _ARM_TOPICS and _ARM_ID.match(parts[0]):
        return parts[0], parts[1]
    return None


def topic_type(topic: str) -> str:
    """The message type of a schema topic; raises for a topic outside the schema."""
    if topic in _RUN_TOPICS:
        return _RUN_TOPICS[topic]
    split = split_arm_topic(topic)
    if split is not None:
        return _ARM_TOPICS[split[1]]
    valid = [*_RUN_TOPICS, *(f"/<arm_id>/{s}" for s in _ARM_TOPICS)]
    raise UnknownNameError("log topic", topic, valid)
