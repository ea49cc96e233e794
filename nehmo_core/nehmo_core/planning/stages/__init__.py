"""What NeHMO adds to the paper's Opt, one mechanism per module, each a stage of the planner
(:mod:`nehmo_core.planning.opt.pipeline` defines the kinds) with its own settings and each off in
the ``paper`` preset:

=======================  ==================  ===================================================
stage (settings group)   kind                what it changes; what it keeps
=======================  ==================  ===================================================
``hold``                 announcer           announces a speed bound at the goal and keeps it;
(:mod:`.speed_bounds`)                       the V rows against every peer's worst case stay
``self_clearance``       row provider        adds self-collision damper rows; V rows stay
``silent_watch``         objective           steps out of a silent peer's path; V rows stay
(:mod:`.silent_peers`)
``escape``               objective           leaves a stall on the safe set; V rows stay
(:mod:`.stall_escape`)
``exact_guard``          command filter      shortens a step toward a holding peer's real
                                             geometry; never lengthens one
``contact``              command filter      within a few cm of a peer's real geometry: no step
(:mod:`.contact_guard`)                      closes the gap; a blocked one turns up the real
                                             distance (only where the V rows are broken)
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
    RowProvider,
    Stage,
)
from nehmo_core.planning.stages.contact_guard import ContactGuard
from nehmo_core.planning.stages.exact_guard import ExactGuard
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
    objectives: tuple[Objective, ...]
    filters: tuple[CommandFilter, ...]

    @property
    def all(self) -> tuple[Stage, ...]:
        """Every stage."""
        head: tuple[Stage, ...] = () if self.announcer is None else (self.announcer,)
        return (*head, *self.rows, *self.objectives, *self.filters)


def build_stages(host: Host) -> Staged:
    """The stages ``host.settings`` switch on, built for ``host``."""
    s = host.settings
    objectives: list[Objective] = []
    if s.silent_watch.lookahead > 0.0:  # before the escape: stepping aside wins over escaping
        objectives.append(SilentPeers(host))
    if s.escape.enabled:
        objectives.append(StallEscape(host))
    rows: tuple[RowProvider, ...] = ()
    if s.self_clearance.enabled:
        rows = (SelfClearance(host.robot, s.self_clearance),)
    filters: list[CommandFilter] = []
    if s.exact_guard.gap > 0.0:
        filters.append(ExactGuard(host))
    if s.contact.clearance > 0.0:  # last: it sees the command every other stage shaped
        filters.append(ContactGuard(host))
    return Staged(
        announcer=HoldAnnouncer(host) if s.hold.bound < FULL_SPEED else None,
        rows=rows,
        objectives=tuple(objectives),
        filters=tuple(filters),
    )
