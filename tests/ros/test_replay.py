"""``orchestrate replay`` republishes a bag through rclpy: a plain rclpy node receives every
message, in order, with its recorded content."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from _ros_testutil import child_env, finish, start

from nehmo_core.logs import Header, JointState, LogWriter, Time

TOPIC = "/ur5_0/joint_states"
NAMES = [f"joint_{i}" for i in range(6)]
COUNT = 40


def _bag(path: Path, topic: str = TOPIC) -> Path:
    with LogWriter(path) as writer:
        for k in range(COUNT):
            t_ns = 1_000_000_000 + k * 20_000_000  # 50 Hz
            msg = JointState(
                header=Header(stamp=Time(sec=t_ns // 1_000_000_000, nanosec=t_ns % 1_000_000_000)),
                name=NAMES,
                position=[0.01 * k] * 6,
            )
            writer.write(topic, msg, log_time_ns=t_ns)
    return path


def _replay(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "nehmo_ros.orchestrate", "replay", *args],
        env=child_env(),
        capture_output=True,
        text=True,
        timeout=240,
    )


def _lines(path: Path) -> int:
    return len(path.read_text().splitlines()) if path.exists() else 0


def test_replay_republishes_every_message_in_order(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "run")
    heard = tmp_path / "listener.jsonl"
    listener = start("listen", "300", str(heard), TOPIC)
    try:
        assert listener.stdout is not None
        assert "listening" in listener.stdout.readline()
        # the first message goes out once the listener is matched (a busy machine can take
        # seconds); afterwards the replay waits for the listener's acknowledgements
        replay = _replay(str(bag), "--min-subscribers", "1", "--wait", "60")
        assert replay.returncode == 0, replay.stderr
        deadline = time.monotonic() + 30.0  # the listener writes what it took to its file
        while _lines(heard) < COUNT and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        listener.terminate()
        finish(listener, timeout=20)
    assert "not every subscriber acknowledged" not in replay.stderr, replay.stderr
    assert f"replayed {COUNT} messages on 1 topics" in replay.stdout
    got = [json.loads(line) for line in heard.read_text().splitlines()]
    assert [g["position"][0] for g in got] == [0.01 * k for k in range(COUNT)]
    assert all(g["name"] == NAMES for g in got)


def test_replay_rejects_topics_the_bag_lacks(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "run")
    proc = _replay(str(bag), "--topics", "/x")
    assert proc.returncode == 2, proc.stderr
    assert "`topics` must be topics of" in proc.stderr and "'/x'" in proc.stderr


def test_replay_without_the_subscribers_it_needs_is_an_error(tmp_path: Path) -> None:
    bag = _bag(tmp_path / "run", "/ur5_1/joint_states")  # a topic nobody here subscribes to
    proc = _replay(str(bag), "--min-subscribers", "1", "--wait", "0.5")
    assert proc.returncode == 2, proc.stderr
    assert "`--min-subscribers` must be reached by every topic's publisher within --wait 0.5 s" in (
        proc.stderr
    )
    assert "'/ur5_1/joint_states': 0" in proc.stderr and "got 1" in proc.stderr
    assert "replayed" not in proc.stdout
