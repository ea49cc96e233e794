"""The ROS 2 messages of the NeHMO suite, served by the ``rosbags`` ROS 2 Jazzy typestore.

The names below (``JointState``, ``DiagnosticStatus``, ...) build the typestore's own dataclass
instances from keyword arguments; a field left out gets its zero value (0, "", an empty
sequence, a zero nested message), and lists given for numeric sequences become the numpy
arrays the typestore needs::

    msg = JointState(header=Header(stamp=Time(sec=1)), name=["j1"], position=[0.5])
    data = serialize(msg)                  # CDR, 4-byte encapsulation header first
    deserialize(data, msgtype_of(msg))     # back to a typestore instance

``isinstance(x, JointState)`` holds for any typestore instance of that ROS type, and constants
stay on the names (``DiagnosticStatus.WARN == 1``; ``byte`` fields are ints here, as in
``rosbags``). Definitions (``message_definition``) and hashes come from the same typestore, so
the CDR, the ``ros2msg`` schema text and the RIHS01 hash all match ROS 2 Jazzy.
"""

from __future__ import annotations

import struct
from collections.abc import Callable, Iterable, Mapping
from functools import cache
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from nehmo_core.errors import InvalidValueError, NehmoError, UnknownNameError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = [
    "MESSAGE_TYPES",
    "Clock",
    "DiagnosticArray",
    "DiagnosticStatus",
    "Float64",
    "Float64MultiArray",
    "Header",
    "JointState",
    "KeyValue",
    "MessageError",
    "MultiArrayDimension",
    "MultiArrayLayout",
    "RosMessage",
    "String",
    "Time",
    "build",
    "deserialize",
    "leading_stamp_ns",
    "message_definition",
    "msgtype_of",
    "serialize",
    "type_hash",
    "typestore",
]

# CDR encapsulation identifiers (first two bytes of a serialized message).
_CDR_LE = b"\x00\x01"
_CDR_BE = b"\x00\x00"
_STAMP = {_CDR_LE: struct.Struct("<iI"), _CDR_BE: struct.Struct(">iI")}


class MessageError(NehmoError, ValueError):
    """Bytes that are not a CDR message of the given type, or a message that cannot be encoded."""


@cache
def typestore() -> Typestore:
    """The ``rosbags`` ROS 2 Jazzy typestore (types, CDR codec, definitions, hashes)."""
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS2_JAZZY)


def _store_class(msgtype: str) -> type:
    try:
        return typestore().types[msgtype]
    except KeyError:
        raise UnknownNameError("message type", msgtype, typestore().types) from None


# ------------------------------------------------------------------ field defaults and coercion

_FieldDef = tuple[Any, Any]  # rosbags (Nodetype, details)


@cache
def _numpy_dtype(base: str) -> np.dtype[Any]:
    from rosbags.serde.utils import ndtype

    return np.dtype(ndtype(base))


def _base_default(base: str) -> object:
    if base == "string" or base == "wstring":
        return ""
    if base == "bool":
        return False
    if base.startswith("float"):
        return 0.0
    return 0


def _default(fdef: _FieldDef) -> object:
    from rosbags.typesys.base import Nodetype

    kind, detail = fdef
    if kind == Nodetype.BASE:
        return _base_default(detail[0])
    if kind == Nodetype.NAME:
        return build(detail)
    sub, length = detail
    if sub[0] == Nodetype.BASE and sub[1][0] not in ("string", "wstring"):
        return np.zeros(length if kind == Nodetype.ARRAY else 0, dtype=_numpy_dtype(sub[1][0]))
    return [_default(sub) for _ in range(length)] if kind == Nodetype.ARRAY else []


def _coerce(fdef: _FieldDef, value: object, where: str, rebuild: bool = False) -> object:
    """`value` in the form the typestore's serializer needs (numpy arrays, nested instances).

    A nested typestore instance is kept as it is unless `rebuild`.
    """
    from rosbags.typesys.base import Nodetype

    kind, detail = fdef
    if kind == Nodetype.BASE:
        if detail[0] in ("byte", "char") and isinstance(value, bytes | bytearray):
            if len(value) != 1:
                raise InvalidValueError(where, "is a byte field and needs exactly 1 byte", value)
            return value[0]
        return value
    if kind == Nodetype.NAME:
        if not rebuild and type(value) is _store_class(detail):
            return value
        return _as_store_message(value, detail, where, rebuild)
    sub, length = detail
    array: Any
    if sub[0] == Nodetype.BASE and sub[1][0] not in ("string", "wstring"):
        dtype = _numpy_dtype(sub[1][0])
        if (
            isinstance(value, np.ndarray)
            and value.dtype == dtype
            and value.ndim == 1
            and value.flags.c_contiguous
        ):
            array = value
        elif isinstance(value, bytes | bytearray) and dtype == np.uint8:
            array = np.frombuffer(bytes(value), dtype=np.uint8).copy()
        elif isinstance(value, str | bytes | bytearray):
            raise InvalidValueError(where, f"must be a sequence of {sub[1][0]}", value)
        else:
            try:
                array = np.ascontiguousarray(value, dtype=dtype).reshape(-1)
            except (TypeError, ValueError) as err:
                raise InvalidValueError(where, f"must be a sequence of {sub[1][0]}", value) from err
    else:
        if isinstance(value, str | bytes) or not isinstance(value, Iterable):
            raise InvalidValueError(where, "must be a sequence, not a single value", value)
        array = [_coerce(sub, item, where, rebuild) for item in value]
    if kind == Nodetype.ARRAY and len(array) != length:
        raise InvalidValueError(where, f"must hold exactly {length} items", len(array))
    return array


def _as_store_message(value: object, msgtype: str, where: str, rebuild: bool = False) -> object:
    """`value` as an instance of the typestore class of `msgtype` with well-formed fields."""
    cls = _store_class(msgtype)
    if isinstance(value, Mapping):
        return build(msgtype, **value)
    if msgtype_of(value) != msgtype and not isinstance(value, cls):
        raise InvalidValueError(where, f"must be a {msgtype}", value)
    fields = typestore().fielddefs[msgtype][1]
    return cls(
        *(_coerce(f, getattr(value, name), f"{where}.{name}", rebuild) for name, f in fields)
    )


def build(msgtype: str, **values: object) -> Any:
    """A typestore instance of `msgtype`; fields not given get their zero value."""
    cls = _store_class(msgtype)
    fields = typestore().fielddefs[msgtype][1]
    names = [name for name, _ in fields]
    unknown = sorted(set(values) - set(names))
    if unknown:
        raise InvalidValueError(f"{msgtype} field", f"must be one of {names}", unknown[0])
    args = [
        _coerce(fdef, values[name], f"{msgtype}.{name}") if name in values else _default(fdef)
        for name, fdef in fields
    ]
    return cls(*args)


# ------------------------------------------------------------------ the public message names


class _MessageMeta(type):
    """Calling a message name builds the typestore instance; isinstance compares ROS types."""

    __msgtype__: str

    def __call__(cls, **values: object) -> Any:
        return build(cls.__msgtype__, **values)

    def __instancecheck__(cls, obj: object) -> bool:
        if cls.__msgtype__ == "":  # RosMessage: any message of the suite
            return msgtype_of(obj) in MESSAGE_TYPES
        return msgtype_of(obj) == cls.__msgtype__

    def __getattr__(cls, name: str) -> Any:  # constants, e.g. DiagnosticStatus.WARN
        if name.startswith("__") or cls.__msgtype__ == "":
            raise AttributeError(name)
        return getattr(_store_class(cls.__msgtype__), name)


class RosMessage(metaclass=_MessageMeta):
    """Base of the message names; ``isinstance(x, RosMessage)`` for any type of the suite."""

    __msgtype__: ClassVar[str] = ""

    if TYPE_CHECKING:  # the instances are typestore dataclasses; their fields are dynamic

        def __init__(self, **values: object) -> None: ...

        def __getattr__(self, name: str) -> Any: ...

        def __setattr__(self, name: str, value: Any) -> None: ...


class Time(RosMessage):
    """builtin_interfaces/msg/Time: ``sec`` [s] and ``nanosec`` [ns] since an epoch."""

    __msgtype__ = "builtin_interfaces/msg/Time"


class Header(RosMessage):
    """std_msgs/msg/Header: ``stamp`` (Time) and ``frame_id``."""

    __msgtype__ = "std_msgs/msg/Header"


class JointState(RosMessage):
    """sensor_msgs/msg/JointState: ``position`` [rad], ``velocity`` [rad/s], ``effort`` [N·m]."""

    __msgtype__ = "sensor_msgs/msg/JointState"


class MultiArrayDimension(RosMessage):
    """std_msgs/msg/MultiArrayDimension: ``label``, ``size``, ``stride``."""

    __msgtype__ = "std_msgs/msg/MultiArrayDimension"


class MultiArrayLayout(RosMessage):
    """std_msgs/msg/MultiArrayLayout: ``dim`` and ``data_offset``."""

    __msgtype__ = "std_msgs/msg/MultiArrayLayout"


class Float64(RosMessage):
    """std_msgs/msg/Float64: one number (``data``), e.g. an announced speed bound."""

    __msgtype__ = "std_msgs/msg/Float64"


class Float64MultiArray(RosMessage):
    """std_msgs/msg/Float64MultiArray: ros2_control's forward-command message (``data``)."""

    __msgtype__ = "std_msgs/msg/Float64MultiArray"


class String(RosMessage):
    """std_msgs/msg/String: ``data``."""

    __msgtype__ = "std_msgs/msg/String"


class Clock(RosMessage):
    """rosgraph_msgs/msg/Clock: the simulated time published on ``/clock`` (``clock``)."""

    __msgtype__ = "rosgraph_msgs/msg/Clock"


class KeyValue(RosMessage):
    """diagnostic_msgs/msg/KeyValue: ``key`` and ``value``."""

    __msgtype__ = "diagnostic_msgs/msg/KeyValue"


class DiagnosticStatus(RosMessage):
    """diagnostic_msgs/msg/DiagnosticStatus; ``level`` is OK 0, WARN 1, ERROR 2 or STALE 3."""

    __msgtype__ = "diagnostic_msgs/msg/DiagnosticStatus"
    OK: ClassVar[int]
    WARN: ClassVar[int]
    ERROR: ClassVar[int]
    STALE: ClassVar[int]


class DiagnosticArray(RosMessage):
    """diagnostic_msgs/msg/DiagnosticArray: ``header`` and ``status`` (DiagnosticStatus list)."""

    __msgtype__ = "diagnostic_msgs/msg/DiagnosticArray"


#: The message names of the suite by ROS type name ("sensor_msgs/msg/JointState").
MESSAGE_TYPES: dict[str, type[RosMessage]] = {
    cls.__msgtype__: cls
    for cls in (
        Time,
        Header,
        JointState,
        MultiArrayDimension,
        MultiArrayLayout,
        Float64,
        Float64MultiArray,
        String,
        Clock,
        KeyValue,
        DiagnosticStatus,
        DiagnosticArray,
    )
}


# ------------------------------------------------------------------ codec, definitions, hashes


def msgtype_of(msg: object) -> str:
    """ROS type name of a message instance or class: a typestore one, ours or rclpy's."""
    cls = msg if isinstance(msg, type) else type(msg)
    own = getattr(cls, "__msgtype__", "")
    if isinstance(own, str) and own:
        return own
    package = cls.__module__.split(".")[0]  # rclpy: "sensor_msgs.msg._joint_state"
    return f"{package}/msg/{cls.__name__}"


def serialize(msg: object, msgtype: str | None = None) -> bytes:
    """Little-endian CDR bytes (4-byte encapsulation header first) of `msg`.

    `msg` is a typestore instance (what the message names build) or any object with the same
    fields, e.g. one whose sequences were set to lists later; `msgtype` defaults to its type.
    """
    msgtype = msgtype or msgtype_of(msg)
    store = typestore()
    _store_class(msgtype)
    try:
        return bytes(store.serialize_cdr(msg, msgtype))
    except (AttributeError, TypeError, ValueError, struct.error):
        pass  # lists where arrays belong, an rclpy message, ...: normalize and retry
    value = _as_store_message(msg, msgtype, msgtype, rebuild=True)
    try:
        return bytes(store.serialize_cdr(value, msgtype))
    except (AttributeError, TypeError, ValueError, struct.error, OverflowError) as err:
        raise MessageError(f"cannot encode a {msgtype}: {type(err).__name__}: {err}") from None


def deserialize(data: bytes | bytearray | memoryview, msgtype: str) -> Any:
    """Decode CDR bytes of ROS type `msgtype` into the typestore's dataclass."""
    from rosbags.serde import SerdeError

    _store_class(msgtype)
    try:
        return typestore().deserialize_cdr(bytes(data), msgtype)
    except (SerdeError, struct.error, IndexError, ValueError, UnicodeDecodeError) as err:
        raise MessageError(
            f"{len(data)} bytes are not a CDR {msgtype} ({type(err).__name__}: {err})"
        ) from None


def message_definition(msgtype: str) -> str:
    """The rosbag2 ``ros2msg`` schema text: the type's .msg, then each dependency's.

    Each dependency follows a line of 80 ``=`` and a line ``MSG: pkg/Type``, as rosbag2 writes.
    """
    _store_class(msgtype)
    return typestore().generate_msgdef(msgtype, ros_version=2)[0]


def type_hash(msgtype: str) -> str:
    """The ROS 2 type description hash (``RIHS01_<sha256 hex>``) of `msgtype`."""
    _store_class(msgtype)
    return typestore().hash_rihs01(msgtype)


def leading_stamp_ns(data: bytes | bytearray | memoryview) -> int:
    """The builtin_interfaces/Time [ns] that starts a CDR message's payload.

    That is the header stamp of a message with a ``header`` first (JointState,
    DiagnosticArray, ...) or the time of a Clock. Raises :class:`MessageError` for bytes too
    short or without a CDR encapsulation header.
    """
    layout: Callable[[Any, int], tuple[int, int]] | None = None
    if len(data) >= 12:
        form = _STAMP.get(bytes(data[:2]))
        layout = form.unpack_from if form is not None else None
    if layout is None:
        head = bytes(data[:4]).hex()
        raise MessageError(
            f"not a CDR message with a leading time stamp ({len(data)} bytes, starting {head!r})"
        )
    sec, nanosec = layout(data, 4)
    return sec * 1_000_000_000 + nanosec
