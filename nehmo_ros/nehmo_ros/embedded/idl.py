# mypy: disable-error-code="type-arg, assignment"
"""cyclonedds ``IdlStruct`` mirrors of the suite's ROS 2 messages, and conversions.

ROS 2 over DDS names a type ``<pkg>::msg::dds_::<Type>_`` and serializes it as XCDR1 (these
structs are final, never ``@appendable``, which would switch cyclonedds to XCDR2) with no key.
Integer widths are explicit: a bare ``int`` would become int64. No ``from __future__ import
annotations`` here: cyclonedds resolves the annotations at run time. Nodes never see these classes:
they register the topics' types, and publishers convert the dataclasses of
``nehmo_core.logs.messages`` through them. The CDR they produce is byte for byte that of
``nehmo_core.logs.messages.serialize``, so CDR bytes are published as they are and samples are
taken as CDR and decoded with that codec (:mod:`nehmo_ros.embedded.node`).
"""

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import byte, float64, int32, sequence, uint32

from nehmo_core.logs.messages import MESSAGE_TYPES, RosMessage


@dataclass
class Time_(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header_(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time_ = field(default_factory=Time_)
    frame_id: str = ""


@dataclass
class JointState_(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header_ = field(default_factory=Header_)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


@dataclass
class MultiArrayDimension_(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayDimension_"):
    label: str = ""
    size: uint32 = 0
    stride: uint32 = 0


@dataclass
class MultiArrayLayout_(IdlStruct, typename="std_msgs::msg::dds_::MultiArrayLayout_"):
    dim: sequence[MultiArrayDimension_] = field(default_factory=list)
    data_offset: uint32 = 0


@dataclass
class Float64MultiArray_(IdlStruct, typename="std_msgs::msg::dds_::Float64MultiArray_"):
    layout: MultiArrayLayout_ = field(default_factory=MultiArrayLayout_)
    data: sequence[float64] = field(default_factory=list)


@dataclass
class String_(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@dataclass
class Clock_(IdlStruct, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time_ = field(default_factory=Time_)


@dataclass
class KeyValue_(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus_(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: byte = 0
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: sequence[KeyValue_] = field(default_factory=list)


@dataclass
class DiagnosticArray_(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header_ = field(default_factory=Header_)
    status: sequence[DiagnosticStatus_] = field(default_factory=list)


#: ROS type name ("sensor_msgs/msg/JointState") → IdlStruct class.
IDL_TYPES: dict[str, type[IdlStruct]] = {
    "builtin_interfaces/msg/Time": Time_,
    "std_msgs/msg/Header": Header_,
    "sensor_msgs/msg/JointState": JointState_,
    "std_msgs/msg/MultiArrayDimension": MultiArrayDimension_,
    "std_msgs/msg/MultiArrayLayout": MultiArrayLayout_,
    "std_msgs/msg/Float64MultiArray": Float64MultiArray_,
    "std_msgs/msg/String": String_,
    "rosgraph_msgs/msg/Clock": Clock_,
    "diagnostic_msgs/msg/KeyValue": KeyValue_,
    "diagnostic_msgs/msg/DiagnosticStatus": DiagnosticStatus_,
    "diagnostic_msgs/msg/DiagnosticArray": DiagnosticArray_,
}

_INTS = {"int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64"}


def dds_type_name(msgtype: str) -> str:
    """``sensor_msgs/msg/JointState`` → ``sensor_msgs::msg::dds_::JointState_``."""
    package, _, name = msgtype.partition("/msg/")
    return f"{package}::msg::dds_::{name}_"


def _convert_out(kind: str, value: Any) -> Any:
    if kind == "float64" or kind == "float32":
        return float(value)
    if kind in _INTS:
        return int(value)
    if kind == "byte":
        return value[0] if isinstance(value, bytes | bytearray) else int(value)
    if kind == "bool":
        return bool(value)
    if kind == "string":
        return str(value)
    return to_idl(value, kind)


def _field_values(obj: Any, msgtype: str, convert: Callable[[str, Any], Any]) -> dict[str, Any]:
    """Every field of ``msgtype`` read from ``obj`` and passed through ``convert``."""
    values: dict[str, Any] = {}
    for spec in MESSAGE_TYPES[msgtype]._FIELDS:
        value = getattr(obj, spec.name)
        if spec.sequence:
            values[spec.name] = [convert(spec.kind, item) for item in value]
        else:
            values[spec.name] = convert(spec.kind, value)
    return values


def to_idl(msg: Any, msgtype: str) -> IdlStruct:
    """The IdlStruct sample of `msg` (our dataclass, or anything with the same fields)."""
    return IDL_TYPES[msgtype](**_field_values(msg, msgtype, _convert_out))


def _convert_in(kind: str, value: Any) -> Any:
    if kind == "byte":
        return bytes([value])
    if kind in MESSAGE_TYPES:
        return from_idl(value, kind)
    return value


def from_idl(sample: Any, msgtype: str) -> RosMessage:
    """Our dataclass from an IdlStruct sample."""
    return MESSAGE_TYPES[msgtype](**_field_values(sample, msgtype, _convert_in))
