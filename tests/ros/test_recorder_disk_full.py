"""A full disk under the recorder: it reports, keeps recording, and what it wrote before the
disk filled stays readable and recoverable.

The disk is simulated below the log writer's buffered file: the device accepts a byte budget,
then the write that crosses it is cut short and the next fails with ENOSPC, as on a file system
that has run out of space. Messages are ~24 kB, so a chunk goes past the file's buffer and a
write fails in the middle of a chunk: the file then holds a torn chunk.
"""

from __future__ import annotations

import errno
import io
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest
import rclpy.node
from _ros_testutil import in_process
from sensor_msgs.msg import JointState as RosJointState

import nehmo_core.logs.writer as writer_module
from nehmo_core.logs import joint_states_topic, read_log
from nehmo_core.logs.recover import recover
from nehmo_ros.recorder import RecorderNode

TOPIC = joint_states_topic("ur5_0")
WIDTH = 3000  # joint positions per message: ~24 kB, a chunk of five is past the 8 kB buffer


class Device(io.RawIOBase):
    """A file on a device with ``free`` bytes left (None: unlimited)."""

    def __init__(self, path: Path) -> None:
        self.file = io.FileIO(path, "wb")
        self.free: int | None = None

    def writable(self) -> bool:
        return True

    def seekable(self) -> bool:
        return True

    def seek(self, offset: int, whence: int = 0) -> int:
        return self.file.seek(offset, whence)

    def tell(self) -> int:
        return self.file.tell()

    def write(self, data: Any) -> int:
        data = bytes(data)
        if self.free is not None:
            if self.free == 0:
                raise OSError(errno.ENOSPC, "No space left on device")
            data = data[: self.free]
            self.free -= len(data)
        return self.file.write(data)

    def close(self) -> None:
        self.file.close()
        super().close()


@dataclass
class Rig:
    recorder: RecorderNode
    device: Device
    path: Path
    burst: Callable[[int, int], None]
    spin: Callable[[float, Callable[[], bool]], bool]


@pytest.fixture
def rig(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Rig]:
    devices: list[Device] = []

    def open_on_device(path: Any, mode: str = "r", *args: Any, **kwargs: Any) -> Any:
        assert mode == "wb", mode
        devices.append(Device(Path(path)))
        return io.BufferedWriter(devices[-1])

    monkeypatch.setattr(writer_module, "open", open_on_device, raising=False)
    path = tmp_path / "run"
    params = ["cell:=dual_ur5", f"output:={path}", "flush_every:=5", "flush_interval:=0.2"]
    with in_process("recorder", params) as nodes:
        recorder = RecorderNode()
        talker = rclpy.node.Node("talker")
        pub = talker.create_publisher(RosJointState, TOPIC, 100)
        nodes.add(recorder)
        nodes.add(talker)

        def burst(first: int, count: int) -> None:
            """Messages ``first`` … at 100 Hz; returns once the recorder has taken every message
            sent so far (the bursts number them from 0 without gaps), written or lost."""
            for k in range(first, first + count):
                pub.publish(RosJointState(name=["a"], position=[float(k)] + [0.0] * WIDTH))
                nodes.spin(0.01)

            def taken() -> int:
                return recorder.count + recorder.lost

            assert nodes.spin(30.0, lambda: taken() == first + count), (taken(), first + count)

        assert nodes.spin(30.0, lambda: pub.get_subscription_count() >= 1)
        yield Rig(recorder, devices[0], path, burst, nodes.spin)


def _firsts(path: Path) -> list[float]:
    """The first position of every logged joint state (every message must deserialize)."""
    return [r.message.position[0] for r in read_log(path) if r.topic == TOPIC]  # type: ignore[union-attr]


def test_a_full_disk_is_reported_and_the_log_before_it_recovers(
    rig: Rig, tmp_path: Path, capfd: pytest.CaptureFixture[str]
) -> None:
    rig.burst(0, 10)
    assert rig.spin(30.0, lambda: rig.recorder.writer.pending == 0)  # flushed
    assert (rig.recorder.count, rig.recorder.lost, rig.recorder.writer.pending) == (10, 0, 0)
    rig.device.free = 100  # the disk fills up inside the next chunk, and stays full
    rig.burst(10, 20)  # every callback returns: the node keeps spinning
    assert rig.recorder.lost > 0
    rig.recorder.on_stop()  # the summary cannot be written either
    out = capfd.readouterr()
    assert "No space left on device" in out.err
    assert f"repair it with: python -m nehmo_core.logs.recover {rig.path}" in out.err
    fixed = tmp_path / "fixed"
    report = recover(rig.path, fixed)
    assert not report.complete and report.stopped_by
    assert _firsts(fixed) == [float(k) for k in range(10)]


def test_a_chunk_torn_by_a_full_disk_ends_a_recovery_instead_of_passing_garbage_on(
    rig: Rig, tmp_path: Path
) -> None:
    rig.burst(0, 10)
    assert rig.spin(30.0, lambda: rig.recorder.writer.pending == 0)  # flushed
    assert rig.recorder.lost == 0
    rig.device.free = 100
    rig.burst(10, 20)
    lost = rig.recorder.lost
    assert lost > 0
    rig.device.free = None  # space again: recording goes on
    rig.burst(30, 10)
    assert rig.recorder.lost == lost
    rig.recorder.on_stop()  # a finished file: its index skips the torn chunk
    assert _firsts(rig.path) == [float(k) for k in (*range(10), *range(30, 40))]
    # A sequential recovery cannot step over the torn chunk (its length field runs into the
    # next records): its checksum ends the recovery there, and every message kept is whole.
    fixed = tmp_path / "fixed"
    report = recover(rig.path, fixed)
    assert "crc" in report.stopped_by.lower()
    assert _firsts(fixed) == [float(k) for k in range(10)]
