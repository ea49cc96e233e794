"""The settings of the planner's stages beyond the paper, one group per stage.

Each group names the module of its stage; the ``paper`` preset turns every one of them off.
"""

from __future__ import annotations

from dataclasses import dataclass

from nehmo_core.errors import InvalidValueError
from nehmo_core.planning.settings.spec import check_group, setting

__all__ = [
    "ActuatorSettings",
    "ContactSettings",
    "EscapeSettings",
    "ExactGuardSettings",
    "HoldSettings",
    "SilentWatchSettings",
]


@dataclass(frozen=True)
class HoldSettings:
    """Announced speed bounds (``planning/stages/speed_bounds.py``).

    An arm within ``tolerance`` of its goal announces ``bound`` (a share of ū) and keeps its
    commands within it until it leaves ``release``, gets a new goal or a peer breaks
    V(bound·t_plan) ≥ ε with it (half its settled margin for a peer that announces), announcing
    the withdrawal ``release_ticks`` commands ahead; peers that keep their announcement are
    planned against V(k·t_safe). ``bound`` = 1: announce nothing (the paper).
    """

    bound: float = setting(
        0.2, "speed bound announced at the goal, share of u_max (1: none, the paper)", ge=0, le=1
    )
    # just inside the evaluation's success tolerance (0.1 rad): an arm that has arrived is
    # settled for its peers, which may then come as close as the settled margin lets them (0.05
    # left arms 0.05-0.1 rad from their goals planned at full speed, pressing a peer that still
    # had to reach a goal beside them: dual_panda development seeds 60-63, 368 -> 373 of 400,
    # 5 gained, none lost)
    tolerance: float = setting(
        0.09, "goal distance (L2) within which the bound is announced", "rad", gt=0
    )
    # an arm held short of its goal by a peer's row announces from farther out, so the peer
    # plans the slow game against it and moves on (dual_panda seed 60, scenario 92); only then,
    # so that an arm arriving in open space is not slowed for its last tenth of a radian
    pressed_tolerance: float = setting(
        0.15,
        "goal distance (L2) within which the bound is announced while a peer presses",
        "rad",
        gt=0,
    )
    pressed_band: float = setting(
        0.03, "a peer presses when its V row reads within this of its margin", "m", ge=0
    )
    # a holding arm pushed off its goal keeps its bound up to release from it, so the pushing
    # peer can pass; 2·tolerance withdrew it early and both arms fled in turns
    release: float = setting(
        0.4, "goal distance (L2) beyond which a holding arm withdraws its bound", "rad", gt=0
    )
    release_ticks: int = setting(
        2, "commands between announcing a withdrawal and moving faster", ge=1
    )
    # an acceleration-limited arm braking into its goal moved faster than its new bound, and its
    # peers planned it at full speed for the rest of the episode (triple UR5, realistic
    # actuators, development seed 60: SR 80 -> 91 %); off by default: trusted again, a holding
    # peer is approached at full speed, which an arm that brakes slowly needs the actuator
    # stage's approach rows for (one collision in those 100 episodes without them)
    self_check: bool = setting(
        False, "withdraw and renew a bound this arm's own observed motion broke, as peers judge it"
    )
    # with certified margins, rows against a peer that announced a bound keep min(raised
    # epsilon, max(settled_epsilon, their model's δ at bound·t_safe)); 1 cm, the exact guard's
    # gap (0.05 m before the guard: a learned distance may read 3 cm at contact; 2 cm until
    # five-UR5 goal sets 1-2 cm apart were seen to end stuck)
    settled_epsilon: float = setting(
        0.01, "floor of the margin against a peer that announced a speed bound", "m", gt=0, le=1
    )

    def __post_init__(self) -> None:
        check_group(self, "hold")
        for name in ("tolerance", "pressed_tolerance"):
            if not self.release >= getattr(self, name):
                raise InvalidValueError(
                    "hold.release",
                    f"must be >= hold.{name} ({getattr(self, name)}) [rad]",
                    self.release,
                )


@dataclass(frozen=True)
class ExactGuardSettings:
    """The exact-geometry guard beside holding peers (``planning/stages/exact_guard.py``)."""

    gap: float = setting(
        0.01,
        "exact clearance kept to holding peers; threat distance when holding (0: off)",
        "m",
        ge=0,
        le=1,
    )
    # the learned values err by a few centimetres; a step moves the arm's points a few
    # centimetres at most
    near: float = setting(0.15, "only peers whose V now reads below this are checked", "m", gt=0)
    scales: tuple[float, ...] = setting(
        (1.0, 0.5, 0.25),
        "shares of a step tried in turn (none fits: the arm stays still)",
        gt=0,
        le=1,
    )

    def __post_init__(self) -> None:
        check_group(self, "exact_guard")


@dataclass(frozen=True)
class ContactSettings:
    """The contact guard (``planning/stages/contact_guard.py``).

    With the real geometry, each peer on its own: a step may not bring the arm closer to a peer
    already within ``clearance``, nor within ``clearance`` of one within ``clearance +
    approach``; a step that would is shortened or replaced by one up the real distance.
    """

    # 2 cm let a UR5 and a Panda closing at 2 cm per tick touch (mixed_four, seed 60,
    # scenario 70); 3 cm left it stuck there, 4 cm parts them
    clearance: float = setting(
        0.04,
        "real distance to a peer below which no step may close it (0: off)",
        "m",
        ge=0,
        le=1,
    )
    # a holding peer moves at most hold.bound·d̄: the exact guard's gap suffices against it, and
    # 4 cm kept arriving arms from goals beside settled ones (five UR5s, development seed 31:
    # 83 → 89 % SR)
    holding_clearance: float = setting(
        0.01,
        "the clearance against a peer that holds (announced a bound below full speed); at most "
        "clearance",
        "m",
        ge=0,
        le=1,
    )
    # two UR5s closing at full speed cover 3 cm in a tick: a gap just above the clearance
    # went to contact in two ticks (seven UR5s, tasks seed 78, gen_7arm_s78_049)
    approach: float = setting(
        0.04,
        "peers within clearance + this are watched: no step may end within clearance of them",
        "m",
        ge=0,
        le=1,
    )
    # the learned V can read 4 cm above the real distance near contact (UR5-Panda); 0.05 m
    # missed a peer at 1.7 cm whose V read 0.061 m
    value: float = setting(
        0.1, "only peers whose V now reads below this are checked", "m", gt=-1, le=1
    )
    probe: float = setting(
        0.01, "joint offset of the real distance's central differences", "rad", gt=0, le=0.2
    )
    scales: tuple[float, ...] = setting(
        (1.0, 0.5, 0.25),
        "shares of a step tried in turn (none fits: the step up the real distance, else stay)",
        gt=0,
        le=1,
    )

    def __post_init__(self) -> None:
        check_group(self, "contact")


@dataclass(frozen=True)
class ActuatorSettings:
    """Commands within the joint acceleration limits (``planning/stages/accel_limits.py``).

    Each command differs from the last by at most ``share`` of what each joint's acceleration
    limit (the robot description's ``facts.accel_limits``) reaches in one ``opt.tick``, V
    against each peer falls no faster than ``approach_rate`` times its gap above the margin, and
    the arm brakes when its rest pose would come within ``brake_clearance`` of a near peer
    (in the slow game, both arms holding, at most ``contact.holding_clearance``).
    """

    enabled: bool = setting(
        False, "keep each command within what the joints' acceleration limits reach in one tick"
    )
    share: float = setting(1.0, "share of the acceleration limits the commands may use", gt=0, le=1)
    # an arm closing at 2 cm of V per tick on a holding peer (1 cm margin) took four ticks to
    # brake and touched it (triple UR5, realistic actuators, development seed 60)
    approach_rate: float = setting(
        4.0,
        "V may fall at most this times its gap above the margin per second (0: off)",
        "1/s",
        ge=0,
    )
    # the learned V read 2 cm above the real distance near contact and a UR5 at 0.5 rad/s
    # closed 1.5 cm per tick while it braked (five UR5, realistic actuators, development
    # seed 60, scenario 32); in the slow game at most contact.holding_clearance: 4 cm stopped
    # arms short of goals beside settled peers (five UR5, development seeds 60, 67)
    brake_clearance: float = setting(
        0.04,
        "real distance the arm's braking path keeps to near peers (0: off); in the slow game "
        "(both arms hold, at the hold's speed) at most contact.holding_clearance",
        "m",
        ge=0,
        le=1,
    )
    brake_near: float = setting(
        0.15,
        "peers whose V now reads below this are near: checked for braking (and, with "
        "far_brake, none near: a fail-safe brakes)",
        "m",
        gt=-1,
        le=1,
    )

    # ended a 20 s fail-safe loop (dual UR5, seed 67, scenario 65) but cost the UR5-Kinova cell
    # five points (seed 67, realistic actuators: 85 against 90 %)
    far_brake: bool = setting(
        False, "a fail-safe with every peer's V at least brake_near brakes instead"
    )

    def __post_init__(self) -> None:
        check_group(self, "actuator")


@dataclass(frozen=True)
class SilentWatchSettings:
    """The silent-path watch (``planning/stages/silent_peers.py``).

    A peer that announces nothing is extrapolated ``lookahead`` along its observed joint
    velocity; when V(t_plan) at a point of that path is below ``clearance`` and more than
    ``approach`` below the current V, the step's target is up ∂V/∂q_own there instead of the
    goal. The V rows are unchanged.
    """

    lookahead: float = setting(
        2.0, "how far a silent peer's observed velocity is extrapolated (0: off)", "s", ge=0
    )
    clearance: float = setting(
        0.2, "V along a silent peer's path that the arm steps away from", "m", ge=0
    )
    approach: float = setting(
        0.02, "a predicted V this far below the current one is an approach", "m", ge=0
    )
    points: tuple[float, ...] = setting(
        (0.25, 0.5, 0.75, 1.0),
        "shares of lookahead at which the peer's path is evaluated",
        gt=0,
        le=1,
    )

    def __post_init__(self) -> None:
        check_group(self, "silent_watch")


@dataclass(frozen=True)
class EscapeSettings:
    """The stall escape (``planning/stages/stall_escape.py``).

    After ``stall_ticks`` plan() calls in which the goal error fell by less than
    ``stall_progress``·t_plan·ū while a V row was within ``stall_margin`` of ε, the arm follows
    a random direction tangent to the critical pair's level set of V for ``escape_ticks`` calls
    (doubled with every escape from the same trap, up to ``max_stretch`` times as long), then
    heads for the goal again; an arm held at its goal that long yields: it steps up V's gradient
    for ``yield_ticks`` calls.
    """

    enabled: bool = setting(True, "stall escape and yield at the goal (false: the paper's Opt)")
    stall_ticks: int = setting(
        12, "calls without progress against an active V row before an escape", ge=1
    )
    escape_ticks: int = setting(25, "calls of the first escape from a trap", ge=1)
    yield_ticks: int = setting(12, "calls an arm held at its goal steps up V's gradient", ge=1)
    max_stretch: int = setting(4, "longest escape, as a multiple of escape_ticks", ge=1)
    stall_progress: float = setting(
        0.1, "progress below this share of t_plan·ū per call is a stall", ge=0
    )
    stall_margin: float = setting(0.01, "a V row within this of ε is active", "m", ge=0)
    seed: int = setting(0, "seed of the escape directions (with the arm id)", ge=0)

    def __post_init__(self) -> None:
        check_group(self, "escape")
