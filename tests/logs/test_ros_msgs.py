"""The message names of ``nehmo_core.logs.messages`` over the ``rosbags`` ROS 2 Jazzy typestore.

Every type round-trips through ``serialize``/``deserialize`` and gives the bytes the typestore
gives for the same message built by hand; defaults, coercion of lists to numpy arrays, the
leading-stamp reader and the errors on bad input are checked too.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.logs import messages as M

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
T = TYPESTORE.types


def _header(sec: int, nanosec: int, frame: str) -> Any:
    return M.Header(stamp=M.Time(sec=sec, nanosec=nanosec), frame_id=frame)


def samples() -> list[Any]:
    """Instances covering empty and odd-length strings, empty sequences and alignment cases."""
    status = M.DiagnosticStatus(
        level=M.DiagnosticStatus.ERROR,
        name="ur5_0|ur5_1",
        message="collision",
        hardware_id="sim",
        values=[
            M.KeyValue(key="distance", value="-0.013"),
            M.KeyValue(key="links", value="wrist_3|forearm"),
        ],
    )
    return [
        M.Time(sec=-3, nanosec=999_999_999),
        _header(1, 2, ""),
        _header(2**31 - 1, 7, "base_link_ü"),
        M.JointState(),
        M.JointState(
            header=_header(12, 500, "a"),
            name=["shoulder_pan_joint", "x", "", "elbow"],
            position=[0.1, -2.5, 3.0, 1e-12],
            velocity=[],
            effort=[7.0],
        ),
        M.JointState(header=_header(0, 0, "abc"), name=["j"], position=[], velocity=[1.5]),
        M.MultiArrayDimension(label="joints", size=6, stride=6),
        M.MultiArrayLayout(dim=[M.MultiArrayDimension(label="a", size=1, stride=2)], data_offset=1),
        M.Float64(),
        M.Float64(data=0.2),
        M.Float64MultiArray(),
        M.Float64MultiArray(
            layout=M.MultiArrayLayout(
                dim=[
                    M.MultiArrayDimension(label="q", size=6, stride=6),
                    M.MultiArrayDimension(label="", size=1, stride=1),
                ],
                data_offset=3,
            ),
            data=[0.5, -0.5, 0.25, 0.0, 1.0, -1.0],
        ),
        M.String(data=""),
        M.String(data='{"seed": 1, "arms": ["ur5_0"]}'),
        M.Clock(clock=M.Time(sec=100, nanosec=40_000_000)),
        M.KeyValue(key="k", value="v"),
        M.DiagnosticStatus(),
        status,
        M.DiagnosticArray(header=_header(5, 6, "world"), status=[status, M.DiagnosticStatus()]),
    ]


def by_hand(msg: Any) -> Any:
    """The same message built directly from the typestore's classes (positional fields)."""
    cls = T[msg.__msgtype__]
    values = []
    for f in dataclasses.fields(cls):
        value = getattr(msg, f.name)
        if isinstance(value, list):
            value = [by_hand(v) if hasattr(v, "__msgtype__") else v for v in value]
        elif isinstance(value, np.ndarray):
            value = np.array(value.tolist(), dtype=value.dtype)
        elif hasattr(value, "__msgtype__"):
            value = by_hand(value)
        values.append(value)
    return cls(*values)


def plain(msg: Any) -> Any:
    """Nested dicts and lists, for comparisons (dataclass == fails on numpy fields)."""
    if hasattr(msg, "__msgtype__"):
        return {f.name: plain(getattr(msg, f.name)) for f in dataclasses.fields(msg)}
    if isinstance(msg, list | np.ndarray):
        return [plain(v) for v in msg]
    return msg.item() if isinstance(msg, np.generic) else msg


def _id(msg: Any) -> str:
    return str(msg.__msgtype__.rsplit("/", 1)[-1])


@pytest.mark.parametrize("msg", samples(), ids=_id)
def test_round_trip_and_bytes_match_the_typestore(msg: Any) -> None:
    msgtype = M.msgtype_of(msg)
    assert msgtype in M.MESSAGE_TYPES and isinstance(msg, M.MESSAGE_TYPES[msgtype])
    assert type(msg) is T[msgtype]  # the typestore's own dataclass
    data = M.serialize(msg)
    assert data[:4] == b"\x00\x01\x00\x00"  # little-endian CDR encapsulation
    assert data == bytes(TYPESTORE.serialize_cdr(by_hand(msg), msgtype))
    back = M.deserialize(data, msgtype)
    assert type(back) is T[msgtype]
    assert plain(back) == plain(msg)
    assert M.serialize(back) == data


def test_every_suite_type_is_covered() -> None:
    assert {M.msgtype_of(m) for m in samples()} == set(M.MESSAGE_TYPES)
    assert set(M.MESSAGE_TYPES) <= set(T)


def test_defaults_are_zero_values_and_lists_become_arrays() -> None:
    js = M.JointState(position=[1, 2])
    assert js.header.stamp.sec == 0 and js.header.frame_id == "" and js.name == []
    assert isinstance(js.position, np.ndarray) and js.position.dtype == np.float64
    np.testing.assert_array_equal(js.position, [1.0, 2.0])
    assert js.velocity.shape == (0,) and js.effort.dtype == np.float64
    status = M.DiagnosticStatus(level=b"\x01")  # rclpy's 1-byte form of a byte field
    assert status.level == M.DiagnosticStatus.WARN == 1
    assert (M.DiagnosticStatus.OK, M.DiagnosticStatus.ERROR, M.DiagnosticStatus.STALE) == (0, 2, 3)
    nested = M.DiagnosticArray(status=[{"name": "a", "values": [{"key": "k", "value": "v"}]}])
    assert nested.status[0].values[0].value == "v"
    arr = np.arange(6, dtype=np.float64)[::2]  # not contiguous: copied
    assert M.Float64MultiArray(data=arr).data.tolist() == [0.0, 2.0, 4.0]


def test_fields_set_to_lists_later_still_serialize() -> None:
    js = M.JointState(name=["a"])
    js.position = [0.5]  # a caller may assign a list after construction
    back = M.deserialize(M.serialize(js), "sensor_msgs/msg/JointState")
    assert back.position.tolist() == [0.5]


def test_isinstance_compares_ros_types() -> None:
    js, clock = M.JointState(), M.Clock()
    assert isinstance(js, M.JointState) and not isinstance(js, M.Clock)
    assert isinstance(clock, M.RosMessage) and not isinstance("text", M.RosMessage)
    other_store = T["sensor_msgs/msg/JointState"]
    assert M.msgtype_of(other_store) == "sensor_msgs/msg/JointState"
    assert M.msgtype_of(M.JointState) == "sensor_msgs/msg/JointState"


def test_message_definition_is_rosbag2s_ros2msg_text() -> None:
    text = M.message_definition("sensor_msgs/msg/JointState")
    assert text == TYPESTORE.generate_msgdef("sensor_msgs/msg/JointState", ros_version=2)[0]
    assert text.startswith("std_msgs/Header header\nstring[] name\nfloat64[] position\n")
    assert "=" * 80 + "\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\n" in text
    assert "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec" in text
    status = M.message_definition("diagnostic_msgs/msg/DiagnosticStatus")
    assert "byte OK=0" in status and "MSG: diagnostic_msgs/KeyValue" in status
    digest = M.type_hash("sensor_msgs/msg/JointState")
    assert digest == TYPESTORE.hash_rihs01("sensor_msgs/msg/JointState")
    assert digest.startswith("RIHS01_") and len(digest) == 7 + 64


def test_leading_stamp_of_header_and_clock_messages() -> None:
    js = M.JointState(header=_header(12, 345, "a"), name=["j"], position=[1.0])
    assert M.leading_stamp_ns(M.serialize(js)) == 12_000_000_345
    clock = M.Clock(clock=M.Time(sec=-1, nanosec=5))
    assert M.leading_stamp_ns(M.serialize(clock)) == -999_999_995
    array = M.DiagnosticArray(header=_header(7, 0, "world"))
    assert M.leading_stamp_ns(memoryview(M.serialize(array))) == 7_000_000_000
    big_endian = b"\x00\x00\x00\x00" + (3).to_bytes(4, "big") + (9).to_bytes(4, "big")
    assert M.leading_stamp_ns(big_endian) == 3_000_000_009
    with pytest.raises(M.MessageError, match="leading time stamp"):
        M.leading_stamp_ns(b"\x00\x01\x00\x00\x01")
    with pytest.raises(M.MessageError, match="leading time stamp"):
        M.leading_stamp_ns(b"\x07\x07\x00\x00" + bytes(8))


def test_invalid_inputs_are_rejected_with_clear_errors() -> None:
    with pytest.raises(InvalidValueError, match=r"JointState field` must be one of .*'bogus'"):
        M.JointState(bogus=1)
    with pytest.raises(InvalidValueError, match=r"JointState\.position` must be a sequence"):
        M.JointState(position="abc")
    with pytest.raises(InvalidValueError, match=r"JointState\.position` must be a sequence"):
        M.JointState(position=[["a"]])
    with pytest.raises(InvalidValueError, match="exactly 1 byte"):
        M.DiagnosticStatus(level=b"\x01\x02")
    with pytest.raises(
        InvalidValueError, match=r"JointState\.header` must be a std_msgs/msg/Header"
    ):
        M.JointState(header=M.Clock())
    with pytest.raises(
        UnknownNameError, match=r"no_such_msgs/msg/Thing.*sensor_msgs/msg/JointState"
    ):
        M.serialize(M.Clock(), "no_such_msgs/msg/Thing")
    with pytest.raises(UnknownNameError, match="message type"):
        M.deserialize(b"\x00\x01\x00\x00", "no_such_msgs/msg/Thing")
    data = M.serialize(M.JointState(name=["a", "b"], position=[1.0, 2.0]))
    for cut in (0, 2, 10, len(data) - 3):
        with pytest.raises(M.MessageError, match="not a CDR sensor_msgs/msg/JointState"):
            M.deserialize(data[:cut], "sensor_msgs/msg/JointState")
    with pytest.raises(M.MessageError, match="cannot encode"):
        M.serialize(M.Time(sec=2**40), "builtin_interfaces/msg/Time")


def test_core_imports_no_ros_package() -> None:
    code = (
        "import sys, nehmo_core.logs, nehmo_core.logs.recover, nehmo_core.eval.episode_log\n"
        "nehmo_core.logs.serialize(nehmo_core.logs.JointState(position=[1.0]))\n"
        "ros = ('rclpy', 'rosidl', 'rmw', 'sensor_msgs', 'std_msgs', 'builtin_interfaces')\n"
        "print(sorted(m for m in sys.modules if m.split('.')[0].startswith(ros)))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
