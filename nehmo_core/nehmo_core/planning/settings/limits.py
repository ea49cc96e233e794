"""The settings group of the joint-limit stage (``planning/stages/joint_limits.py``)."""

from __future__ import annotations

from dataclasses import dataclass

from nehmo_core.planning.settings.spec import check_group, setting

__all__ = ["JointLimitSettings"]


@dataclass(frozen=True)
class JointLimitSettings:
    """The joint-limit stage (``planning/stages/joint_limits.py``): no command drives a joint
    past its limit within the next tick."""

    # a Panda's fail-safe drove joint 2 into its lower limit, where the simulator held it, and the
    # self-clearance check, predicting the joint's motion, let the hand graze the base (dual_panda,
    # seed 60, scenario 14)
    enabled: bool = setting(True, "clip each joint's command at its limit (the paper does not)")

    def __post_init__(self) -> None:
        check_group(self, "joint_limits")
