"""Every message class serializes byte-for-byte like rosbags' ROS 2 Jazzy CDR serializer.

Checked for both encoders the suite uses: nehmo_core's own CDR codec (logs, recorder) and the
cyclonedds IdlStruct mirrors of the embedded runtime (the bytes on the wire).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.msg import get_types_from_msg

from nehmo_core.logs import messages as M
from nehmo_ros import msgs

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)


def _header(sec: int, nanosec: int, frame: str) -> M.Header:
    return M.Header(stamp=M.Time(sec=sec, nanosec=nanosec), frame_id=frame)


def samples() -> list[M.RosMessage]:
    """Instances covering empty and odd-length strings, empty sequences and alignment cases."""
    status = M.DiagnosticStatus(
        level=M.DiagnosticStatus.ERROR,
        name="ur5_0|ur5_1",
        message="collision",
        hardware_id="sim",
        values=[M.KeyValue("distance", "-0.013"), M.KeyValue("links", "wrist_3|forearm")],
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
        M.MultiArrayLayout(dim=[M.MultiArrayDimension("a", 1, 2)], data_offset=1),
        M.Float64MultiArray(),
        M.Float64MultiArray(
            layout=M.MultiArrayLayout(
                dim=[M.MultiArrayDimension("q", 6, 6), M.MultiArrayDimension("", 1, 1)],
                data_offset=3,
            ),
            data=[0.5, -0.5, 0.25, 0.0, 1.0, -1.0],
        ),
        M.String(data=""),
        M.String(data='{"seed": 1, "arms": ["ur5_0"]}'),
        M.Clock(clock=M.Time(sec=100, nanosec=40_000_000)),
        M.KeyValue(key="plan_time_ms", value="3.2"),
        status,
        M.DiagnosticStatus(),
        M.DiagnosticArray(header=_header(5, 6, "world"), status=[status, M.DiagnosticStatus()]),
        M.DiagnosticArray(),
    ]


def to_rosbags(msg: Any, msgtype: str) -> Any:
    """The rosbags instance of one of our messages, built field by field."""
    cls = TYPESTORE.types[msgtype]
    values: dict[str, Any] = {}
    for spec in M.MESSAGE_TYPES[msgtype]._FIELDS:
        value = getattr(msg, spec.name)
        if spec.kind in M.MESSAGE_TYPES:
            value = (
                [to_rosbags(v, spec.kind) for v in value]
                if spec.sequence
                else to_rosbags(value, spec.kind)
            )
        elif spec.kind == "byte":
            value = value[0]
        elif spec.sequence and spec.kind == "float64":
            value = np.asarray(value, dtype=np.float64)
        values[spec.name] = value
    return cls(**values)


@pytest.mark.parametrize("msg", samples(), ids=lambda m: type(m).__name__)
def test_cdr_matches_rosbags_jazzy(msg: M.RosMessage) -> None:
    msgtype = msg._TYPE
    expected = bytes(TYPESTORE.serialize_cdr(to_rosbags(msg, msgtype), msgtype))
    assert M.serialize(msg) == expected
    assert M.deserialize(expected, msgtype) == msg


@pytest.mark.parametrize("msg", samples(), ids=lambda m: type(m).__name__)
def test_wire_idl_matches_rosbags_jazzy(msg: M.RosMessage) -> None:
    from nehmo_ros.embedded.idl import IDL_TYPES, dds_type_name, from_idl, to_idl

    msgtype = msg._TYPE
    expected = bytes(TYPESTORE.serialize_cdr(to_rosbags(msg, msgtype), msgtype))
    sample = to_idl(msg, msgtype)
    assert sample.serialize() == expected
    assert from_idl(IDL_TYPES[msgtype].deserialize(expected), msgtype) == msg
    assert IDL_TYPES[msgtype].__idl_typename__ == dds_type_name(msgtype)


def test_every_type_is_covered_by_samples() -> None:
    assert {m._TYPE for m in samples()} == set(M.MESSAGE_TYPES)


@pytest.mark.parametrize("msgtype", sorted(M.MESSAGE_TYPES))
def test_schema_text_parses_to_jazzy_definitions(msgtype: str) -> None:
    parsed = get_types_from_msg(M.message_definition(msgtype), msgtype)
    assert set(parsed) == {msgtype, *M.dependencies(msgtype)}
    for name, definition in parsed.items():
        assert definition == TYPESTORE.fielddefs[name], name


def test_msgs_module_mirrors_rclpy_usage() -> None:
    msg = msgs.JointState()
    msg.header.stamp.sec = 3
    msg.name = ["a"]
    msg.position = np.array([1.0])  # numpy arrays are accepted by the encoder
    assert msgs.deserialize(msgs.serialize(msg), "sensor_msgs/msg/JointState").position == [1.0]
    assert msgs.DiagnosticStatus.WARN == b"\x01"
    assert msgs.JointState.get_fields_and_field_types()["position"] == "float64[]"


def test_truncated_cdr_raises_one_clear_error() -> None:
    from nehmo_core.logs.cdr import CdrError

    data = M.serialize(samples()[4])
    with pytest.raises(CdrError, match="truncated"):
        M.deserialize(data[:-5], "sensor_msgs/msg/JointState")
