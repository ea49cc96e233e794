"""The planners of an evaluation row: one per arm, Opt kinds backed by the model registry.

Value models come from :class:`~nehmo_core.planning.models.registry.ModelRegistry`. A row fails to
build, naming the missing pair, when an Opt planner has a peer in reach that no model covers:
such a peer would not be constrained at all.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

from nehmo_core.errors import NehmoError
from nehmo_core.eval.setups import is_centralized
from nehmo_core.hjr.model_files import SHIPPED_VALUE_FUNCTIONS
from nehmo_core.planning.factory import centralized_trackers, make_planner
from nehmo_core.planning.models.registry import OPT_KINDS, SHIPPED_PAIRS, ModelRegistry
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.opt.interface import Planner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots.model import Cell
from nehmo_core.sim.scenarios import Scenario

__all__ = ["build_planners", "unmodelled_peers"]


def unmodelled_peers(planners: Mapping[str, Planner]) -> dict[str, list[str]]:
    """Peers in reach that each Opt planner does not constrain (no pair model fits)."""
    return {a: list(p.peers_unmodelled) for a, p in planners.items() if p.peers_unmodelled}


def _missing_models(
    cell: Cell,
    arm_id: str,
    kind: str,
    peers: Sequence[str],
    models: Sequence[PairValueModel],
    registry: ModelRegistry,
) -> NehmoError:
    """The error for an Opt planner whose peers ``peers`` no loaded pair model covers."""
    own = cell.arm(arm_id).robot.name
    need = sorted({(own, cell.arm(p).robot.name) for p in peers})
    loaded = [f"{m.name} ({m.robot1}, {m.robot2})" for m in models]
    shipped = [
        f"{name} {pair}"
        for pair, names in SHIPPED_PAIRS.items()
        for name in names
        if name in SHIPPED_VALUE_FUNCTIONS  # not an optional model that is not trained yet
    ]
    base = cell.arm(arm_id).base.xyz
    where = []
    for p in peers:
        x, y, z = (b - a for a, b in zip(base, cell.arm(p).base.xyz, strict=True))
        where.append(f"{p} ({cell.arm(p).robot.name}) {math.hypot(x, y):.2f} m away, {z:+.2f} m up")
    return NehmoError(
        f"arm {arm_id!r} ({kind}) has peers {list(peers)} that no value model covers "
        f"({'; '.join(where)}); it needs pair models {need} (robot1 = the planning arm) whose "
        "base range holds that distance at an equal mounting height. Sources used: "
        f"{registry.sources_for(kind, cell)}; models loaded: {loaded or 'none'}; shipped pair "
        f"models: {', '.join(shipped)}"
    )


def build_planners(
    cell: Cell,
    kinds: Mapping[str, str],
    scenario: Scenario,
    period: float,
    registry: ModelRegistry,
    settings: PlannerSettings | None = None,
    cache: dict[str, Planner] | None = None,
    allow_unmodelled: bool = False,
) -> dict[str, Planner]:
    """One planner per arm for a row (``kinds``); centralized rows plan ``scenario`` now.

    ``cache`` (arm id → planner) reuses decentralized planners across episodes of a row. An Opt
    planner with a peer in reach that no model covers raises, unless ``allow_unmodelled``
    (see :func:`unmodelled_peers` to report them).
    """
    if is_centralized(kinds):
        kind = next(iter(kinds.values()))
        trackers, _ = centralized_trackers(
            kind, cell, scenario.start, scenario.goal, period, settings
        )
        return trackers
    if cache is not None and set(cache) == set(cell.arm_ids):
        return dict(cache)
    out: dict[str, Planner] = {}
    settings = (settings or PlannerSettings()).override(
        {"opt.tick": period}
    )  # plan() runs once a period
    for arm_id, kind in kinds.items():
        models = registry.models_for(kind, cell) if kind in OPT_KINDS else []
        if kind in OPT_KINDS and not models and len(cell.arms) > 1:  # alone: nothing to model
            peers = tuple(a for a in cell.arm_ids if a != arm_id)
            raise _missing_models(cell, arm_id, kind, peers, models, registry)
        planner = make_planner(kind, cell, arm_id, models, settings)
        if planner.peers_unmodelled and not allow_unmodelled:
            raise _missing_models(cell, arm_id, kind, planner.peers_unmodelled, models, registry)
        out[arm_id] = planner
    if cache is not None:
        cache.clear()
        cache.update(out)
    return out
