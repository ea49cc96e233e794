"""Robot models (UR5, Kinova Gen3 6-DoF, planar 2-link), their registry and cell layouts."""

from nehmo_core.robots.descriptions import robot_names
from nehmo_core.robots.loader import cell_names, load_cell, load_robot
from nehmo_core.robots.model import (
    ArmSpec,
    Cell,
    JointSpec,
    Pose,
    RobotFacts,
    RobotModel,
    wrap_angle,
)
from nehmo_core.robots.registry import ROBOT_NAMES

__all__ = [
    "ROBOT_NAMES",
    "ArmSpec",
    "Cell",
    "JointSpec",
    "Pose",
    "RobotFacts",
    "RobotModel",
    "cell_names",
    "load_cell",
    "load_robot",
    "robot_names",
    "wrap_angle",
]
