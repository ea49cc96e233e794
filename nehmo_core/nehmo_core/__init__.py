"""NeHMO core: robot models, geometry, neural HJR, planning, simulation and evaluation.

This package never imports ROS; the ROS 2 nodes in ``nehmo_ros`` and ``sim_bridge`` are thin
shells around it.
"""

from nehmo_core.errors import InvalidValueError, ModelFileError, NehmoError, UnknownNameError

__version__ = "0.1.0"

__all__ = ["InvalidValueError", "ModelFileError", "NehmoError", "UnknownNameError", "__version__"]
