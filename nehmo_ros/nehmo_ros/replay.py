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
    min_subscribers: int = 0,
) -> int:
    """Republish the messages of a bag through rclpy with their recorded timing (× 1/rate).

    Every topic's publisher is created first. With ``min_subscribers`` 0, ``wait_s`` seconds
    pass for discovery before the first message; otherwise the first message goes out as soon
    as every publisher has ``min_subscribers`` matched subscriptions, and an
    :class:`InvalidValueError` naming ``--min-subscribers`` ends the replay when that takes
    longer than ``wait_s``. After the last message the replay waits up to ``wait_s`` seconds
    for every reliable subscriber to acknowledge what it was sent (and says on stderr which
    topics were not acknowledged in time). The serialized bytes go out as recorded; goals and
    the scenario are latched as the bridge publishes them. Topics of types this ROS install
    lacks are skipped (and listed).
    """
    import rclpy
    from rclpy.duration import Duration
    from rclpy.node import Node

    from nehmo_core.logs import iter_log, summarize
    from nehmo_ros.recorder import LATCHED, is_latched, message_class

    if not rate > 0:
        raise InvalidValueError("rate", "must be > 0", rate)
    if not wait_s >= 0:
        raise InvalidValueError("wait", "must be >= 0 [s]", wait_s)
    if not min_subscribers >= 0:
        raise InvalidValueError("--min-subscribers", "must be >= 0", min_subscribers)
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
    count, t0_log = 0, None
    try:
        _wait_for_subscribers(pubs, min_subscribers, wait_s)
        t0_wall = time.monotonic()
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
        end = time.monotonic() + wait_s
        unacked = [
            topic
            for topic, pub in pubs.items()
            if not pub.wait_for_all_acked(Duration(seconds=max(end - time.monotonic(), 0.0)))
        ]
        if unacked:
            print(
                f"replay: not every subscriber acknowledged the messages of {unacked} "
                f"within --wait {wait_s:g} s",
                file=sys.stderr,
            )
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(f"replayed {count} messages on {len(pubs)} topics from {path}")
    return 0


def _wait_for_subscribers(pubs: dict[str, Any], min_subscribers: int, wait_s: float) -> None:
    """Return once every publisher has ``min_subscribers`` matched subscriptions (0: after
    ``wait_s`` seconds); an :class:`InvalidValueError` if that takes longer than ``wait_s``."""
    if min_subscribers == 0:
        time.sleep(wait_s)
        return
    end = time.monotonic() + wait_s
    while True:
        counts = {topic: pub.get_subscription_count() for topic, pub in pubs.items()}
        if all(n >= min_subscribers for n in counts.values()):
            return
        if time.monotonic() >= end:
            short = {topic: n for topic, n in counts.items() if n < min_subscribers}
            raise InvalidValueError(
                "--min-subscribers",
                f"must be reached by every topic's publisher within --wait {wait_s:g} s "
                f"(subscriptions now: {short})",
                min_subscribers,
            )
        time.sleep(0.05)
