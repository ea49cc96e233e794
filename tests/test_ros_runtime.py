"""The embedded runtime: multi-process pub/sub over loopback, interop with plain cyclonedds,
timers, simulated time and the DDS configuration."""

from __future__ import annotations

import itertools
import json
import signal
import statistics
import time
from collections.abc import Iterator

import pytest
from _ros_testutil import DOMAIN_ID, finish, start

from nehmo_ros import msgs
from nehmo_ros.embedded import (
    MultiThreadedExecutor,
    Node,
    ReentrantCallbackGroup,
    SingleThreadedExecutor,
    init,
    try_shutdown,
)
from nehmo_ros.embedded.config import LOOPBACK_XML, DdsConfigError, dds_config


@pytest.fixture
def context() -> Iterator[None]:
    init(args=[], domain_id=DOMAIN_ID)
    yield
    try_shutdown()


def _json_lines(text: str) -> list[dict[str, object]]:
    return [json.loads(line) for line in text.splitlines() if line.startswith("{")]


def test_joint_state_between_two_processes() -> None:
    sub = start("sub", "20", "5")
    time.sleep(0.3)
    pub = start("pub", "20")
    try:
        code, out, err = finish(sub, timeout=25)
    finally:
        pub.kill()
        finish(pub, timeout=5)
    received = _json_lines(out)
    assert code == 0, err
    assert len(received) >= 5, err
    assert received[0]["name"] == [f"joint_{i}" for i in range(6)]
    assert len(received[-1]["position"]) == 6  # type: ignore[arg-type]


def test_plain_cyclonedds_participant_receives_joint_state() -> None:
    reader = start("plain_sub", "20")
    time.sleep(0.3)
    pub = start("pub", "20")
    try:
        code, out, err = finish(reader, timeout=25)
    finally:
        pub.kill()
        finish(pub, timeout=5)
    received = _json_lines(out)
    assert code == 0, err
    assert received, f"the plain participant received nothing: {err}"
    assert received[0]["frame_id"] == "base"
    assert received[0]["type"] == "sensor_msgs::msg::dds_::JointState_"
    assert received[0]["name"] == [f"joint_{i}" for i in range(6)]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_signal_stops_spin_cleanly(signum: int) -> None:
    proc = start("spin")
    assert proc.stdout is not None
    assert proc.stdout.readline().strip() == "spinning"
    time.sleep(0.2)
    proc.send_signal(signum)
    code, out, err = finish(proc, timeout=10)
    assert code == 0, err
    assert "clean exit" in out


def test_timer_rate_single_threaded(context: None) -> None:
    node = Node("timer_node")
    stamps: list[float] = []
    node.create_timer(0.02, lambda: stamps.append(time.monotonic()))
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        executor.spin_once(0.1)
    # The machine is shared with training: a stalled process skips periods (as rcl timers do),
    # so the count has slack below; the median period is what must be right.
    assert 35 <= len(stamps) <= 51
    periods = [b - a for a, b in itertools.pairwise(stamps)]
    assert abs(statistics.median(periods) - 0.02) < 0.003
    node.destroy_node()


def test_timers_and_messages_multi_threaded(context: None) -> None:
    node = Node("multi_node")
    group = ReentrantCallbackGroup()
    fast: list[float] = []
    got: list[msgs.String] = []
    pub = node.create_publisher(msgs.String, "chatter", 10)
    node.create_subscription(msgs.String, "chatter", got.append, 10, callback_group=group)

    def slow_tick() -> None:
        pub.publish(msgs.String(data=f"{len(fast)}"))
        time.sleep(0.03)  # would delay the fast timer if the two could not overlap

    node.create_timer(0.05, lambda: fast.append(time.monotonic()), callback_group=group)
    node.create_timer(0.1, slow_tick, callback_group=group)
    executor = MultiThreadedExecutor(num_threads=3)
    executor.add_node(node)
    end = time.monotonic() + 1.0
    while time.monotonic() < end:
        executor.spin_once(0.05)
    executor.shutdown()
    assert 14 <= len(fast) <= 21
    assert len(got) >= 7 and all(isinstance(m, msgs.String) for m in got)
    node.destroy_node()


def test_use_sim_time_follows_clock(context: None) -> None:
    sim = Node("sim_node", cli_args=["-p", "use_sim_time:=true"])
    clock_source = Node("clock_source")
    pub = clock_source.create_publisher(msgs.Clock, "/clock", 10)
    ticks: list[int] = []
    sim.create_timer(0.1, lambda: ticks.append(sim.get_clock().now().nanoseconds))
    executor = SingleThreadedExecutor()
    executor.add_node(sim)
    executor.add_node(clock_source)
    assert sim.get_clock().now().nanoseconds == 0  # no /clock yet

    def publish_and_wait(t_ns: int) -> None:
        end = time.monotonic() + 5.0
        while sim.get_clock().now().nanoseconds != t_ns and time.monotonic() < end:
            sec, nanosec = divmod(t_ns, 1_000_000_000)
            pub.publish(msgs.Clock(clock=msgs.Time(sec=sec, nanosec=nanosec)))
            executor.spin_once(0.02)
        assert sim.get_clock().now().nanoseconds == t_ns

    publish_and_wait(10_000_000_000)
    ticks.clear()
    for step in range(1, 21):  # 10.05 s ... 11.0 s of simulated time, as fast as possible
        publish_and_wait(10_000_000_000 + step * 50_000_000)
    executor.spin_once(0.01)
    assert 9 <= len(ticks) <= 11
    assert clock_source.get_clock().now().nanoseconds > 1_600_000_000 * 10**9  # wall time
    sim.destroy_node()
    clock_source.destroy_node()


def test_dds_config_defaults_to_loopback() -> None:
    config = dds_config(environ={})
    assert config.scope == "loopback" and config.xml == LOOPBACK_XML and config.domain_id == 0
    assert "127.0.0.1" in LOOPBACK_XML and "<AllowMulticast>false" in LOOPBACK_XML
    assert dds_config(environ={"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}).scope == "loopback"
    wide = dds_config(environ={"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_DOMAIN_ID": "7"})
    assert wide.xml is None and wide.domain_id == 7
    own = dds_config(environ={"NEHMO_DDS_CONFIG": "<CycloneDDS/>"})
    assert own.xml == "<CycloneDDS/>" and own.scope == "NEHMO_DDS_CONFIG"


@pytest.mark.parametrize(
    ("env", "message"),
    [
        ({"ROS_DOMAIN_ID": "300"}, "ROS_DOMAIN_ID"),
        ({"ROS_DOMAIN_ID": "x"}, "ROS_DOMAIN_ID"),
        ({"ROS_AUTOMATIC_DISCOVERY_RANGE": "WORLD"}, "ROS_AUTOMATIC_DISCOVERY_RANGE"),
        ({"NEHMO_DDS_CONFIG": "/nonexistent.xml"}, "NEHMO_DDS_CONFIG"),
    ],
)
def test_dds_config_errors(env: dict[str, str], message: str) -> None:
    with pytest.raises(DdsConfigError, match=message):
        dds_config(environ=env)
