"""Child processes of the ROS tests: ``python _ros_proc.py <mode> [options]``.

Modes
  listen SECONDS OUT TOPIC...  a plain rclpy node (no nehmo code): subscribe to each TOPIC
                       (JointState for ``*/joint_states``, Float64MultiArray for
                       ``*/commands``, Float64 for ``*/speed_bound``, DiagnosticArray for
                       ``/diagnostics``) and append one
                       JSON line per message received to the file OUT (a file, not a pipe: a
                       pipe nobody reads fills up and stops the node); prints "listening"
  flood SECONDS ARM    a plain rclpy node (no nehmo code) that publishes garbage at 100 Hz
                       for SECONDS: JointState on ``/ARM/joint_states`` (NaN, inf, 1e9
                       positions, three joints, unknown names; default header stamp) and
                       Float64MultiArray on ``/ARM/velocity_controller/commands`` (NaN, five
                       values, 1e6); prints one JSON line with the counts published
"""

import json
import signal
import sys
import time


def run_listen(seconds: float, out_path: str, topics: list[str]) -> int:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.node import Node
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64, Float64MultiArray

    rclpy.init()
    node = Node("plain_listener")
    out_file = open(out_path, "a")  # noqa: SIM115 (closed below)

    def printer(topic: str):  # type: ignore[no-untyped-def]
        def on_msg(msg) -> None:  # type: ignore[no-untyped-def]
            out: dict[str, object] = {"topic": topic}
            if isinstance(msg, JointState):
                out.update(name=list(msg.name), position=list(msg.position))
            elif isinstance(msg, Float64MultiArray):
                out.update(data=list(msg.data))
            elif isinstance(msg, Float64):
                out.update(data=msg.data)
            else:
                out.update(status=[s.name for s in msg.status])
            out_file.write(json.dumps(out) + "\n")
            out_file.flush()

        return on_msg

    for topic in topics:
        if topic.endswith("joint_states"):
            node.create_subscription(JointState, topic, printer(topic), 100)  # reliable
        elif topic.endswith("commands"):
            node.create_subscription(Float64MultiArray, topic, printer(topic), 10)
        elif topic.endswith("speed_bound"):
            node.create_subscription(Float64, topic, printer(topic), 10)
        else:
            node.create_subscription(DiagnosticArray, topic, printer(topic), 10)
    print(json.dumps({"listening": topics}), flush=True)
    end = time.monotonic() + seconds
    while time.monotonic() < end and rclpy.ok():
        rclpy.spin_once(node, timeout_sec=0.05)
    node.destroy_node()
    rclpy.try_shutdown()
    out_file.close()
    return 0


def run_flood(seconds: float, arm: str) -> int:
    import rclpy
    from rclpy.node import Node
    from rclpy.signals import SignalHandlerOptions
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Float64MultiArray

    # its own SIGTERM handler: the loop ends and the counts are printed whatever rclpy is doing
    stop: list[int] = []
    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, lambda n, _frame: stop.append(n))
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    node = Node("foreign_flood")
    states = node.create_publisher(JointState, f"/{arm}/joint_states", 100)
    commands = node.create_publisher(Float64MultiArray, f"/{arm}/velocity_controller/commands", 10)
    joints = [
        "shoulder_pan_joint",
        "shoulder_lift_joint",
        "elbow_joint",
        "wrist_1_joint",
        "wrist_2_joint",
        "wrist_3_joint",
    ]
    bad_states = [
        (joints, [float("nan")] * 6),
        (joints, [float("inf")] * 6),
        (joints, [1e9] * 6),
        (joints[:3], [0.1] * 3),
        ([f"unknown_{i}" for i in range(6)], [0.1] * 6),
    ]
    bad_commands = [[float("nan")] * 6, [0.1] * 5, [1e6] * 6]
    sent = {"states": 0, "commands": 0}
    print(json.dumps({"flooding": arm}), flush=True)
    end = time.monotonic() + seconds
    k = 0
    while time.monotonic() < end and rclpy.ok() and not stop:
        names, position = bad_states[k % len(bad_states)]
        states.publish(JointState(name=names, position=position))
        sent["states"] += 1
        if k % 2 == 0:
            commands.publish(Float64MultiArray(data=bad_commands[(k // 2) % len(bad_commands)]))
            sent["commands"] += 1
        k += 1
        rclpy.spin_once(node, timeout_sec=0.0)
        time.sleep(0.01)
    print(json.dumps(sent), flush=True)
    node.destroy_node()
    rclpy.try_shutdown()
    return 0


def main() -> int:
    mode, args = sys.argv[1], sys.argv[2:]
    if mode == "listen":
        return run_listen(float(args[0]), args[1], args[2:])
    if mode == "flood":
        return run_flood(float(args[0]), args[1])
    raise SystemExit(f"unknown mode {mode!r}")


if __name__ == "__main__":
    raise SystemExit(main())
