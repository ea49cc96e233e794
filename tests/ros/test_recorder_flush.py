"""The recorder flushes what it holds once traffic stops: a SIGKILL then loses nothing."""

from __future__ import annotations

from pathlib import Path

import rclpy.node
from _ros_testutil import in_process
from sensor_msgs.msg import JointState as RosJointState

from nehmo_core.logs import joint_states_topic, read_log
from nehmo_core.logs.recover import recover
from nehmo_ros.recorder import RecorderNode

NAMES = ["a", "b"]


def test_messages_are_flushed_after_traffic_stops(tmp_path: Path) -> None:
    """A burst of 5 messages (far below ``flush_every``), then silence; simulated time stands
    still (no /clock), so only a monotonic timer can flush them."""
    path = tmp_path / "run"
    params = ["cell:=dual_ur5", f"output:={path}", "flush_interval:=0.2", "use_sim_time:=true"]
    with in_process("recorder", params) as nodes:
        recorder = RecorderNode()
        talker = rclpy.node.Node("talker")
        pub = talker.create_publisher(RosJointState, joint_states_topic("ur5_0"), 10)
        nodes.add(recorder)
        nodes.add(talker)
        assert nodes.spin(30.0, lambda: pub.get_subscription_count() >= 1)
        nodes.spin(0.3)  # past the first flush interval
        for k in range(5):
            pub.publish(RosJointState(name=NAMES, position=[0.1 * k, 0.0]))
        assert nodes.spin(30.0, lambda: recorder.count >= 5), recorder.count
        assert recorder.count == 5
        # silence: only the flush timer can empty the writer now
        assert nodes.spin(30.0, lambda: recorder.writer.pending == 0), recorder.writer.pending
        fixed = tmp_path / "fixed"
        recover(path, fixed)  # the file as a SIGKILL now would leave it
        states = [r for r in read_log(fixed) if r.topic == joint_states_topic("ur5_0")]
        assert [r.message.position[0] for r in states] == [0.1 * k for k in range(5)]  # type: ignore[union-attr]
        recorder.on_stop()
