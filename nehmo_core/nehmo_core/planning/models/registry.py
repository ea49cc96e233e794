"""The pair value-model registry: which trained models back each Opt planner kind.

Used by the batch runner (:mod:`nehmo_core.eval.batch`), the planner node and the benches, so
every one of them loads the very same models for a row. Value models come from *sources*,
given as ``[KIND=]SOURCE``:

* ``SOURCE`` is a shipped pair name (``ur5_ur5``, ``ur5_kinova``, ``kinova_ur5``: the variant
  is the row's, per :data:`OPT_KINDS`), a training run directory (its
  model, or its latest checkpoint) or a ``.safetensors`` file, or ``synthetic``: random-weight
  stand-ins from :mod:`nehmo_core.planning.models.synthetic` (for smoke runs only; their numbers
  mean nothing).
* ``KIND=`` limits a source to one planner kind (``nehmo_no_sym=runs/ur5_ur5_bc``); a source
  without it serves every Opt kind whose variant it matches.
* Without a source for a kind, the shipped models of the cell's robot pairs are used
  (:data:`SHIPPED_PAIRS`): in the UR5-Kinova cell, ``ur5_kinova`` for the UR5 and
  ``kinova_ur5`` (the Kinova-controls game) for the Kinova; for two UR5s, ``ur5_ur5`` (bases
  0.6 m apart) and, where the row's variant is shipped for it, ``ur5_ur5_diag`` (0.849 m, the
  diagonal neighbours of the five-UR5 cell) and ``ur5_ur5_opposite`` (1.2 m, the outer arms
  facing each other across the centre arm in the three- and five-UR5 cells). Each peer uses the
  model whose base distance matches (:func:`~nehmo_core.planning.models.pair_frame.match_pair`).
  A UR5 pair at any other base distance within its range uses ``ur5_ur5_any``, the value
  function conditioned on the base distance (loaded only when some pair of the cell needs it).
  A UR5 and a Kinova at another base distance likewise use ``ur5_kinova_any`` (the UR5's side)
  and ``kinova_ur5_any`` (the Kinova's side) once those are trained and in ``models/``
  (:data:`~nehmo_core.hjr.model_files.OPTIONAL_VALUE_FUNCTIONS`); until then such a pair is
  reported as unmodelled, as any pair no model fits.

"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import casadi as ca

from nehmo_core.errors import InvalidValueError, ModelFileError, NehmoError
from nehmo_core.hjr.model_files import (
    OPTIONAL_VALUE_FUNCTIONS,
    SHIPPED_VALUE_FUNCTIONS,
    load_value_function,
)
from nehmo_core.planning.models.pair_frame import (
    ModelGeometry,
    inverse_pose,
    match_pair,
    pose_from_matrix,
    relative_pose,
)
from nehmo_core.planning.models.sources import (
    OPT_KINDS,
    SHIPPED,
    SYNTHETIC,
    ValueModelSource,
    model_sources,
    parse_value_models,
    snapshot_value_models,
)
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.robots.model import Cell
from nehmo_core.robots.registry import pairs_by_robots, synthetic_pairs

__all__ = [
    "OPT_KINDS",
    "SHIPPED",
    "SHIPPED_PAIRS",
    "SYNTHETIC",
    "ModelRegistry",
    "ValueModelSource",
    "model_registry",
    "model_sources",
    "pair_geometry",
    "parse_value_models",
    "snapshot_value_models",
    "swapped_pair_model",
]

_SYNTHETIC_PAIRS = synthetic_pairs()
"""(controlled robot, other robot) → pair with a synthetic stand-in (a learned-distance cell)."""
SHIPPED_PAIRS: dict[tuple[str, str], tuple[str, ...]] = pairs_by_robots()
"""(controlled robot, other robot) → the shipped value functions of that game, one per base
distance (``*_any``: any distance in its range, after the fixed ones), as the robot registry
(:data:`~nehmo_core.robots.registry.ARM_PAIRS`) lists them. The first is required for every Opt
kind; the others serve the kinds whose variant they ship, when their files are present (a peer
at their distance is otherwise reported as unconstrained)."""


def pair_variant(source: str, variant: str) -> str:
    """The variant a kind of ``variant`` uses for the named pair ``source``: ``variant`` itself,
    except that a pair whose robots have no exact mirror map ships ``bc`` alone (``nehmo pair
    build`` decides it on the exact geometry), which the ``bc+sym`` kinds then use."""
    names = (*SHIPPED_VALUE_FUNCTIONS, *OPTIONAL_VALUE_FUNCTIONS)
    if variant != "bc+sym" or source not in names:
        return variant
    declared = (
        *SHIPPED_VALUE_FUNCTIONS.get(source, ()),
        *OPTIONAL_VALUE_FUNCTIONS.get(source, ()),
    )
    return "bc" if set(declared) == {"bc"} else variant


def robot_pairs(cell: Cell) -> list[tuple[str, str]]:
    """Ordered (own robot, peer robot) pairs of the cell's arms, without repeats."""
    pairs = []
    for own in cell.arms:
        for peer in cell.arms:
            key = (own.robot.name, peer.robot.name)
            if own.arm_id != peer.arm_id and key not in pairs:
                pairs.append(key)
    return pairs


def swapped_pair_model(model: PairValueModel, name: str) -> PairValueModel:
    """``model`` seen from its second robot: ``V'(τ, q², q¹) = V(τ, q¹, q²)``.

    The roles of the players are swapped too (the controlled arm becomes the disturbance), so
    this is NOT the value function of the swapped game. It serves synthetic stand-ins, whose
    ``V`` is the symmetric distance plus a small residual; trained models of the swapped game
    are separate (``kinova_ur5``).
    """
    n1, n2 = model.n1, model.n2
    tau = ca.MX.sym("tau")
    x = ca.MX.sym("x", n1 + n2)
    original = ca.vertcat(x[n2:], x[:n2])
    v = model.value(tau, original)
    v2, g = model.value_grad(tau, original)
    grad = ca.vertcat(g[n1:], g[:n1])
    return PairValueModel(
        name=name,
        robot1=model.robot2,
        robot2=model.robot1,
        base2=inverse_pose(model.base2),
        n1=n2,
        n2=n1,
        horizon=model.horizon,
        value=ca.Function(name, [tau, x], [v], ["tau", "x"], ["v"]),
        value_grad=ca.Function(f"{name}_grad", [tau, x], [v2, grad], ["tau", "x"], ["v", "grad"]),
        backend=model.backend,
    )


class ModelRegistry:
    """Builds and caches the pair value models of each Opt kind (one registry per process)."""

    def __init__(self, sources: Sequence[ValueModelSource] = (), backend: str = "auto") -> None:
        for s in sources:
            if s.kind is not None and s.kind not in OPT_KINDS:
                raise InvalidValueError("kind", f"must be one of {sorted(OPT_KINDS)}", s.kind)
        self.sources = tuple(sources)
        self.backend = backend
        self._cache: dict[tuple[str, str, tuple[tuple[str, str], ...]], list[PairValueModel]] = {}
        self.described: dict[str, list[dict[str, Any]]] = {}

    def sources_for(self, kind: str, cell: Cell) -> list[str]:
        """The sources serving ``kind`` on ``cell`` (explicit ones first, else the shipped)."""
        scoped = [s.source for s in self.sources if s.kind == kind]
        if scoped:
            return scoped
        general = [s.source for s in self.sources if s.kind is None]
        if general:
            return general
        variant = OPT_KINDS[kind]
        out: list[str] = []
        for pair in robot_pairs(cell):
            names = SHIPPED_PAIRS.get(pair, ())
            out.extend(
                name
                for i, name in enumerate(names)
                if i == 0
                or (
                    pair_variant(name, variant) in SHIPPED_VALUE_FUNCTIONS.get(name, ())
                    and _cell_uses(name, cell)
                )
            )
        return out

    def models_for(self, kind: str, cell: Cell) -> list[PairValueModel]:
        """Every pair model the ``kind`` planners of ``cell`` use."""
        if kind not in OPT_KINDS:
            raise InvalidValueError("kind", f"must be one of {sorted(OPT_KINDS)}", kind)
        out: list[PairValueModel] = []
        pairs = tuple(robot_pairs(cell))
        for source in self.sources_for(kind, cell):
            key = (kind, source, pairs)
            if key not in self._cache:
                self._cache[key] = self._load(kind, source, pairs)
            out.extend(self._cache[key])
        self.described[kind] = [
            {"name": m.name, "robots": [m.robot1, m.robot2], "backend": m.backend} for m in out
        ]
        return out

    def _load(
        self, kind: str, source: str, pairs: tuple[tuple[str, str], ...]
    ) -> list[PairValueModel]:
        variant = OPT_KINDS[kind]
        if source == SYNTHETIC:
            return self._synthetic(variant, pairs)
        variant = pair_variant(source, variant)
        slug = variant.replace("+", "_")
        if source in SHIPPED_VALUE_FUNCTIONS or source in OPTIONAL_VALUE_FUNCTIONS:
            try:
                vf = load_value_function(source, variant=variant)
            except (ModelFileError, NehmoError, FileNotFoundError) as exc:
                raise ModelFileError(
                    f"row {kind!r} needs the shipped {variant} value function of {source!r}, "
                    f"which is not available ({exc}); pass --value-model {kind}=PATH "
                    f"(a run directory) or --value-model synthetic for a smoke run"
                ) from None
        else:
            vf = load_value_function(Path(source))
            if vf.variant != variant:
                raise InvalidValueError(
                    "value model",
                    f"for row {kind!r} must be a {variant} model ({Path(source).name} is "
                    f"{vf.variant}); scope it with {_kind_for(vf.variant)}=PATH",
                    source,
                )
        name = f"{kind}_{Path(source).name}_{slug}".replace(".", "_").replace("-", "_")
        return [PairValueModel.from_value_function(vf, name, backend=self.backend)]

    def _synthetic(self, variant: str, pairs: tuple[tuple[str, str], ...]) -> list[PairValueModel]:
        from nehmo_core.planning.models.synthetic import random_value_function

        slug = variant.replace("+", "_")
        made: dict[tuple[str, str], PairValueModel] = {}
        for pair in pairs:
            forward = _SYNTHETIC_PAIRS.get(pair)
            backward = _SYNTHETIC_PAIRS.get((pair[1], pair[0]))
            if forward is not None:
                vf = random_value_function(forward, variant)
                made[pair] = PairValueModel.from_value_function(
                    vf, f"synthetic_{forward}_{slug}", backend=self.backend
                )
            elif backward is not None:
                if (pair[1], pair[0]) not in made:
                    vf = random_value_function(backward, variant)
                    made[(pair[1], pair[0])] = PairValueModel.from_value_function(
                        vf, f"synthetic_{backward}_{slug}", backend=self.backend
                    )
                made[pair] = swapped_pair_model(
                    made[(pair[1], pair[0])], f"synthetic_{backward}_{slug}_swapped"
                )
        return [made[p] for p in pairs if p in made]


def pair_geometry(pair: str) -> ModelGeometry:
    """``(robot 1, robot 2, base of arm 2 in arm 1's frame[, base-distance range])`` of a
    named arm pair (or a swapped one, ``kinova_ur5``, ``kinova_ur5_any``): what
    :func:`~nehmo_core.planning.models.pair_frame.match_pair` takes per model."""
    from nehmo_core.geometry.distance_data import (
        CONDITIONED_PAIRS,
        SWAPPED_PAIRS,
        system_pair_cell,
    )
    from nehmo_core.robots.registry import pair_base_range

    model_cell, a, b = system_pair_cell(pair)
    arm1, arm2 = model_cell.arm(a), model_cell.arm(b)
    base2 = pose_from_matrix(relative_pose(arm1.base, arm2.base))
    if SWAPPED_PAIRS.get(pair, pair) in CONDITIONED_PAIRS:
        return arm1.robot.name, arm2.robot.name, base2, pair_base_range(pair)
    return arm1.robot.name, arm2.robot.name, base2


def _cell_uses(pair: str, cell: Cell) -> bool:
    """Whether some (own, peer) pair of ``cell`` maps onto the shipped pair model ``pair`` and
    onto no shipped model listed before it (those take precedence)."""
    names = next(n for n in SHIPPED_PAIRS.values() if pair in n)
    earlier = [pair_geometry(n) for n in names[: names.index(pair)]]
    model = [pair_geometry(pair)]
    return any(
        match_pair(own, peer, model) is not None and match_pair(own, peer, earlier) is None
        for own in cell.arms
        for peer in cell.arms
        if own.arm_id != peer.arm_id and (own.robot.name, peer.robot.name) == model[0][:2]
    )


def _kind_for(variant: str) -> str:
    return next((k for k, v in OPT_KINDS.items() if v == variant), "KIND")


def model_registry(model: str) -> ModelRegistry:
    """The registry for a ``model`` text (``shipped``, ``synthetic`` or sources)."""
    return ModelRegistry(model_sources(model))
