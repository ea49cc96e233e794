"""The standard ROS 2 messages of the suite, importable without ROS.

These are ``nehmo_core.logs.messages``' dataclasses (one definition shared with the MCAP logs);
their field names and value types mirror rclpy's generated classes, so node code written against
``ros.msg.JointState`` runs unchanged when :mod:`nehmo_ros.ros` hands out rclpy's real classes.

=============================== =======================================================
module of rclpy                 classes
=============================== =======================================================
builtin_interfaces.msg          Time
std_msgs.msg                    Header, String, Float64MultiArray, MultiArrayLayout,
                                MultiArrayDimension
sensor_msgs.msg                 JointState
rosgraph_msgs.msg               Clock
diagnostic_msgs.msg             DiagnosticStatus, DiagnosticArray, KeyValue
=============================== =======================================================
"""

from nehmo_core.logs.messages import (
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
    serialize,
)

__all__ = [
    "Clock",
    "DiagnosticArray",
    "DiagnosticStatus",
    "Float64MultiArray",
    "Header",
    "JointState",
    "KeyValue",
    "MultiArrayDimension",
    "MultiArrayLayout",
    "RosMessage",
    "String",
    "Time",
    "deserialize",
    "serialize",
]
