r"""Launch one `sim_bridge`, one `arm_planner` per arm and one `recorder` for a cell.

    ros2 launch nehmo_ros arms.launch.py \
        cell:=/path/to/nehmo_core/nehmo_core/robots/cells/dual_ur5.yaml \
        arm_ids:=ur5_0,ur5_1 planner:=nehmo model:=synthetic

Each planner runs as node `arm_planner_<arm_id>` without a namespace: the node itself derives its
absolute topic names (`/<arm_id>/joint_states`, ...) from its `arm_id` parameter, as in the
design's ROS 2 interface, so it behaves the same under `ros2 run`. `arm_ids` must name arms of the
cell YAML; every node also receives `cell`, each planner `planner` and `model` (shipped |
synthetic | a training run directory), the bridge `planners` (recorded in the episode
metadata). The nodes run on wall time here; `orchestrate` runs the same nodes on simulated time.
"""

from launch import LaunchContext, LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def parse_arm_ids(text: str) -> list[str]:
    """Split a comma-separated `arm_ids` argument; raise if it names no arm or repeats one."""
    arm_ids = [arm_id.strip() for arm_id in text.split(",") if arm_id.strip()]
    if not arm_ids:
        raise ValueError(f"`arm_ids` must name at least one arm, e.g. 'ur5_0,ur5_1'; got {text!r}")
    repeated = sorted({arm_id for arm_id in arm_ids if arm_ids.count(arm_id) > 1})
    if repeated:
        raise ValueError(f"`arm_ids` must not repeat an arm; got {text!r} (repeated: {repeated})")
    return arm_ids


def make_nodes(context: LaunchContext) -> list[Node]:
    """Build the bridge, one planner per arm id and the recorder once arguments are known."""
    cell = LaunchConfiguration("cell").perform(context)
    planner = LaunchConfiguration("planner").perform(context)
    model = LaunchConfiguration("model").perform(context)
    arm_ids = parse_arm_ids(LaunchConfiguration("arm_ids").perform(context))
    nodes = [
        Node(
            package="sim_bridge",
            executable="sim_bridge",
            name="sim_bridge",
            parameters=[{"cell": cell, "planners": planner}],
            output="screen",
        )
    ]
    for arm_id in arm_ids:
        nodes.append(
            Node(
                package="nehmo_ros",
                executable="arm_planner",
                name=f"arm_planner_{arm_id}",
                parameters=[{"arm_id": arm_id, "cell": cell, "planner": planner, "model": model}],
                output="screen",
            )
        )
    nodes.append(
        Node(
            package="nehmo_ros",
            executable="recorder",
            name="recorder",
            parameters=[{"cell": cell}],
            output="screen",
        )
    )
    return nodes


def generate_launch_description() -> LaunchDescription:
    """Entry point read by `ros2 launch`."""
    return LaunchDescription(
        [
            DeclareLaunchArgument("cell", description="Path to the cell YAML (arms, base poses)."),
            DeclareLaunchArgument(
                "arm_ids", description="Comma-separated arm ids of the cell, e.g. ur5_0,ur5_1."
            ),
            DeclareLaunchArgument(
                "planner", default_value="nehmo", description="Planner kind of every arm."
            ),
            DeclareLaunchArgument(
                "model",
                default_value="shipped",
                description="Value models: shipped | synthetic | a run directory or .safetensors.",
            ),
            OpaqueFunction(function=make_nodes),
        ]
    )
