"""Build one arm's planner from node parameters, with the planning model registry.

The node's ``model`` parameter is a value-model source list for
:mod:`nehmo_core.planning.models.registry` (the registry the batch runner uses too), so a ROS run
and a batch run of the same row use the very same pair models:

``shipped``    the shipped value functions of the cell's robot pairs (variant per planner kind:
               nehmo, nehmo_paper → bc+sym, nehmo_no_sym → bc, opt_deepreach → deepreach);
``synthetic``  random-weight stand-ins on the pair's learned distance, for plumbing tests and
               demos until trained models ship (V is the distance plus a small residual, not a
               reachability value);
otherwise      ``[KIND=]SOURCE`` items, comma-separated: a training run directory or a
               ``.safetensors`` file.

Naive and reckless planners take no model. This module imports no ROS package; it stays in
``nehmo_ros`` because it turns the node's parameters into a planner and names them in errors.
"""

from __future__ import annotations

import numpy as np

from nehmo_core.errors import InvalidValueError, NehmoError, UnknownNameError
from nehmo_core.planning.factory import DECENTRALIZED, make_planner
from nehmo_core.planning.models.registry import OPT_KINDS, model_registry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.interface import Planner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.model import Cell

__all__ = ["build_planner", "warm_up"]


def build_planner(
    kind: str,
    cell: Cell,
    arm_id: str,
    model: str,
    settings: PlannerSettings,
    allow_unmodelled: bool = False,
) -> Planner:
    """A planner of ``kind`` for ``arm_id``; raises naming the parameter on bad input.

    Peers in reach that no pair model covers are an error unless ``allow_unmodelled`` (they
    are then not constrained, and the node reports them).
    """
    if kind not in DECENTRALIZED:
        raise UnknownNameError("planner", kind, DECENTRALIZED)
    registry = model_registry(model)
    try:
        models = registry.models_for(kind, cell) if kind in OPT_KINDS else []
    except NehmoError as exc:
        raise NehmoError(f"parameter `model` ({model!r}): {exc}") from None
    except (KeyError, TypeError, ValueError, AttributeError) as exc:  # a malformed model card
        raise NehmoError(
            f"parameter `model` ({model!r}): malformed model file ({type(exc).__name__}: {exc})"
        ) from None
    if kind in OPT_KINDS and not models:
        raise InvalidValueError(
            "model", f"provides no pair value model for the arms of cell {cell.name!r}", model
        )
    planner = make_planner(kind, cell, arm_id, models, settings)
    if isinstance(planner, NehmoPlanner) and planner.peers_unmodelled and not allow_unmodelled:
        raise InvalidValueError(
            "model",
            f"covers no pair of arm {arm_id!r} with its peers in reach "
            f"{list(planner.peers_unmodelled)}; those peers would not be constrained "
            "(set allow_unmodelled:=true to accept that)",
            model,
        )
    return planner


def warm_up(planner: Planner, cell: Cell, arm_id: str, calls: int = 3) -> None:
    """Solve a few times at the joint zeros of every arm (arms overlapping: the constrained
    path), so that first-call costs (buffers, caches) do not fall on the first real ticks."""
    q = {a.arm_id: np.clip(np.zeros(a.robot.dof), a.robot.lower, a.robot.upper) for a in cell.arms}
    peers = {a: v for a, v in q.items() if a != arm_id}
    goal = q[arm_id] + 0.3
    for _ in range(calls):
        planner.plan(q[arm_id], peers, goal)
    planner.fail_safe(q[arm_id], peers)
    planner.reset()
