"""A quicker CDR decoder for sensor_msgs/JointState, the suite's most frequent message.

Every planner takes every arm's joint states (100 Hz per arm), so their decoding is a large part
of an idle planner's work. :func:`decode` is :func:`nehmo_core.logs.messages.deserialize` with a
specialised path for JointState: the same message for every well-formed one; anything else
(other types, truncated or malformed data) goes to the generic decoder, which returns or raises
as usual.
"""

from __future__ import annotations

import struct

from nehmo_core.logs.cdr import CDR_LE_HEADER
from nehmo_core.logs.messages import Header, JointState, RosMessage, Time, deserialize

_U32 = struct.Struct("<I")
_STAMP = struct.Struct("<iI")
_ORIGIN = len(CDR_LE_HEADER)  # alignment counts from the end of the header


def _string(data: bytes, pos: int) -> tuple[str, int]:
    pos += -(pos - _ORIGIN) % 4
    (n,) = _U32.unpack_from(data, pos)
    pos += 4
    if n == 0:  # "" written as length 0 (tolerated, as by the generic decoder)
        return "", pos
    end = pos + n
    if end > len(data) or data[end - 1] != 0:
        raise ValueError("truncated or not NUL-terminated")
    return data[pos : end - 1].decode("utf-8"), end


def _doubles(data: bytes, pos: int) -> tuple[list[float], int]:
    pos += -(pos - _ORIGIN) % 4
    (n,) = _U32.unpack_from(data, pos)
    pos += 4
    if n == 0:
        return [], pos
    pos += -(pos - _ORIGIN) % 8
    return list(struct.unpack_from(f"<{n}d", data, pos)), pos + 8 * n


def _joint_state(data: bytes) -> JointState:
    if data[:2] != CDR_LE_HEADER[:2]:
        raise ValueError("not little-endian plain CDR")
    sec, nanosec = _STAMP.unpack_from(data, _ORIGIN)
    frame_id, pos = _string(data, _ORIGIN + _STAMP.size)
    pos += -(pos - _ORIGIN) % 4
    (count,) = _U32.unpack_from(data, pos)
    pos += 4
    names = []
    for _ in range(count):
        name, pos = _string(data, pos)
        names.append(name)
    position, pos = _doubles(data, pos)
    velocity, pos = _doubles(data, pos)
    effort, pos = _doubles(data, pos)
    return JointState(
        header=Header(stamp=Time(sec=sec, nanosec=nanosec), frame_id=frame_id),
        name=names,
        position=position,
        velocity=velocity,
        effort=effort,
    )


def decode(data: bytes, msgtype: str) -> RosMessage:
    """The message of ROS type ``msgtype`` in the CDR bytes ``data`` (as ``deserialize``)."""
    if msgtype == JointState._TYPE:
        try:
            return _joint_state(data)
        except Exception:  # let the generic decoder decide (and report) what is wrong
            pass
    return deserialize(data, msgtype)
