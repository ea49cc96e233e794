"""`recorder` node: records the suite's topics into a rosbag2 bag (metadata.yaml + MCAP).

    install/nehmo_ros/lib/nehmo_ros/recorder --ros-args -p cell:=dual_ur5 -p output:=run_bag

It records every topic of the NeHMO schema for the cell's arms (:func:`nehmo_core.logs.topics
.ros_topics`: joint states, commands, goals, planner status and markers per arm; ``/clock``,
``/nehmo/collisions``, ``/nehmo/scenario``). Subscriptions are raw (``raw=True``): the bag holds
the serialized bytes as they arrived, written by :class:`nehmo_core.logs.LogWriter` (the writer
of the batch runs), so ``nehmo_core.eval`` evaluates a ROS run like a batch one, and
``ros2 bag``, Foxglove, ``rosbags`` and ``mcap`` open it.

Log times: with ``stamp_source:=header`` (default) a message that carries a time (a header
stamp, or ``/clock``'s time) is logged at that time and the others at their receive time on the
node clock (simulated time under ``use_sim_time``), so the joint states of all arms published
at one simulator step share one log time; ``stamp_source:=receive`` logs everything at its
receive time, as ``ros2 bag record`` does.

Durability: the bag is flushed every ``flush_every`` messages and, by a timer on the monotonic
clock (it runs when traffic and simulated time stop), every ``flush_interval`` s while messages
are unflushed. On SIGINT/SIGTERM the node takes what is still queued, then writes the summary
and ``metadata.yaml``: nothing received is lost. After SIGKILL the bag lacks both; repair it
with ``python -m nehmo_core.logs.recover BROKEN_BAG FIXED_BAG`` (loses at most the last flush
interval). An existing ``output`` is never overwritten: the node records to ``<output>_1``
(``_2`` ...) instead and says so. A message that cannot be written (disk full, ...) is counted
and reported, and recording goes on.

Parameters: ``cell`` (required), ``output`` (bag directory; default ``nehmo_<date>_<time>``),
``stamp_source`` (header | receive), ``flush_every`` [messages], ``flush_interval`` [s].
"""

from __future__ import annotations

import importlib
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.logs.messages import leading_stamp_ns
from nehmo_core.logs.topics import (
    CLOCK_TYPE,
    COLLISIONS_TYPE,
    JOINT_STATE_TYPE,
    SCENARIO_TOPIC,
    ros_topics,
    split_arm_topic,
)
from nehmo_core.logs.writer import LogWriter, QosDescription, WriterSettings
from nehmo_ros.node_support import Param, declare_parameters, load_cell_parameter, run_main

PARAMS: dict[str, Param] = {
    "cell": Param("", "shipped cell name (dual_ur5, ...) or a cell YAML path"),
    "output": Param("", "bag directory to create; default nehmo_<date>_<time>"),
    "stamp_source": Param("header", "header | receive: the log time of stamped messages"),
    # each flush closes an MCAP chunk, and the writer keeps ~1.5 KB of index per chunk until
    # the bag is closed: under load (1000 messages/s) the timer, not the count, should flush
    "flush_every": Param(1000, "[messages] flush to the OS after this many"),
    "flush_interval": Param(0.5, "[s] flush at least this often while messages are pending"),
}
STAMP_SOURCES = ("header", "receive")
#: Types whose CDR starts with a builtin_interfaces/Time (a header stamp or the clock).
STAMPED_TYPES = (JOINT_STATE_TYPE, COLLISIONS_TYPE, CLOCK_TYPE)

LATCHED = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
#: Reader history per topic: 10 s of 100 Hz joint states, so a recorder that stalls (CPU
#: starved) catches up without evicting anything; publishers keep 2 s (bridge, planners).
RECORDING = QoSProfile(depth=1000)


def message_class(msgtype: str) -> Any:
    """The generated rclpy class of ``pkg/msg/Name``."""
    package, _, name = msgtype.split("/")
    return getattr(importlib.import_module(f"{package}.msg"), name)


def free_path(path: Path) -> Path:
    """``path``, or ``<path>_<n>`` with the first ``n`` that names nothing existing."""
    if not path.exists():
        return path
    n = 1
    while (candidate := path.with_name(f"{path.name}_{n}")).exists():
        n += 1
    return candidate


def is_latched(topic: str) -> bool:
    """Topics published once and latched: the scenario and the goals."""
    split = split_arm_topic(topic)
    return topic == SCENARIO_TOPIC or (split is not None and split[1] == "goal")


class RecorderNode(Node):
    """The node: one raw subscription per schema topic, one bag writer."""

    def __init__(self) -> None:
        super().__init__("recorder")
        p = declare_parameters(self, PARAMS)
        self.cell = load_cell_parameter(p["cell"])
        if p["stamp_source"] not in STAMP_SOURCES:
            raise UnknownNameError("stamp_source", p["stamp_source"], STAMP_SOURCES)
        self.by_header = p["stamp_source"] == "header"
        for name in ("flush_every", "flush_interval"):  # checked under the node's own names
            if not float(p[name]) > 0:
                raise InvalidValueError(name, "must be > 0", p[name])
        settings = WriterSettings(
            flush_every=int(p["flush_every"]), flush_interval_s=float(p["flush_interval"])
        )
        output = p["output"] or time.strftime("nehmo_%Y%m%d_%H%M%S")
        path = Path(output)
        if path.suffix == ".mcap":
            raise InvalidValueError(
                "output", "must name a bag directory (rosbag2 layout), not an .mcap file", output
            )
        path = free_path(path)
        if str(path) != str(Path(output)):
            self.get_logger().warning(f"{output} exists: recording to {path} instead")
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            self.writer = LogWriter(path, settings, library="nehmo_ros recorder")
        except OSError as err:
            raise InvalidValueError(
                "output", f"must be a writable directory path ({err.strerror or err})", output
            ) from None
        self.path = path
        self.lost = 0
        self.topics = ros_topics(list(self.cell.arm_ids))
        for topic, msgtype in self.topics.items():
            latched = is_latched(topic)
            self.writer.add_topic(
                topic,
                msgtype,
                QosDescription(depth=1, durability="transient_local")
                if latched
                else QosDescription(depth=RECORDING.depth),
            )
            self.create_subscription(
                message_class(msgtype),
                topic,
                self._callback(topic, msgtype),
                LATCHED if latched else RECORDING,
                raw=True,
            )
        self.count = 0
        self.flush_timer = self.create_timer(
            settings.flush_interval_s,
            self._flush_pending,
            clock=Clock(clock_type=ClockType.STEADY_TIME),
        )
        self.get_logger().info(f"recording {len(self.topics)} topics to {path}")

    def _callback(self, topic: str, msgtype: str) -> Callable[[bytes], None]:
        stamped = self.by_header and msgtype in STAMPED_TYPES
        return lambda data: self._on_message(topic, msgtype, bytes(data), stamped)

    def _on_message(self, topic: str, msgtype: str, data: bytes, stamped: bool) -> None:
        received = self.get_clock().now().nanoseconds
        try:
            log_time = leading_stamp_ns(data) if stamped else received
        except Exception:  # a message too short to hold a stamp: log it at its receive time
            log_time = received
        try:
            self.writer.write_raw(topic, data, max(log_time, 0), received, msgtype)
        except Exception as err:  # disk full, ...: count, report, keep recording
            self.lost += 1
            self.get_logger().error(
                f"cannot write a message of {topic} ({type(err).__name__}: {err}); "
                f"{self.lost} lost so far",
                throttle_duration_sec=2.0,
            )
            return
        self.count += 1

    def _flush_pending(self) -> None:
        """Flush what came since the last flush (traffic may have stopped since)."""
        if not self.writer.pending:
            return
        try:
            self.writer.flush()
        except Exception as err:  # disk full, ...: report, keep recording
            self.get_logger().error(
                f"cannot flush {self.path} ({type(err).__name__}: {err})",
                throttle_duration_sec=2.0,
            )

    def on_stop(self) -> None:
        """Write the summary (the queued messages were taken by the final drain)."""
        self.flush_timer.cancel()
        try:
            self.writer.close()
        except Exception as err:
            print(
                f"recorder: error: cannot finish {self.path} ({type(err).__name__}: {err}); "
                f"repair it with: python -m nehmo_core.logs.recover {self.path} <fixed_bag>",
                file=sys.stderr,
                flush=True,
            )
            return
        lost = f", {self.lost} could not be written" if self.lost else ""
        print(f"recorder: {self.count} messages written to {self.path}{lost}", flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `recorder` console script."""
    return run_main("recorder", RecorderNode, argv, drain_s=0.3, usage=__doc__)


if __name__ == "__main__":
    sys.exit(main())
