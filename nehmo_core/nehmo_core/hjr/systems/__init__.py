"""HJI systems, one per module (as ``hj_reachability.systems``), and the registry by name.

- :mod:`.base`: :class:`HJISystem` (dynamics, Hamiltonian, boundary, symmetry) and the
  conventions every system follows.
- :mod:`.air3d`: :class:`Air3D`, two Dubins cars.
- :mod:`.arm_pair`: :class:`ArmPairSystem`, two velocity-controlled arms.
- :mod:`.two_link`: :class:`TwoLinkPair`, the paper's planar 2-link arms.
- :mod:`.arm_pairs`: the shipped UR5-UR5 and UR5-Kinova pair systems.
- :mod:`.registry`: :func:`make_system` by name.
"""

from nehmo_core.hjr.systems.air3d import Air3D
from nehmo_core.hjr.systems.arm_pair import ArmPairSystem, JointInterval
from nehmo_core.hjr.systems.base import HJISystem, wrap_to_pi
from nehmo_core.hjr.systems.registry import make_system, register_system, system_names
from nehmo_core.hjr.systems.two_link import TwoLinkDistance, TwoLinkPair, segment_distance

__all__ = [
    "Air3D",
    "ArmPairSystem",
    "HJISystem",
    "JointInterval",
    "TwoLinkDistance",
    "TwoLinkPair",
    "make_system",
    "register_system",
    "segment_distance",
    "system_names",
    "wrap_to_pi",
]
