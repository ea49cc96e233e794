"""Robot models (UR5, Kinova Gen3 6-DoF, planar 2-link), their registry and cell layouts."""

from nehmo_core.robots.loader import ROBOT_NAMES, cell_names, load_cell, load_robot
from nehmo_core.robots.model import (
    ArmSpec,
    Cell,
    JointSpec,
    Pose,
    RobotFacts,
    RobotModel,
    wrap_angle,
)

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
    "wrap_angle",
]
