"""``orchestrate replay``: republish a bag's topics through rclpy with their recorded timing."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from nehmo_core.errors import InvalidValueError

__all__ = ["replay"]


def replay(
    path: Path,
    rate: float,
    topics: Sequence[str] | None,
    domain_id: int | None,
    wait_s: float = 1.0,
) -> int:
    """Republish the messages of a bag through rclpy with their recorded timing (× 1/rate).

    Every topic's publisher is created first, then ``wait_s`` seconds pass for discovery before
    the first message. The serialized bytes go out as recorded; goals and the scenario are
    latched as the bridge publishes them. Topics of types this ROS install lacks are skipped
    (and listed).
    """
    import rclpy
    from rclpy.node import Node

    from nehmo_core.logs import iter_log, summarize
    from nehmo_ros.recorder import LATCHED, is_latched, message_class

    if not rate > 0:
        raise InvalidValueError("rate", "must be > 0", rate)
    if not wait_s >= 0:
        raise InvalidValueError("wait", "must be >= 0 [s]", wait_s)
    if domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    in_bag = summarize(path).topics
    wanted = list(in_bag) if not topics else list(topics)
    unknown = sorted(set(wanted) - set(in_bag))
    if unknown:
        raise InvalidValueError("topics", f"must be topics of {path} {sorted(in_bag)}", unknown)
    rclpy.init(args=["orchestrate_replay"])
    node = Node("nehmo_replay")
    pubs: dict[str, Any] = {}
    skipped = []
    for topic in wanted:
        try:
            msg_class = message_class(in_bag[topic][0])
        except (ImportError, AttributeError, ValueError):
            skipped.append(topic)
            continue
        qos = LATCHED if is_latched(topic) else 100
        pubs[topic] = node.create_publisher(msg_class, topic, qos)
    if skipped:
        print(f"skipping topics of unknown types: {skipped}", file=sys.stderr)
    time.sleep(wait_s)
    count, t0_log, t0_wall = 0, None, time.monotonic()
    try:
        for rec in iter_log(path, list(pubs)):
            if not rclpy.ok():
                break
            t0_log = rec.log_time_ns if t0_log is None else t0_log
            due = t0_wall + (rec.log_time_ns - t0_log) / 1e9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            pubs[rec.topic].publish(rec.data)
            count += 1
        time.sleep(min(wait_s, 0.5))  # reliable subscribers fetch the last messages
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(f"replayed {count} messages on {len(pubs)} topics from {path}")
    return 0
