"""The MCAP log schema of NeHMO: one writer and one reader for batch runs and the ROS recorder.

Logs are rosbag2-compatible MCAP (profile ``ros2``, ``ros2msg`` schemas, ``cdr`` messages), so
``ros2 bag``, Foxglove and the ``mcap`` and ``rosbags`` readers open them. Topics are
listed in :mod:`nehmo_core.logs.topics`; message classes and their CDR codec live in
:mod:`nehmo_core.logs.messages`. A log whose writer was killed is repaired with
``python -m nehmo_core.logs.recover broken.mcap fixed.mcap`` (in code:
:func:`nehmo_core.logs.recover.recover`).
"""

from nehmo_core.logs.messages import (
    MESSAGE_TYPES,
    Clock,
    DiagnosticArray,
    DiagnosticStatus,
    Float64MultiArray,
    Header,
    JointState,
    KeyValue,
    MultiArrayDimension,
    MultiArrayLayout,
    RosMessage,
    String,
    Time,
    deserialize,
    message_definition,
    serialize,
)
from nehmo_core.logs.reader import (
    LogFileError,
    LogRecord,
    LogSummary,
    iter_log,
    read_log,
    read_scenario,
    summarize,
)
from nehmo_core.logs.topics import (
    CLOCK_TOPIC,
    COLLISIONS_TOPIC,
    SCENARIO_TOPIC,
    arm_topics,
    command_topic,
    goal_topic,
    joint_states_topic,
    run_topics,
    status_topic,
    topic_type,
)
from nehmo_core.logs.writer import LogWriter, LogWriterError, QosDescription, WriterSettings

__all__ = [
    "CLOCK_TOPIC",
    "COLLISIONS_TOPIC",
    "MESSAGE_TYPES",
    "SCENARIO_TOPIC",
    "Clock",
    "DiagnosticArray",
    "DiagnosticStatus",
    "Float64MultiArray",
    "Header",
    "JointState",
    "KeyValue",
    "LogFileError",
    "LogRecord",
    "LogSummary",
    "LogWriter",
    "LogWriterError",
    "MultiArrayDimension",
    "MultiArrayLayout",
    "QosDescription",
    "RosMessage",
    "String",
    "Time",
    "WriterSettings",
    "arm_topics",
    "command_topic",
    "deserialize",
    "goal_topic",
    "iter_log",
    "joint_states_topic",
    "message_definition",
    "read_log",
    "read_scenario",
    "run_topics",
    "serialize",
    "status_topic",
    "summarize",
    "topic_type",
]
