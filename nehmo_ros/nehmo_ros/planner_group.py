"""`arm_planners` nodes: several `arm_planner` nodes in one process (composition).

    ros2 run nehmo_ros arm_planners --ros-args -p arm_ids:="[ur5_0, ur5_1]" -p cell:=dual_ur5

Each arm of ``arm_ids`` gets a node of its own, ``arm_planner_<id>``, exactly as the
``arm_planner`` executable builds it: its own topics, services, action, lifecycle, parameters
and solve worker thread. One executor spins them all. This is what ROS 2 composition does for
C++ components: on a small machine, eight planners in one or two processes share one DDS
participant each instead of eight, and the operating system schedules two processes instead of
eight (``bench/ros_task.py --layouts``).

Parameters: ``arm_ids`` (required, the cell's arm ids), ``planners`` (optional: one kind per
arm joined by '/', as ``orchestrate --planner``; '' gives every node the ``planner``
parameter), and every parameter of ``arm_planner`` (``cell``, ``model``, ``rate``, planner
settings, ...), which applies to every node of the group; ``arm_id`` and the node name come
from ``arm_ids`` (a ``__node`` remap is refused: it would give every node the same name).
A bad parameter stops the process with one line naming the arm, the parameter, the rule and
the value.
"""

from __future__ import annotations

import sys
from collections.abc import Sequence

from rclpy.node import Node

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_ros.arm_planner import ArmPlannerNode
from nehmo_ros.node_support import NODE_ERRORS, Param, declare_parameters, run_main
from nehmo_ros.processes import planner_node_name

PROGRAM = "arm_planners"
GROUP_PARAMS: dict[str, Param] = {
    "arm_ids": Param([""], "ids of the arms this process plans for, one node each"),
    "planners": Param("", "one planner kind per arm joined by '/' ('': the planner parameter)"),
}


def group_members(arm_ids: Sequence[str], planners: str) -> dict[str, dict[str, str]]:
    """``{arm_id: own parameters}`` of each node; errors name the parameter and the value."""
    ids = [a.strip() for a in arm_ids if a.strip()]
    if not ids:
        raise InvalidValueError("arm_ids", "must name at least one arm", list(arm_ids))
    if len(set(ids)) != len(ids):
        raise InvalidValueError("arm_ids", "must not repeat an arm", list(arm_ids))
    kinds = [k.strip() for k in planners.split("/")] if planners.strip() else []
    if kinds and len(kinds) != len(ids):
        rule = f"must give one kind per arm of arm_ids ({len(ids)}) joined by '/'"
        raise InvalidValueError("planners", rule, planners)
    return {a: {"arm_id": a, **({"planner": kinds[i]} if kinds else {})} for i, a in enumerate(ids)}


class _GroupParameters(Node):
    """The process's own node: it reads ``arm_ids`` and ``planners`` and stays up as the
    group's container (it publishes nothing)."""

    def __init__(self) -> None:
        super().__init__(PROGRAM)
        values = declare_parameters(self, GROUP_PARAMS)
        self.members = group_members(values["arm_ids"], str(values["planners"]))

    def on_stop(self) -> None:
        pass


def build_group() -> list[Node]:
    """The container node, then one :class:`ArmPlannerNode` per arm."""
    group = _GroupParameters()
    nodes: list[Node] = [group]
    for arm_id, own in group.members.items():
        try:
            nodes.append(ArmPlannerNode(planner_node_name(arm_id), own))
        except NODE_ERRORS as err:
            raise NehmoError(f"arm {arm_id!r}: {err}") from None
    return nodes


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `arm_planners` console script."""
    args = list(sys.argv[1:] if argv is None else argv)
    if any(a.startswith(("__node:=", "__name:=")) for a in args):
        rule = "cannot be remapped for a group (each node is named arm_planner_<id>)"
        print(f"{PROGRAM}: error: `__node` {rule}", file=sys.stderr, flush=True)
        return 2
    sys.setswitchinterval(5e-4)  # the timer thread gets the GIL back from the solvers quickly
    return run_main(PROGRAM, build_group, args, usage=__doc__)


if __name__ == "__main__":
    raise SystemExit(main())
