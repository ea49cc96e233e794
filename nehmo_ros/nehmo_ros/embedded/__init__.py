"""An rclpy-compatible runtime over Eclipse Cyclone DDS (``cyclonedds`` on PyPI).

It follows ROS 2's DDS conventions (topic ``rt/<name>``, type ``<pkg>::msg::dds_::<Type>_``,
XCDR1, keyless, ROS default QoS), so a ROS 2 Jazzy machine using rmw_cyclonedds sees its topics.
Only what the NeHMO nodes need is implemented; import it through :mod:`nehmo_ros.ros`.
"""

from nehmo_ros.embedded.arguments import remove_ros_args
from nehmo_ros.embedded.clock import Clock, ClockType, Duration, ROSClock, Time
from nehmo_ros.embedded.config import DdsConfig, dds_config
from nehmo_ros.embedded.context import Context, default_context
from nehmo_ros.embedded.exceptions import (
    ExternalShutdownException,
    InvalidParameterTypeException,
    InvalidParameterValueException,
    ParameterAlreadyDeclaredException,
    ParameterException,
    ParameterNotDeclaredException,
    ParameterUninitializedException,
    RosArgsError,
)
from nehmo_ros.embedded.executors import (
    Executor,
    MultiThreadedExecutor,
    SingleThreadedExecutor,
    get_global_executor,
    init,
    ok,
    shutdown,
    spin,
    spin_once,
    try_shutdown,
)
from nehmo_ros.embedded.node import (
    CallbackGroup,
    MutuallyExclusiveCallbackGroup,
    Node,
    Publisher,
    RcutilsLogger,
    ReentrantCallbackGroup,
    Subscription,
    Timer,
)
from nehmo_ros.embedded.parameters import Parameter, ParameterDescriptor, ParameterValue
from nehmo_ros.embedded.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_default,
    qos_profile_sensor_data,
)

__all__ = [
    "CallbackGroup",
    "Clock",
    "ClockType",
    "Context",
    "DdsConfig",
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
    "ParameterValue",
    "Publisher",
    "QoSProfile",
    "ROSClock",
    "RcutilsLogger",
    "ReentrantCallbackGroup",
    "ReliabilityPolicy",
    "RosArgsError",
    "SingleThreadedExecutor",
    "Subscription",
    "Time",
    "Timer",
    "dds_config",
    "default_context",
    "get_global_executor",
    "init",
    "ok",
    "qos_profile_default",
    "qos_profile_sensor_data",
    "remove_ros_args",
    "shutdown",
    "spin",
    "spin_once",
    "try_shutdown",
]
