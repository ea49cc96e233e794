"""The one ROS import of the NeHMO nodes: rclpy when it is installed, else the embedded runtime.

Nodes write ``from nehmo_ros import ros`` and use ``ros.Node``, ``ros.init``, ``ros.spin``,
``ros.qos_profile_sensor_data``, ``ros.msg.JointState`` ... exactly as they would use rclpy and
the generated message packages; they never look at which runtime they got.

Choice (once, at import): ``NEHMO_RUNTIME=rclpy`` or ``embedded`` forces one (forcing rclpy
where it cannot be imported is an ImportError); unset, rclpy is used if ``import rclpy`` works.
``RUNTIME`` tells which one was picked (for logs, not for branching).

The embedded runtime speaks ROS 2's wire format over Cyclone DDS on loopback only unless
configured otherwise; see :mod:`nehmo_ros.embedded.config` and nehmo_ros/README.md.
"""

from __future__ import annotations

import importlib.util
import os
from typing import TYPE_CHECKING, Any


def _choose_runtime() -> str:
    forced = os.environ.get("NEHMO_RUNTIME", "").strip().lower()
    if forced not in ("", "rclpy", "embedded"):
        raise ImportError(f"NEHMO_RUNTIME must be 'rclpy' or 'embedded'; got {forced!r}")
    if forced == "embedded":
        return "embedded"
    try:
        found = importlib.util.find_spec("rclpy") is not None
    except (ImportError, ValueError):
        found = False
    if forced == "rclpy" and not found:
        raise ImportError("NEHMO_RUNTIME=rclpy but rclpy cannot be imported (source ROS 2 first)")
    return "rclpy" if found else "embedded"


RUNTIME: str = _choose_runtime()

if TYPE_CHECKING or RUNTIME == "embedded":
    from nehmo_ros import msgs as msg
    from nehmo_ros.embedded import (
        CallbackGroup,
        Clock,
        ClockType,
        DurabilityPolicy,
        Duration,
        Executor,
        ExternalShutdownException,
        HistoryPolicy,
        InvalidParameterTypeException,
        InvalidParameterValueException,
        MultiThreadedExecutor,
        MutuallyExclusiveCallbackGroup,
        Node,
        Parameter,
        ParameterAlreadyDeclaredException,
        ParameterDescriptor,
        ParameterException,
        ParameterNotDeclaredException,
        ParameterUninitializedException,
        Publisher,
        QoSProfile,
        ReentrantCallbackGroup,
        ReliabilityPolicy,
        RosArgsError,
        SingleThreadedExecutor,
        Subscription,
        Time,
        Timer,
        get_global_executor,
        init,
        ok,
        qos_profile_default,
        qos_profile_sensor_data,
        remove_ros_args,
        shutdown,
        spin,
        spin_once,
        try_shutdown,
    )
else:  # pragma: no cover - needs a ROS 2 installation
    import types

    import builtin_interfaces.msg as _builtin_interfaces
    import diagnostic_msgs.msg as _diagnostic_msgs
    import rclpy
    import rclpy.exceptions as _exc
    import rosgraph_msgs.msg as _rosgraph_msgs
    import sensor_msgs.msg as _sensor_msgs
    import std_msgs.msg as _std_msgs
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.callback_groups import (
        CallbackGroup,
        MutuallyExclusiveCallbackGroup,
        ReentrantCallbackGroup,
    )
    from rclpy.clock import Clock, ClockType
    from rclpy.duration import Duration
    from rclpy.executors import (
        Executor,
        ExternalShutdownException,
        MultiThreadedExecutor,
        SingleThreadedExecutor,
        get_global_executor,
    )
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.publisher import Publisher
    from rclpy.qos import (
        DurabilityPolicy,
        HistoryPolicy,
        QoSProfile,
        ReliabilityPolicy,
        qos_profile_sensor_data,
    )
    from rclpy.subscription import Subscription
    from rclpy.time import Time
    from rclpy.timer import Timer
    from rclpy.utilities import remove_ros_args

    from nehmo_core.logs.messages import deserialize as _deserialize
    from nehmo_core.logs.messages import serialize as _serialize

    init = rclpy.init
    ok = rclpy.ok
    shutdown = rclpy.shutdown
    try_shutdown = rclpy.try_shutdown
    spin = rclpy.spin
    spin_once = rclpy.spin_once
    qos_profile_default = QoSProfile(depth=10)
    ParameterException = getattr(_exc, "ParameterException", Exception)
    ParameterNotDeclaredException = _exc.ParameterNotDeclaredException
    ParameterAlreadyDeclaredException = _exc.ParameterAlreadyDeclaredException
    ParameterUninitializedException = _exc.ParameterUninitializedException
    InvalidParameterValueException = _exc.InvalidParameterValueException
    InvalidParameterTypeException = _exc.InvalidParameterTypeException
    RosArgsError = getattr(getattr(rclpy, "_rclpy_pybind11", None), "RCLError", RuntimeError)
    msg = types.SimpleNamespace(
        Time=_builtin_interfaces.Time,
        Header=_std_msgs.Header,
        String=_std_msgs.String,
        Float64MultiArray=_std_msgs.Float64MultiArray,
        MultiArrayLayout=_std_msgs.MultiArrayLayout,
        MultiArrayDimension=_std_msgs.MultiArrayDimension,
        JointState=_sensor_msgs.JointState,
        Clock=_rosgraph_msgs.Clock,
        DiagnosticStatus=_diagnostic_msgs.DiagnosticStatus,
        DiagnosticArray=_diagnostic_msgs.DiagnosticArray,
        KeyValue=_diagnostic_msgs.KeyValue,
        serialize=_serialize,
        deserialize=_deserialize,
    )

#: What a node's main() catches to print one clear line for bad parameters or arguments.
PARAMETER_ERRORS: tuple[type[BaseException], ...] = (
    ParameterException,
    ParameterNotDeclaredException,
    ParameterUninitializedException,
    InvalidParameterValueException,
    RosArgsError,
    ValueError,
)


def describe() -> dict[str, Any]:
    """Which runtime is in use (for a node's start-up log line)."""
    return {"runtime": RUNTIME, "domain_id": os.environ.get("ROS_DOMAIN_ID", "0")}


__all__ = [
    "PARAMETER_ERRORS",
    "RUNTIME",
    "CallbackGroup",
    "Clock",
    "ClockType",
    "DurabilityPolicy",
    "Duration",
    "Executor",
    "ExternalShutdownException",
    "HistoryPolicy",
    "InvalidParameterTypeException",
    "InvalidParameterValueException",
    "MultiThreadedExecutor",
    "MutuallyExclusiveCallbackGroup",
    "Node",
    "Parameter",
    "ParameterAlreadyDeclaredException",
    "ParameterDescriptor",
    "ParameterException",
    "ParameterNotDeclaredException",
    "ParameterUninitializedException",
    "Publisher",
    "QoSProfile",
    "ReentrantCallbackGroup",
    "ReliabilityPolicy",
    "RosArgsError",
    "SingleThreadedExecutor",
    "Subscription",
    "Time",
    "Timer",
    "describe",
    "get_global_executor",
    "init",
    "msg",
    "ok",
    "qos_profile_default",
    "qos_profile_sensor_data",
    "remove_ros_args",
    "shutdown",
    "spin",
    "spin_once",
    "try_shutdown",
]
