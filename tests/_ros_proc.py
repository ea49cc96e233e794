"""Child processes of the ROS runtime tests: ``python _ros_proc.py <mode> [options]``.

Modes
  pub SECONDS          embedded runtime: publish JointState on /arm_a/joint_states at 50 Hz
  sub SECONDS COUNT    embedded runtime: print received JointStates as JSON lines, stop at COUNT
  plain_sub SECONDS [TOPIC]  plain cyclonedds (no nehmo code): read a JointState DDS topic
                       (default rt/arm_a/joint_states), print JSON
  spin                 a node main() spinning until SIGINT/SIGTERM; prints "clean exit"
  params ARGS...       build a node from ARGS and print its parameters as JSON (one error line
                       and exit status 2 on bad parameters)
  mcap_writer PATH COUNTER  write JointStates to an MCAP log forever, counting them in COUNTER
"""

import json
import os
import sys
import time
from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, sequence, uint32

# The independent participant's own types (no nehmo code), named as ROS 2 names them. No
# `from __future__ import annotations` in this file: cyclonedds resolves annotations at run time.


@dataclass
class Stamp(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Hdr(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Stamp = field(default_factory=Stamp)
    frame_id: str = ""


@dataclass
class Joints(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Hdr = field(default_factory=Hdr)
    name: sequence[str] = field(default_factory=list)
    position: sequence[float64] = field(default_factory=list)
    velocity: sequence[float64] = field(default_factory=list)
    effort: sequence[float64] = field(default_factory=list)


def run_pub(seconds: float) -> int:
    from nehmo_ros import ros

    ros.init(args=[])
    node = ros.Node("test_pub")
    pub = node.create_publisher(ros.msg.JointState, "/arm_a/joint_states", 10)
    count = [0]

    def tick() -> None:
        count[0] += 1
        msg = ros.msg.JointState()
        msg.header.stamp = node.get_clock().now().to_msg()
        msg.header.frame_id = "base"
        msg.name = [f"joint_{i}" for i in range(6)]
        msg.position = [0.1 * i + count[0] for i in range(6)]
        msg.velocity = [0.0] * 6
        pub.publish(msg)

    node.create_timer(0.02, tick)
    executor = ros.SingleThreadedExecutor()
    executor.add_node(node)
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        executor.spin_once(0.05)
    print(json.dumps({"published": count[0]}), flush=True)
    node.destroy_node()
    ros.shutdown()
    return 0


def run_spin() -> int:
    """A node main() as the suite writes them: spin until Ctrl-C/SIGTERM, then clean up."""
    from nehmo_ros import ros

    ros.init(args=[])
    node = ros.Node("spinner")
    node.create_timer(0.01, lambda: None)
    print("spinning", flush=True)
    try:
        ros.spin(node)
    except (KeyboardInterrupt, ros.ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        ros.try_shutdown()
    print("clean exit", flush=True)
    return 0


def run_sub(seconds: float, wanted: int) -> int:
    from nehmo_ros import ros

    ros.init(args=[])
    node = ros.Node("test_sub")
    got: list[dict[str, object]] = []

    def on_msg(msg: ros.msg.JointState) -> None:
        got.append({"name": list(msg.name), "position": list(msg.position)})
        print(json.dumps(got[-1]), flush=True)

    node.create_subscription(ros.msg.JointState, "/arm_a/joint_states", on_msg, 10)
    end = time.monotonic() + seconds
    while time.monotonic() < end and len(got) < wanted:
        ros.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    ros.shutdown()
    return 0


def run_plain_sub(seconds: float, dds_topic: str = "rt/arm_a/joint_states") -> int:
    """An independent participant: cyclonedds only, its own types and its own loopback config."""
    from cyclonedds.domain import Domain, DomainParticipant
    from cyclonedds.qos import Policy, Qos
    from cyclonedds.sub import DataReader
    from cyclonedds.topic import Topic
    from cyclonedds.util import duration

    domain_id = int(os.environ["ROS_DOMAIN_ID"])
    config = (
        '<CycloneDDS><Domain Id="any"><General><Interfaces>'
        '<NetworkInterface address="127.0.0.1"/></Interfaces>'
        "<AllowMulticast>false</AllowMulticast></General><Discovery>"
        "<ParticipantIndex>auto</ParticipantIndex>"
        "<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>"
        '<Peers><Peer address="127.0.0.1"/></Peers></Discovery></Domain></CycloneDDS>'
    )
    domain = Domain(domain_id, config)
    participant = DomainParticipant(domain_id)
    qos = Qos(
        Policy.Reliability.Reliable(duration(milliseconds=100)),
        Policy.History.KeepLast(10),
        Policy.Durability.Volatile,
    )
    topic = Topic(participant, dds_topic, Joints, qos=qos)
    reader = DataReader(participant, topic, qos=qos)
    end = time.monotonic() + seconds
    n = 0
    while time.monotonic() < end and n < 3:
        for sample in reader.take(N=10):
            if isinstance(sample, Joints):
                n += 1
                out = {
                    "frame_id": sample.header.frame_id,
                    "name": list(sample.name),
                    "position": list(sample.position),
                    "type": topic.get_type_name(),
                }
                print(json.dumps(out), flush=True)
        time.sleep(0.02)
    del reader, topic, participant, domain
    return 0


def run_params(argv: list[str]) -> int:
    """The parameter handling a node's main() does: one clear line and status 2 on bad input."""
    from nehmo_ros import ros

    try:
        ros.init(args=["node", *argv])
        node = ros.Node("arm_planner")
        values = {
            "arm_id": node.declare_parameter("arm_id", ros.Parameter.Type.STRING),
            "rate": node.declare_parameter("rate", 25.0),
            "t_plan": node.declare_parameter("t_plan", 0.1),
            "planner": node.declare_parameter("planner", "nehmo"),
            "peers": node.declare_parameter("peers", ["a"]),
        }
        out = {k: v.value for k, v in values.items()}
        node.get_parameter("arm_id")
        out["node"] = node.get_name()
    except ros.PARAMETER_ERRORS as err:
        print(f"arm_planner: error: {err}", file=sys.stderr)
        return 2
    print(json.dumps(out))
    ros.try_shutdown()
    return 0


def run_mcap_writer(path: str, counter_path: str) -> None:
    """Write JointStates forever; COUNTER always holds how many write() calls returned."""
    from nehmo_core.logs import Header, JointState, LogWriter, Time, WriterSettings

    fd = os.open(counter_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    writer = LogWriter(path, WriterSettings(flush_every=20, flush_interval_s=10.0))
    writer.write_scenario({"arms": ["arm_a"], "seed": 1})
    i = 0
    while True:
        msg = JointState(
            header=Header(stamp=Time(sec=i // 1000, nanosec=(i % 1000) * 1_000_000)),
            name=["j1", "j2"],
            position=[0.001 * i, -0.001 * i],
        )
        writer.write("/arm_a/joint_states", msg, log_time_ns=1_000_000 * (i + 1))
        i += 1
        os.pwrite(fd, f"{i:12d}\n".encode(), 0)
        if i % 200 == 0:
            time.sleep(0.01)


def main() -> int:
    mode, args = sys.argv[1], sys.argv[2:]
    if mode == "pub":
        return run_pub(float(args[0]))
    if mode == "sub":
        return run_sub(float(args[0]), int(args[1]))
    if mode == "plain_sub":
        return run_plain_sub(float(args[0]), *args[1:2])
    if mode == "spin":
        return run_spin()
    if mode == "params":
        return run_params(args)
    if mode == "mcap_writer":
        run_mcap_writer(args[0], args[1])  # runs until killed
    raise SystemExit(f"unknown mode {mode!r}")


if __name__ == "__main__":
    raise SystemExit(main())
