"""Build any planner of the comparison by name (the ablation rows and the baselines).

=================  =====================================================================
``nehmo``          Opt with the ``bc+sym`` value model (the paper's NeHMO), plus the
                   self-clearance rows (:mod:`~nehmo_core.planning.stages.self_clearance`) and
                   the stall escape (:class:`~nehmo_core.planning.nehmo.NehmoPlanner`)
``nehmo_paper``    NeHMO exactly as the paper's Opt: no self-clearance rows, no stall escape
``nehmo_no_sym``   Opt with the ``bc`` value model (NeHMO w/o Sym)
``opt_deepreach``  Opt with the ``deepreach`` value model (Opt + DeepReach)
``nehmo_wrap``     NeHMO whose goal cost wraps continuous joints (the paper does not)
``naive``          straight to the goal, clamped (ignores everyone)
``reckless``       the naive law for one arm the others must defend against
``chomp``          centralized CHOMP, tracked per arm (:func:`centralized_trackers`)
``ompl``           centralized RRT-Connect, tracked per arm (:func:`centralized_trackers`)
=================  =====================================================================

The Opt rows differ only in the pair value models passed in (``nehmo_wrap`` also in its goal
cost, ``nehmo_paper`` in leaving out the self-clearance rows and the stall escape); which
trained model backs which row is the caller's choice (the model registry lives with the trained
weights).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.planning.baselines.chomp import ChompSettings, plan_chomp
from nehmo_core.planning.baselines.naive import NaivePlanner, TrajectoryTracker, retime
from nehmo_core.planning.baselines.ompl import OmplSettings, plan_rrt_connect
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.interface import Planner
from nehmo_core.planning.settings import PAPER_OPT, PlannerSettings
from nehmo_core.robots.model import Cell

__all__ = ["CENTRALIZED", "DECENTRALIZED", "centralized_trackers", "make_planner"]

OPT = ("nehmo", "nehmo_paper", "nehmo_no_sym", "opt_deepreach", "nehmo_wrap")
DECENTRALIZED = (*OPT, "naive", "reckless")
CENTRALIZED = ("chomp", "ompl")


def make_planner(
    kind: str,
    cell: Cell,
    arm_id: str,
    models: Sequence[PairValueModel] = (),
    settings: PlannerSettings | None = None,
) -> Planner:
    """A per-arm planner of kind ``kind`` (one of :data:`DECENTRALIZED`)."""
    if kind in OPT:
        if not models and len(cell.arms) > 1:  # an arm alone has no pair to model
            raise InvalidValueError("models", f"must hold at least one pair model for {kind!r}", [])
        if kind == "nehmo_wrap":
            settings = (settings or PlannerSettings()).override({"opt.wrap_goal": True})
        if kind == "nehmo_paper":
            settings = (settings or PlannerSettings()).override(PAPER_OPT)
        return NehmoPlanner(cell, arm_id, models, settings)
    if kind in ("naive", "reckless"):
        return NaivePlanner(cell, arm_id, settings, reckless=kind == "reckless")
    if kind in CENTRALIZED:
        raise InvalidValueError(
            "kind", "is centralized: plan once with centralized_trackers()", kind
        )
    raise UnknownNameError("planner", kind, DECENTRALIZED + CENTRALIZED)


def centralized_trackers(
    kind: str,
    cell: Cell,
    start: Mapping[str, np.ndarray],
    goal: Mapping[str, np.ndarray],
    period: float,
    settings: PlannerSettings | None = None,
    chomp: ChompSettings | None = None,
    ompl: OmplSettings | None = None,
) -> tuple[dict[str, Planner], dict[str, object]]:
    """Plan all arms at once with ``chomp`` or ``ompl``; per-arm trackers and a summary.

    The trajectory is retimed so that no joint exceeds ``ū``; ``summary`` holds the plan time
    [s], success (OMPL solved / CHOMP collision-free on the exact geometry) and iterations.
    """
    s = settings or PlannerSettings()
    if kind == "chomp":
        result = plan_chomp(cell, start, goal, chomp)
        waypoints, plan_time = result.waypoints, result.plan_time
        summary: dict[str, object] = {
            "plan_time": plan_time,
            "success": result.collision_free,
            "iterations": result.iterations,
        }
    elif kind == "ompl":
        r = plan_rrt_connect(cell, start, goal, ompl)
        waypoints, plan_time = r.waypoints, r.plan_time
        summary = {"plan_time": plan_time, "success": r.solved, "checks": r.checks}
        if not r.solved:  # hold still: the planner found nothing
            waypoints = {
                a.arm_id: np.asarray(start[a.arm_id])[None, :].repeat(2, 0) for a in cell.arms
            }
    else:
        raise UnknownNameError("centralized planner", kind, CENTRALIZED)
    trajectory = retime(waypoints, s.opt.u_max)
    trackers: dict[str, Planner] = {
        a.arm_id: TrajectoryTracker(cell, trajectory, a.arm_id, period, s, plan_time)
        for a in cell.arms
    }
    return trackers, summary
