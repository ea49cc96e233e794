"""What NeHMO adds to the paper's Opt, one mechanism per module, each a stage of the planner
(:mod:`nehmo_core.planning.opt.pipeline` defines the kinds) with its own settings and each off in
the ``paper`` preset:

=======================  ==================  ===================================================
stage (settings group)   kind                what it changes; what it keeps
=======================  ==================  ===================================================
``hold``                 announcer           announces a speed bound at the goal and keeps it;
(:mod:`.speed_bounds`)                       the V rows against every peer's worst case stay
``self_clearance``       row provider and    adds self-collision damper rows; checks the step's
                         command filter      end with the exact geometry; V rows stay
``silent_watch``         objective           steps out of a silent peer's path; V rows stay
(:mod:`.silent_peers`)
``escape``               objective           leaves a stall on the safe set; V rows stay
(:mod:`.stall_escape`)
``exact_guard``          command filter      shortens a step toward a holding peer's real
                                             geometry; never lengthens one
``actuator``             row provider, peer  each command within what the joints' acceleration
(:mod:`.accel_limits`)   rows and command    limits reach in one tick, and closing on a peer
                         filter              no faster than the gap allows; V rows stay
``contact``              command filter      within a few cm of a peer's real geometry: no step
(:mod:`.contact_guard`)                      closes the gap; a blocked one turns up the real
                                             distance (only where the V rows are broken)
``joint_limits``         row provider and    no joint driven past its limit (rows in Opt; first
(:mod:`.joint_limits`)   command filter      filter: the others check the step the arm takes);
                                             V rows stay
=======================  ==================  ===================================================

:func:`build_stages` makes the stages a planner's settings switch on.
"""

from __future__ import annotations

from dataclasses import dataclass

from nehmo_core.planning.opt.peer_bounds import FULL_SPEED
from nehmo_core.planning.opt.pipeline import (
    Announcer,
    CommandFilter,
    Host,
    Objective,
    PeerRowProvider,
    RowProvider,
    Stage,
)
from nehmo_core.planning.stages.accel_limits import AccelLimits
from nehmo_core.planning.stages.contact_guard import ContactGuard
from nehmo_core.planning.stages.exact_guard import ExactGuard
from nehmo_core.planning.stages.joint_limits import JointLimits
from nehmo_core.planning.stages.self_clearance import SelfClearance
from nehmo_core.planning.stages.silent_peers import SilentPeers
from nehmo_core.planning.stages.speed_bounds import HoldAnnouncer
from nehmo_core.planning.stages.stall_escape import StallEscape

__all__ = ["Staged", "build_stages"]


@dataclass(frozen=True)
class Staged:
    """A planner's stages by kind (objectives in priority order: the first target wins)."""

    announcer: Announcer | None
    rows: tuple[RowProvider, ...]
    peer_rows: tuple[PeerRowProvider, ...]
    objectives: tuple[Objective, ...]
    filters: tuple[CommandFilter, ...]

    @property
    def all(self) -> tuple[Stage, ...]:
        """Every stage."""
        head: tuple[Stage, ...] = () if self.announcer is None else (self.announcer,)
        # a stage of two kinds (actuator: rows and a filter) counts once
        kinds = (*head, *self.rows, *self.peer_rows, *self.objectives, *self.filters)
        every = {id(s): s for s in kinds}
        return tuple(every.values())


def build_stages(host: Host) -> Staged:
    """The stages ``host.settings`` switch on, built for ``host``."""
    s = host.settings
    objectives: list[Objective] = []
    if s.silent_watch.lookahead > 0.0:  # before the escape: stepping aside wins over escaping
        objectives.append(SilentPeers(host))
    if s.escape.enabled:
        objectives.append(StallEscape(host))
    rows: list[RowProvider] = []
    joint_limits = JointLimits(host) if s.joint_limits.enabled else None
    if joint_limits is not None:
        rows.append(joint_limits)
    self_clearance = (
        SelfClearance(host.robot, s.self_clearance, host) if s.self_clearance.enabled else None
    )
    if self_clearance is not None:
        rows.append(self_clearance)
    accel = AccelLimits(host) if s.actuator.enabled and host.robot.facts.accel_limits else None
    if accel is not None:
        rows.append(accel)
    filters: list[CommandFilter] = []
    if joint_limits is not None:  # first: every later filter checks the step the arm takes
        filters.append(joint_limits)
    if s.exact_guard.gap > 0.0:
        filters.append(ExactGuard(host))
    if s.contact.clearance > 0.0:  # it sees the command every stage before it shaped
        filters.append(ContactGuard(host))
    if self_clearance is not None and s.self_clearance.check > 0.0:  # after every step change
        filters.append(self_clearance)
    if accel is not None:  # last: what is sent must be reachable
        filters.append(accel)
    return Staged(
        announcer=HoldAnnouncer(host) if s.hold.bound < FULL_SPEED else None,
        rows=tuple(rows),
        peer_rows=(accel,) if accel is not None and s.actuator.approach_rate > 0 else (),
        objectives=tuple(objectives),
        filters=tuple(filters),
    )
