"""The ROS 2 message types of the NeHMO suite, as plain dataclasses with a CDR codec.

Field names and Python value types mirror rclpy's generated classes (``byte`` fields hold a
1-byte ``bytes``; sequences are lists here where rclpy uses ``array.array``), so node code works
with either. Each class records its ROS type name and its fields once; the CDR encoder, the
decoder and the ``.msg`` text stored in MCAP schemas are all derived from that one description.

Checked byte-for-byte against ``rosbags``' ROS 2 Jazzy serializer in ``tests/test_ros_msgs.py``.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, ClassVar

from nehmo_core.errors import UnknownNameError
from nehmo_core.logs.cdr import PRIMITIVE_TYPES, CdrReader, CdrWriter

#: Line that separates dependencies in a rosbag2 ``ros2msg`` schema (80 ``=``).
MSGDEF_SEPARATOR = "=" * 80


@dataclass(frozen=True)
class FieldSpec:
    """One field of a message: `kind` is a primitive, "string" or a type "pkg/msg/Name"."""

    name: str
    kind: str
    sequence: bool = False


@dataclass(frozen=True)
class ConstantSpec:
    """A constant of a message definition (e.g. ``byte OK=0``)."""

    name: str
    kind: str
    value: int


class RosMessage:
    """Base of the message dataclasses: the ROS type name and the ordered field list."""

    _TYPE: ClassVar[str] = ""
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = ()
    _CONSTANTS: ClassVar[tuple[ConstantSpec, ...]] = ()

    @classmethod
    def get_fields_and_field_types(cls) -> dict[str, str]:
        """Field name → ROS type, like rclpy's classmethod of the same name."""
        return {f.name: _field_type_text(f) for f in cls._FIELDS}


@dataclass
class Time(RosMessage):
    """builtin_interfaces/msg/Time: seconds [s] and nanoseconds [ns] since an epoch."""

    _TYPE: ClassVar[str] = "builtin_interfaces/msg/Time"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("sec", "int32"),
        FieldSpec("nanosec", "uint32"),
    )
    sec: int = 0
    nanosec: int = 0


@dataclass
class Header(RosMessage):
    """std_msgs/msg/Header: a time stamp and a coordinate frame name."""

    _TYPE: ClassVar[str] = "std_msgs/msg/Header"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("stamp", Time._TYPE),
        FieldSpec("frame_id", "string"),
    )
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class JointState(RosMessage):
    """sensor_msgs/msg/JointState: positions [rad], velocities [rad/s], efforts [N·m]."""

    _TYPE: ClassVar[str] = "sensor_msgs/msg/JointState"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("header", Header._TYPE),
        FieldSpec("name", "string", sequence=True),
        FieldSpec("position", "float64", sequence=True),
        FieldSpec("velocity", "float64", sequence=True),
        FieldSpec("effort", "float64", sequence=True),
    )
    header: Header = field(default_factory=Header)
    name: list[str] = field(default_factory=list)
    position: list[float] = field(default_factory=list)
    velocity: list[float] = field(default_factory=list)
    effort: list[float] = field(default_factory=list)


@dataclass
class MultiArrayDimension(RosMessage):
    """std_msgs/msg/MultiArrayDimension."""

    _TYPE: ClassVar[str] = "std_msgs/msg/MultiArrayDimension"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("label", "string"),
        FieldSpec("size", "uint32"),
        FieldSpec("stride", "uint32"),
    )
    label: str = ""
    size: int = 0
    stride: int = 0


@dataclass
class MultiArrayLayout(RosMessage):
    """std_msgs/msg/MultiArrayLayout."""

    _TYPE: ClassVar[str] = "std_msgs/msg/MultiArrayLayout"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("dim", MultiArrayDimension._TYPE, sequence=True),
        FieldSpec("data_offset", "uint32"),
    )
    dim: list[MultiArrayDimension] = field(default_factory=list)
    data_offset: int = 0


@dataclass
class Float64MultiArray(RosMessage):
    """std_msgs/msg/Float64MultiArray: ros2_control's forward-command message."""

    _TYPE: ClassVar[str] = "std_msgs/msg/Float64MultiArray"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("layout", MultiArrayLayout._TYPE),
        FieldSpec("data", "float64", sequence=True),
    )
    layout: MultiArrayLayout = field(default_factory=MultiArrayLayout)
    data: list[float] = field(default_factory=list)


@dataclass
class String(RosMessage):
    """std_msgs/msg/String."""

    _TYPE: ClassVar[str] = "std_msgs/msg/String"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (FieldSpec("data", "string"),)
    data: str = ""


@dataclass
class Clock(RosMessage):
    """rosgraph_msgs/msg/Clock: the simulated time published on ``/clock``."""

    _TYPE: ClassVar[str] = "rosgraph_msgs/msg/Clock"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (FieldSpec("clock", Time._TYPE),)
    clock: Time = field(default_factory=Time)


@dataclass
class KeyValue(RosMessage):
    """diagnostic_msgs/msg/KeyValue."""

    _TYPE: ClassVar[str] = "diagnostic_msgs/msg/KeyValue"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("key", "string"),
        FieldSpec("value", "string"),
    )
    key: str = ""
    value: str = ""


@dataclass
class DiagnosticStatus(RosMessage):
    """diagnostic_msgs/msg/DiagnosticStatus; `level` is a 1-byte ``bytes`` as in rclpy."""

    _TYPE: ClassVar[str] = "diagnostic_msgs/msg/DiagnosticStatus"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("level", "byte"),
        FieldSpec("name", "string"),
        FieldSpec("message", "string"),
        FieldSpec("hardware_id", "string"),
        FieldSpec("values", KeyValue._TYPE, sequence=True),
    )
    _CONSTANTS: ClassVar[tuple[ConstantSpec, ...]] = (
        ConstantSpec("OK", "byte", 0),
        ConstantSpec("WARN", "byte", 1),
        ConstantSpec("ERROR", "byte", 2),
        ConstantSpec("STALE", "byte", 3),
    )
    OK: ClassVar[bytes] = b"\x00"
    WARN: ClassVar[bytes] = b"\x01"
    ERROR: ClassVar[bytes] = b"\x02"
    STALE: ClassVar[bytes] = b"\x03"
    level: bytes = b"\x00"
    name: str = ""
    message: str = ""
    hardware_id: str = ""
    values: list[KeyValue] = field(default_factory=list)


@dataclass
class DiagnosticArray(RosMessage):
    """diagnostic_msgs/msg/DiagnosticArray."""

    _TYPE: ClassVar[str] = "diagnostic_msgs/msg/DiagnosticArray"
    _FIELDS: ClassVar[tuple[FieldSpec, ...]] = (
        FieldSpec("header", Header._TYPE),
        FieldSpec("status", DiagnosticStatus._TYPE, sequence=True),
    )
    header: Header = field(default_factory=Header)
    status: list[DiagnosticStatus] = field(default_factory=list)


#: Every message class of the suite by ROS type name ("sensor_msgs/msg/JointState").
MESSAGE_TYPES: dict[str, type[RosMessage]] = {
    cls._TYPE: cls
    for cls in (
        Time,
        Header,
        JointState,
        MultiArrayDimension,
        MultiArrayLayout,
        Float64MultiArray,
        String,
        Clock,
        KeyValue,
        DiagnosticStatus,
        DiagnosticArray,
    )
}


def message_class(msgtype: str) -> type[RosMessage]:
    """The class of ROS type `msgtype`; raises listing the known types otherwise."""
    try:
        return MESSAGE_TYPES[msgtype]
    except KeyError:
        raise UnknownNameError("message type", msgtype, MESSAGE_TYPES) from None


def msgtype_of(msg: object) -> str:
    """ROS type name of a message instance or class, ours or rclpy's generated one."""
    cls = msg if isinstance(msg, type) else type(msg)
    own = getattr(cls, "_TYPE", "")
    if own:
        return str(own)
    package = cls.__module__.split(".")[0]  # rclpy: "sensor_msgs.msg._joint_state"
    return f"{package}/msg/{cls.__name__}"


# ---------------------------------------------------------------------------------------- CDR


def _byte_value(value: object) -> int:
    if isinstance(value, bytes | bytearray):
        if len(value) != 1:
            raise ValueError(f"a byte field needs exactly 1 byte; got {bytes(value)!r}")
        return value[0]
    return int(value)  # type: ignore[call-overload]


def _encode_fields(writer: CdrWriter, msg: object, cls: type[RosMessage]) -> None:
    for spec in cls._FIELDS:
        value = getattr(msg, spec.name)
        kind = spec.kind
        if kind == "string":
            if spec.sequence:
                writer.strings(value)
            else:
                writer.string(value)
        elif kind in PRIMITIVE_TYPES:
            if kind == "byte":
                value = [_byte_value(v) for v in value] if spec.sequence else _byte_value(value)
            if spec.sequence:
                writer.primitives(kind, value)
            else:
                writer.primitive(kind, value)
        else:
            sub = MESSAGE_TYPES[kind]
            if spec.sequence:
                items = list(value)
                writer.count(len(items))
                for item in items:
                    _encode_fields(writer, item, sub)
            else:
                _encode_fields(writer, value, sub)


def _decode_fields(reader: CdrReader, cls: type[RosMessage]) -> RosMessage:
    values: dict[str, Any] = {}
    for spec in cls._FIELDS:
        kind = spec.kind
        if kind == "string":
            values[spec.name] = reader.strings() if spec.sequence else reader.string()
        elif kind in PRIMITIVE_TYPES:
            if spec.sequence:
                items = reader.primitives(kind)
                values[spec.name] = [bytes([v]) for v in items] if kind == "byte" else items  # type: ignore[list-item]
            else:
                item = reader.primitive(kind)
                values[spec.name] = bytes([item]) if kind == "byte" else item  # type: ignore[list-item]
        else:
            sub = MESSAGE_TYPES[kind]
            if spec.sequence:
                values[spec.name] = [_decode_fields(reader, sub) for _ in range(reader.count())]
            else:
                values[spec.name] = _decode_fields(reader, sub)
    return cls(**values)


def serialize(msg: object, msgtype: str | None = None) -> bytes:
    """CDR bytes (with the encapsulation header) of `msg`.

    `msg` may be one of our dataclasses or any object with the same attributes (an rclpy
    message, for instance); `msgtype` defaults to the type name of `msg`.
    """
    cls = message_class(msgtype or msgtype_of(msg))
    writer = CdrWriter()
    _encode_fields(writer, msg, cls)
    return writer.getvalue()


def deserialize(data: bytes | bytearray | memoryview, msgtype: str) -> RosMessage:
    """Decode CDR bytes of ROS type `msgtype` into our dataclass."""
    cls = message_class(msgtype)
    return _decode_fields(CdrReader(data), cls)


def to_dict(msg: RosMessage) -> dict[str, Any]:
    """The message as nested plain dicts and lists (for JSON or comparisons)."""
    return dataclasses.asdict(msg)  # type: ignore[call-overload]


# ------------------------------------------------------------------------------- .msg texts


def _field_type_text(spec: FieldSpec) -> str:
    if "/msg/" in spec.kind:
        package, _, name = spec.kind.partition("/msg/")
        text = f"{package}/{name}"
    else:
        text = spec.kind
    return text + ("[]" if spec.sequence else "")


def own_definition(msgtype: str) -> str:
    """The ``.msg`` text of one type (fields and constants, no dependencies)."""
    cls = message_class(msgtype)
    lines = [f"{c.kind} {c.name}={c.value}" for c in cls._CONSTANTS]
    lines += [f"{_field_type_text(f)} {f.name}" for f in cls._FIELDS]
    return "\n".join(lines) + "\n"


def dependencies(msgtype: str) -> list[str]:
    """Every message type `msgtype` uses, recursively, in first-use order."""
    found: list[str] = []

    def visit(name: str) -> None:
        for spec in message_class(name)._FIELDS:
            if spec.kind in MESSAGE_TYPES and spec.kind not in found:
                found.append(spec.kind)
                visit(spec.kind)

    visit(msgtype)
    return found


def message_definition(msgtype: str) -> str:
    """The rosbag2 ``ros2msg`` schema text: the type's .msg, then each dependency's.

    Each dependency is preceded by a line of 80 ``=`` and a line ``MSG: pkg/msg/Type``.
    """
    parts = [own_definition(msgtype)]
    for dep in dependencies(msgtype):
        parts.append(f"{MSGDEF_SEPARATOR}\nMSG: {dep}\n{own_definition(dep)}")
    return "".join(parts)


def all_message_types() -> Iterable[str]:
    """The ROS type names this module can encode and decode."""
    return tuple(MESSAGE_TYPES)
