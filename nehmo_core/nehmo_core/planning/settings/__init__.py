"""Settings of the NeHMO planner in groups: ``opt``, ``margins``, ``solver``, ``fail_safe`` and
one group per stage beyond the paper (``hold``, ``exact_guard``, ``silent_watch``,
``self_clearance``, ``escape``). See :class:`PlannerSettings`."""

from nehmo_core.planning.settings.groups import (
    BACKENDS,
    SOLVERS,
    FailSafeSettings,
    MarginSettings,
    OptSettings,
    SolverSettings,
)
from nehmo_core.planning.settings.limits import SelfClearanceSettings
from nehmo_core.planning.settings.planner import (
    PAPER_OPT,
    PRESETS,
    REMOVED,
    RENAMED,
    PlannerSettings,
    parse_assignments,
)
from nehmo_core.planning.settings.spec import Rule
from nehmo_core.planning.settings.stage_groups import (
    EscapeSettings,
    ExactGuardSettings,
    HoldSettings,
    SilentWatchSettings,
)

__all__ = [
    "BACKENDS",
    "PAPER_OPT",
    "PRESETS",
    "REMOVED",
    "RENAMED",
    "SOLVERS",
    "EscapeSettings",
    "ExactGuardSettings",
    "FailSafeSettings",
    "HoldSettings",
    "MarginSettings",
    "OptSettings",
    "PlannerSettings",
    "Rule",
    "SelfClearanceSettings",
    "SilentWatchSettings",
    "SolverSettings",
    "parse_assignments",
]
