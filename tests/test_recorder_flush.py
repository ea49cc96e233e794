"""The recorder flushes what it holds once traffic stops: a SIGKILL then loses nothing."""

from __future__ import annotations

import time
from collections.abc import Callable
from pathlib import Path

from _ros_testutil import DOMAIN_ID

from nehmo_core.logs import JointState, joint_states_topic, read_log
from nehmo_core.logs.recover import recover
from nehmo_ros import ros
from nehmo_ros.recorder import RecorderNode

NAMES = ["a", "b"]


def _spin(executor: ros.SingleThreadedExecutor, until: Callable[[], bool], seconds: float) -> None:
    end = time.monotonic() + seconds
    while time.monotonic() < end and not until():
        executor.spin_once(timeout_sec=0.02)


def test_messages_are_flushed_after_traffic_stops(tmp_path: Path) -> None:
    """A burst of 5 messages (far below ``flush_every``), then silence; simulated time stands
    still (no /clock), so only a monotonic timer can flush them."""
    path = tmp_path / "run.mcap"
    params = ["cell:=dual_ur5", f"output:={path}", "flush_interval:=0.2", "use_sim_time:=true"]
    args = ["recorder", "--ros-args"] + [a for p in params for a in ("-p", p)]
    ros.init(args=args, domain_id=DOMAIN_ID)
    try:
        recorder = RecorderNode()
        talker = ros.Node("talker")
        pub = talker.create_publisher(ros.msg.JointState, joint_states_topic("ur5_0"), 10)
        executor = ros.SingleThreadedExecutor()
        executor.add_node(recorder.node)
        executor.add_node(talker)
        _spin(executor, lambda: pub.get_subscription_count() >= 1, 10.0)
        _spin(executor, lambda: False, 0.3)  # past the first flush interval
        for k in range(5):
            pub.publish(JointState(name=NAMES, position=[0.1 * k, 0.0]))
        _spin(executor, lambda: recorder.count >= 5, 5.0)
        assert recorder.count == 5
        _spin(executor, lambda: False, 0.5)  # silence: 2.5 flush intervals
        fixed = tmp_path / "fixed.mcap"
        recover(path, fixed)  # the file as a SIGKILL now would leave it
        states = [r for r in read_log(fixed) if r.topic == joint_states_topic("ur5_0")]
        assert [r.message.position[0] for r in states] == [0.1 * k for k in range(5)]  # type: ignore[union-attr]
        assert recorder.writer.pending == 0
        recorder.on_stop()
        executor.remove_node(recorder.node)
        executor.remove_node(talker)
        recorder.node.destroy_node()
        talker.destroy_node()
    finally:
        ros.try_shutdown()
