"""The embedded runtime's CDR path: bytes published as they are, samples taken as bytes, the
JointState fast decoder, all equal to what the generic codec and the IdlStruct mirrors give."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest
from _ros_testutil import DOMAIN_ID

from nehmo_core.logs.cdr import CdrError
from nehmo_core.logs.messages import deserialize, serialize
from nehmo_ros import msgs
from nehmo_ros.embedded import Node, SingleThreadedExecutor, fastcdr, init, try_shutdown
from nehmo_ros.embedded.fastcdr import decode
from nehmo_ros.embedded.idl import IDL_TYPES


@pytest.fixture
def context() -> Iterator[None]:
    init(args=[], domain_id=DOMAIN_ID)
    yield
    try_shutdown()


def _statuses() -> list[msgs.DiagnosticStatus]:
    """Statuses whose CDR lengths need 0, 1, 2 and 3 padding bytes."""
    out = []
    for n in range(8):
        values = [msgs.KeyValue(key="k", value="v" * (n // 2))]
        out.append(msgs.DiagnosticStatus(level=b"\x01", name="x" * n, values=values))
    assert {len(serialize(m)) % 4 for m in out} == {0, 1, 2, 3}
    return out


def _spin_until(executor: SingleThreadedExecutor, done: Any, seconds: float = 5.0) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end and not done():
        executor.spin_once(0.05)


def test_published_bytes_arrive_unchanged(context: None) -> None:
    from cyclonedds.core import Policy, Qos
    from cyclonedds.sub import DataReader

    node = Node("wire_node")
    typed: list[Any] = []
    raw: list[bytes] = []
    pub = node.create_publisher(msgs.DiagnosticStatus, "wire_status", 50)
    node.create_subscription(msgs.DiagnosticStatus, "wire_status", typed.append, 50)
    node.create_subscription(msgs.DiagnosticStatus, "wire_status", raw.append, 50, raw=True)
    plain = DataReader(
        node.context.participant,
        node.context.topic("rt/wire_status", IDL_TYPES["diagnostic_msgs/msg/DiagnosticStatus"]),
        qos=Qos(Policy.Reliability.Reliable(0), Policy.History.KeepLast(50)),
    )
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    _spin_until(executor, lambda: pub.get_subscription_count() >= 3)
    sent = _statuses()
    for m in sent:
        pub.publish(serialize(m))  # as CDR bytes
        pub.publish(m)  # as a message
    _spin_until(executor, lambda: len(raw) >= 2 * len(sent) and len(typed) >= 2 * len(sent))
    twice = [m for m in sent for _ in range(2)]
    assert typed == twice
    assert raw == [serialize(m) for m in twice]  # the padding is not part of the message
    samples = plain.take(N=100)  # a plain cyclonedds reader decodes the same messages
    assert [s.serialize() for s in samples] == [serialize(m) for m in twice]
    node.destroy_node()


def test_bytes_that_are_not_cdr_are_refused(context: None) -> None:
    node = Node("wire_refuse")
    pub = node.create_publisher(msgs.String, "wire_refuse", 10)
    for bad in (b"", b"\x01\x00\x00\x00abcd", b"\x00\x01"):
        with pytest.raises(ValueError, match="not little-endian plain CDR"):
            pub.publish(bad)
    with pytest.raises(TypeError):
        pub.publish(msgs.Clock())
    node.destroy_node()


def _joint_states(rng: np.random.Generator, count: int) -> Iterator[msgs.JointState]:
    letters = list("abz_0é😀")
    for _ in range(count):

        def text(n: int) -> str:
            return "".join(rng.choice(letters) for _ in range(n))

        yield msgs.JointState(
            header=msgs.Header(
                stamp=msgs.Time(
                    sec=int(rng.integers(-(2**31), 2**31)), nanosec=int(rng.integers(0, 2**32))
                ),
                frame_id=text(int(rng.integers(0, 4))),
            ),
            name=[text(int(rng.integers(0, 9))) for _ in range(int(rng.integers(0, 8)))],
            position=rng.normal(size=int(rng.integers(0, 8))).tolist(),
            velocity=rng.normal(size=int(rng.integers(0, 8))).tolist(),
            effort=rng.normal(size=int(rng.integers(0, 3))).tolist(),
        )


def test_joint_state_decoder_equals_the_generic_one() -> None:
    rng = np.random.default_rng(1)
    for m in _joint_states(rng, 500):
        data = serialize(m)
        for variant in (data, data + bytes(-len(data) % 4)):  # with the wire's padding
            assert fastcdr._joint_state(variant) == m  # the fast path itself, not its fallback
            assert decode(variant, m._TYPE) == m
        for cut in rng.integers(0, len(data), 3):  # truncated: the generic error, unchanged
            with pytest.raises(CdrError) as generic:
                deserialize(data[:cut], m._TYPE)
            with pytest.raises(CdrError) as fast:
                decode(data[:cut], m._TYPE)
            assert str(fast.value) == str(generic.value)
            with pytest.raises(Exception):  # noqa: B017  (the fast path refuses it too)
                fastcdr._joint_state(data[:cut])


def test_other_types_go_to_the_generic_decoder() -> None:
    m = msgs.String(data="hello")
    assert decode(serialize(m), m._TYPE) == m
    bad = bytearray(serialize(msgs.JointState(name=["a"])))
    bad[bad.index(b"a\x00") + 1] = 0x41  # the name's NUL
    with pytest.raises(CdrError, match="NUL"):
        decode(bytes(bad), msgs.JointState._TYPE)


def test_a_sample_that_does_not_decode_costs_only_itself(
    context: None, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Samples are removed from the reader before decoding: a bad one is dropped and counted,
    the others of the same batch are still delivered."""
    import nehmo_ros.embedded.node as node_module

    node = Node("wire_drop")
    try:
        sub = node.create_subscription(msgs.JointState, "/drop/joint_states", lambda m: None, 10)
        good = msgs.JointState(name=["a"], position=[1.0])
        big_endian = bytes([0, 0, 0, 0]) + serialize(good)[4:]  # not little-endian XCDR1
        batch = [serialize(good), big_endian, serialize(good)]
        monkeypatch.setattr(node_module, "take_cdr", lambda reader, limit: batch)
        monkeypatch.setattr(sub, "condition", type("Triggered", (), {"triggered": True})())
        assert sub.take() == [good, good]
        assert sub.dropped == 1
    finally:
        node.destroy_node()
