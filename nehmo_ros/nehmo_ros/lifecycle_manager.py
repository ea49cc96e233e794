"""`lifecycle_manager` node: brings managed nodes (``arm_planner`` with ``autostart:=false``) up,
or down, in order, then exits.

    install/nehmo_ros/lib/nehmo_ros/lifecycle_manager --ros-args \\
        -p node_names:="[arm_planner_ur5_0, arm_planner_ur5_1]" -p transitions:=configure,activate

For each transition in ``transitions`` (``configure``, ``activate``, ``deactivate``,
``cleanup``, ``shutdown``) it calls ``/<node>/change_state`` (lifecycle_msgs/ChangeState) of every
node of ``node_names`` in turn, waiting up to ``timeout`` seconds for each node's service to
appear and answer: first every node is configured, then every node activated, as Nav2's
lifecycle manager does. It exits 0 when every transition succeeded, else 2 with one line
naming the node and the transition. ``orchestrate`` starts the planners unconfigured and runs
this before the episode.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Sequence

import rclpy
from lifecycle_msgs.msg import Transition
from lifecycle_msgs.srv import ChangeState
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_ros.node_support import Param, check_ros_arguments, declare_parameters

__all__ = ["TRANSITIONS", "main", "manage"]

TRANSITIONS: dict[str, int] = {
    "configure": Transition.TRANSITION_CONFIGURE,
    "activate": Transition.TRANSITION_ACTIVATE,
    "deactivate": Transition.TRANSITION_DEACTIVATE,
    "cleanup": Transition.TRANSITION_CLEANUP,
    "shutdown": Transition.TRANSITION_INACTIVE_SHUTDOWN,
}
PARAMS: dict[str, Param] = {
    "node_names": Param([""], "the managed nodes, in order"),
    "transitions": Param("configure,activate", f"comma-separated, among {list(TRANSITIONS)}"),
    "timeout": Param(120.0, "[s] longest wait for one node's service and answer", 0.1, 3600.0),
}


def manage(node: Node, names: Sequence[str], transitions: Sequence[str], timeout: float) -> None:
    """Run every transition on every node (transition by transition); NehmoError on the first
    that fails."""
    executor = SingleThreadedExecutor(context=node.context)
    executor.add_node(node)
    try:
        for transition in transitions:
            for name in names:
                client = node.create_client(ChangeState, f"/{name.strip('/')}/change_state")
                try:
                    end = time.monotonic() + timeout
                    while not client.service_is_ready() and time.monotonic() < end:
                        executor.spin_once(timeout_sec=0.05)
                    if not client.service_is_ready():
                        raise NehmoError(f"{name}: no change_state service within {timeout:g} s")
                    request = ChangeState.Request(transition=Transition(id=TRANSITIONS[transition]))
                    future = client.call_async(request)
                    while not future.done() and time.monotonic() < end:
                        executor.spin_once(timeout_sec=0.05)
                    if not future.done():
                        raise NehmoError(f"{name}: {transition} got no answer within {timeout:g} s")
                    if not future.result().success:
                        raise NehmoError(f"{name}: {transition} failed (see the node's log)")
                    node.get_logger().info(f"{name}: {transition}d")
                finally:
                    node.destroy_client(client)
    finally:
        executor.remove_node(node)


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `lifecycle_manager` console script."""
    program = "lifecycle_manager"
    args = [program, *(sys.argv[1:] if argv is None else argv)]
    if "-h" in args or "--help" in args:
        print(__doc__.strip(), flush=True)
        return 0
    context = rclpy.Context()
    try:
        check_ros_arguments(args)
        rclpy.init(args=args, context=context)
        node = Node(program, context=context)
        try:
            p = declare_parameters(node, PARAMS)
            names = [n for n in p["node_names"] if n.strip()]
            if not names:
                raise InvalidValueError("node_names", "must name at least one node", [])
            transitions = [t.strip() for t in str(p["transitions"]).split(",") if t.strip()]
            bad = [t for t in transitions if t not in TRANSITIONS]
            if bad or not transitions:
                rule = f"must be comma-separated among {list(TRANSITIONS)}"
                raise InvalidValueError("transitions", rule, p["transitions"])
            manage(node, names, transitions, float(p["timeout"]))
        finally:
            node.destroy_node()
    except (NehmoError, ValueError) as err:
        print(f"{program}: error: {err}", file=sys.stderr, flush=True)
        return 2
    finally:
        context.try_shutdown()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
