"""``orchestrate replay`` republishes a bag through rclpy: a plain rclpy node receives every
message, in order, with its recorded content."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from _ros_testutil import child_env, finish, start

from nehmo_core.logs import Header, JointState, LogWriter, Time

TOPIC = "/ur5_0/joint_states"
NAMES = [f"joint_{i}" for i in range(6)]
COUNT = 40


def _bag(path: Path) -> Path:
    with LogWriter(path) as writer:
        for k in range(COUNT):
            t_ns = 1_000_000_000 + k * 20_000_000  # 50 Hz
            msg = JointState(
                header=Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)),
                name=NAMES,
                position=[0.01 * k] * 6,
            )
            writer.write(TOPIC, msg, log_time_ns=t_ns)
    return path


def _replay(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "nehmo_ros.orchestrate", "replay", *args],
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_replay_republishes_every_message_in_order(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "run")
    heard = tmp_path / "listener.jsonl"
    listener = start("listen", "60", str(heard), TOPIC)
    try:
        assert listener.stdout is not None
        assert "listening" in listener.stdout.readline()
        # discovery before the first message: generous, a busy machine can take seconds
        replay = _replay(str(bag), "--wait", "10")
    finally:
        listener.terminate()
        finish(listener, timeout=20)
    assert replay.returncode == 0, replay.stderr
    assert f"replayed {COUNT} messages on 1 topics" in replay.stdout
    got = [json.loads(line) for line in heard.read_text().splitlines()]
    assert [g["position"][0] for g in got] == [0.01 * k for k in range(COUNT)]
    assert all(g["name"] == NAMES for g in got)


def test_replay_rejects_topics_the_bag_lacks(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "run")
    proc = _replay(str(bag), "--topics", "/x")
    assert proc.returncode == 2, proc.stderr
    assert "`topics` must be topics of" in proc.stderr and "'/x'" in proc.stderr
