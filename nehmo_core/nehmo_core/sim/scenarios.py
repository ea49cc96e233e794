"""Start/goal sampling per the paper's evaluation protocol, in this project's joint zeros.

The authors sample UR5 joints in their model's zeros; ``example-robot-data``'s UR5 differs by
−π/2 on shoulder_lift (q₂) and wrist_1 (q₄), so those two ranges are shifted here.

Scenario sets (:class:`ScenarioSet`) are numbered, seeded draws saved as JSON files
(:func:`save_scenario_set` / :func:`load_scenario_set`: cell, start and goal per arm); a filter
keeps only some candidates (the UR5-Kinova challenging set keeps those where the naive planner
collides, see :mod:`nehmo_core.eval.scenario_sets`).
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.loader import load_cell
from nehmo_core.robots.model import Cell, RobotModel, wrap_angle

_HALF_PI = np.pi / 2
SAMPLING_RANGES: dict[str, np.ndarray] = {
    # (dof, 2) [rad]: low, high per joint.
    "ur5": np.array(
        [
            [-5.0, -1.5],
            [-1.0 - _HALF_PI, 0.5 - _HALF_PI],
            [1.0, 2.0],
            [-0.2 - _HALF_PI, 0.8 - _HALF_PI],
            [-2.5, -0.5],
            [-1e-4, 0.0],
        ]
    ),
}


def sample_configuration(robot: RobotModel, rng: np.random.Generator) -> np.ndarray:
    """One joint vector [rad]: the protocol's box for the UR5, the joint limits otherwise."""
    if robot.name in SAMPLING_RANGES:
        box = SAMPLING_RANGES[robot.name]
        q = rng.uniform(box[:, 0], box[:, 1])
    else:
        lo = np.maximum(robot.lower, -np.pi)
        hi = np.minimum(robot.upper, np.pi)
        q = rng.uniform(lo, hi)
    return robot.wrap(q)


@dataclass(frozen=True)
class Scenario:
    """Start and goal joint vectors per arm id."""

    start: Mapping[str, np.ndarray]
    goal: Mapping[str, np.ndarray]


def _collision_free(world: CellWorld, q: Mapping[str, np.ndarray]) -> bool:
    world.set_configuration(q)
    return not world.in_collision()


def sample_scenario(
    cell: Cell,
    rng: np.random.Generator,
    world: CellWorld | None = None,
    start_tries: int = 100,
    goal_tries: int = 10,
) -> Scenario:
    """Collision-free start and goal configurations of every arm (authors' retry counts)."""
    own = world is None
    w = world if world is not None else CellWorld(cell)
    try:
        start = goal = None
        for _ in range(start_tries):
            cand = {a.arm_id: sample_configuration(a.robot, rng) for a in cell.arms}
            if _collision_free(w, cand):
                start = cand
                break
        for _ in range(goal_tries if start is not None else 0):
            cand = {a.arm_id: sample_configuration(a.robot, rng) for a in cell.arms}
            if _collision_free(w, cand):
                goal = cand
                break
        if start is None or goal is None:
            raise NehmoError(f"no collision-free start/goal found for cell {cell.name!r}")
        return Scenario(start, goal)
    finally:
        if own:
            w.close()


def goal_error(q: np.ndarray, goal: np.ndarray, robot: RobotModel) -> np.ndarray:
    """Per-joint error [rad], wrapped on continuous joints."""
    e = np.asarray(q, dtype=np.float64) - np.asarray(goal, dtype=np.float64)
    c = robot.continuous
    e[c] = wrap_angle(e[c])
    return e


# ------------------------------------------------------------------------------------------------
# Scenario sets: seeded, saved as JSON files (cell, start and goal per arm).

SCENARIO_FORMAT = "nehmo-scenarios"
SCENARIO_FORMAT_VERSION = 1


class ScenarioFileError(NehmoError):
    """A scenario file that is missing, not JSON, or does not fit its cell."""


@dataclass(frozen=True)
class ScenarioSet:
    """Numbered scenarios of one cell, drawn from one seed.

    Scenario ``index`` is drawn by :func:`sample_scenario` from
    ``np.random.default_rng([seed, index])``, so any scenario can be regenerated on its own.
    A filtered set (``accept`` in :func:`generate_scenario_set`) keeps the first candidates that
    pass the filter; ``indices`` are then the candidates' numbers. ``meta`` is free-form JSON
    (e.g. the evaluation setup and the filter's name).
    """

    cell: str
    seed: int
    indices: tuple[int, ...]
    scenarios: tuple[Scenario, ...]
    candidates: int = 0  # candidates drawn to fill the set (= len(scenarios) when unfiltered)
    meta: Mapping[str, Any] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.scenarios)

    def head(self, count: int) -> ScenarioSet:
        """The first ``count`` scenarios."""
        if not 0 <= count <= len(self):
            raise InvalidValueError("count", f"must be in [0, {len(self)}]", count)
        return replace(self, indices=self.indices[:count], scenarios=self.scenarios[:count])


def scenario_rng(seed: int, index: int) -> np.random.Generator:
    """The generator of scenario ``index`` of the set with ``seed``."""
    return np.random.default_rng([int(seed), int(index)])


def generate_scenario_set(
    cell: Cell,
    seed: int,
    count: int,
    accept: Callable[[Scenario], bool] | None = None,
    max_candidates: int | None = None,
    meta: Mapping[str, Any] | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> ScenarioSet:
    """``count`` scenarios of ``cell``; with ``accept``, the first ``count`` candidates it keeps.

    ``max_candidates`` (default ``10·count``; the authors drew 500 for 100 challenging ones)
    bounds the search; running out raises :class:`NehmoError`. ``progress(kept, drawn)`` is
    called after every candidate.
    """
    if count < 1:
        raise InvalidValueError("count", "must be >= 1", count)
    limit = max_candidates if max_candidates is not None else 10 * count
    if limit < count:
        raise InvalidValueError("max_candidates", f"must be >= count ({count})", limit)
    kept: list[Scenario] = []
    indices: list[int] = []
    index = 0
    with CellWorld(cell) as world:
        while len(kept) < count and index < limit:
            scenario = sample_scenario(cell, scenario_rng(seed, index), world)
            if accept is None or accept(scenario):
                kept.append(scenario)
                indices.append(index)
            index += 1
            if progress is not None:
                progress(len(kept), index)
    if len(kept) < count:
        raise NehmoError(
            f"only {len(kept)} of {count} scenarios of cell {cell.name!r} passed the filter "
            f"in {limit} candidates (seed {seed}); raise max_candidates"
        )
    return ScenarioSet(cell.name, int(seed), tuple(indices), tuple(kept), index, dict(meta or {}))


def scenario_set_to_dict(scenarios: ScenarioSet, cell: Cell) -> dict[str, Any]:
    """The JSON form of a scenario set (joint vectors as lists [rad], arms in cell order)."""
    return {
        "format": SCENARIO_FORMAT,
        "version": SCENARIO_FORMAT_VERSION,
        "cell": scenarios.cell,
        "seed": scenarios.seed,
        "candidates": scenarios.candidates,
        "arms": {a.arm_id: a.robot.name for a in cell.arms},
        "meta": dict(scenarios.meta),
        "scenarios": [
            {
                "index": i,
                "start": {a: [float(v) for v in s.start[a]] for a in cell.arm_ids},
                "goal": {a: [float(v) for v in s.goal[a]] for a in cell.arm_ids},
            }
            for i, s in zip(scenarios.indices, scenarios.scenarios, strict=True)
        ],
    }


def save_scenario_set(scenarios: ScenarioSet, path: str | os.PathLike[str]) -> Path:
    """Write ``scenarios`` as JSON (atomically) and return the path."""
    cell = load_cell(scenarios.cell)
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(out.suffix + ".tmp")
    tmp.write_text(json.dumps(scenario_set_to_dict(scenarios, cell), indent=1) + "\n")
    os.replace(tmp, out)
    return out


def _field(data: Mapping[str, Any], key: str, where: str, kind: type | tuple[type, ...]) -> Any:
    if key not in data:
        raise ScenarioFileError(f"{where}: missing key {key!r}")
    value = data[key]
    if not isinstance(value, kind) or (isinstance(value, bool) and kind is int):
        raise ScenarioFileError(f"{where}.{key}: expected {_kind_name(kind)}; got {value!r}")
    return value


def _kind_name(kind: type | tuple[type, ...]) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    return " or ".join(k.__name__ for k in kinds)


def _joint_vectors(data: Any, cell: Cell, where: str) -> dict[str, np.ndarray]:
    if not isinstance(data, dict):
        raise ScenarioFileError(f"{where}: expected a mapping arm id -> joint list; got {data!r}")
    if set(data) != set(cell.arm_ids):
        raise ScenarioFileError(
            f"{where}: arms {sorted(data)} do not match cell {cell.name!r} arms "
            f"{sorted(cell.arm_ids)}"
        )
    out = {}
    for arm in cell.arms:
        try:
            q = arm.robot.check_within_limits(data[arm.arm_id], f"{where}.{arm.arm_id}")
        except (NehmoError, TypeError, ValueError) as exc:
            raise ScenarioFileError(str(exc)) from None
        out[arm.arm_id] = q
    return out


def scenario_set_from_dict(data: Any, source: str = "<scenarios>") -> ScenarioSet:
    """Parse and check the JSON form; every error names ``source`` and the offending field."""
    if not isinstance(data, dict):
        raise ScenarioFileError(f"{source}: expected a JSON object; got {type(data).__name__}")
    fmt = _field(data, "format", source, str)
    if fmt != SCENARIO_FORMAT:
        raise ScenarioFileError(f"{source}: format must be {SCENARIO_FORMAT!r}; got {fmt!r}")
    version = _field(data, "version", source, int)
    if version != SCENARIO_FORMAT_VERSION:
        raise ScenarioFileError(
            f"{source}: version {version} is not supported (this reader reads "
            f"{SCENARIO_FORMAT_VERSION})"
        )
    cell_name = _field(data, "cell", source, str)
    try:
        cell = load_cell(cell_name)
    except NehmoError as exc:
        raise ScenarioFileError(f"{source}.cell: {exc}") from None
    arms = _field(data, "arms", source, dict)
    robots = {a.arm_id: a.robot.name for a in cell.arms}
    if arms != robots:
        raise ScenarioFileError(f"{source}.arms: {arms} do not match cell {cell_name!r} {robots}")
    seed = _field(data, "seed", source, int)
    candidates = _field(data, "candidates", source, int)
    meta = _field(data, "meta", source, dict)
    items = _field(data, "scenarios", source, list)
    if not items:
        raise ScenarioFileError(f"{source}.scenarios: the set is empty")
    indices, scenarios = [], []
    for k, item in enumerate(items):
        where = f"{source}.scenarios[{k}]"
        if not isinstance(item, dict):
            raise ScenarioFileError(f"{where}: expected an object; got {item!r}")
        indices.append(_field(item, "index", where, int))
        start = _joint_vectors(_field(item, "start", where, dict), cell, f"{where}.start")
        goal = _joint_vectors(_field(item, "goal", where, dict), cell, f"{where}.goal")
        scenarios.append(Scenario(start, goal))
    if len(set(indices)) != len(indices):
        raise ScenarioFileError(f"{source}.scenarios: indices must be unique; got {indices}")
    return ScenarioSet(cell_name, seed, tuple(indices), tuple(scenarios), candidates, meta)


def load_scenario_set(path: str | os.PathLike[str]) -> ScenarioSet:
    """Read a scenario file written by :func:`save_scenario_set`."""
    p = Path(path)
    if not p.is_file():
        raise ScenarioFileError(f"scenario file not found: {p}")
    try:
        data = json.loads(p.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioFileError(f"{p}: not valid JSON ({exc})") from None
    return scenario_set_from_dict(data, p.name)
