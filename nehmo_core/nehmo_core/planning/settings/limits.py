"""The settings groups of the stages that keep an arm within its own limits: its joints' range
(``planning/stages/joint_limits.py``) and its links' clearance from each other
(``planning/stages/self_clearance.py``)."""

from __future__ import annotations

from dataclasses import dataclass

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.settings.spec import check_group, setting

__all__ = ["JointLimitSettings", "SelfClearanceSettings"]


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


@dataclass(frozen=True)
class SelfClearanceSettings:
    """Self-collision velocity dampers (``planning/stages/self_clearance.py``): link pairs
    closer than ``influence`` may close at most ``gain`` of their distance above ``safety`` per
    planned step, in the step and in the fail-safe."""

    enabled: bool = setting(
        True, "self-collision rows in Opt and the fail-safe (false: the paper's Opt)"
    )
    influence: float = setting(0.10, "link pairs closer than this get a row", "m", gt=0)
    safety: float = setting(0.005, "distance the rows keep between links", "m", ge=0)
    gain: float = setting(
        0.5, "share of the distance above safety a pair may close per step", gt=0, le=1
    )
    # a command runs from where the one in flight takes the arm (one tick after it was planned)
    ahead: bool = setting(
        True,
        "rows at the pose the command in flight reaches in one opt.tick (false: the observed pose)",
    )
    # linear rows let a folded UR5 creep 0.5-1 mm a tick through the safety distance into a
    # self-contact (a ridge of its wrist-upper arm distance in wrist 2; gen_7arm_s78_024)
    check: float = setting(
        0.02,
        "pairs closer than this are checked at the step's end with the exact geometry: none "
        "may end below min(now, max(safety - slack, 0)) (0: off)",
        "m",
        ge=0,
    )
    # at d = safety a row allows no closing to first order, and the distance's curvature along
    # any step closes it by a few µm: every step failed the check, and a Panda stood still 2.5
    # rad from its goal, 25 cm from its peer, for the rest of the episode (dual_panda seed 81)
    slack: float = setting(
        0.001,
        "how far below safety the check lets a step end (the curvature the rows cannot see)",
        "m",
        ge=0,
    )
    # the curvature closed pairs at 4.0-4.1 mm by up to 0.8 mm in one tick along steps the rows
    # kept at zero, every share failed, and two Pandas stood still ~2 rad from their goals for
    # good (dual_panda development seeds 62 and 63; 373 -> 375 of 400 on seeds 60-63)
    opening: float = setting(
        0.0005,
        "what a step the check refused at every share must open the near pairs by, to first "
        "order, per tick (then 3x that; 0: stop the arm instead)",
        "m",
        ge=0,
    )
    # On the UR5's closed-loop joint paths of the planning-speed bench, 0.5 m asks 5.4 pairs per
    # step against 7.7 at 0.15 m (a pair out of reach reads as at the reach, so a short reach
    # brings it back soon)
    query_reach: float = setting(
        0.5,
        "how far beyond influence a pair is queried before it is skipped until joints move",
        "m",
        gt=0,
    )

    def __post_init__(self) -> None:
        check_group(self, "self_clearance")
        if not self.influence > self.safety:
            raise InvalidValueError(
                "self_clearance.influence",
                f"must be > self_clearance.safety ({self.safety})",
                self.influence,
            )
