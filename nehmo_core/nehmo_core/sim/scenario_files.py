"""Scenario set files: the JSON format (cell, start and goal per arm), saving and loading.

A file names its format and version (:data:`SCENARIO_FORMAT`), the cell, the seed, the scenario
numbers and one start and goal joint vector per arm [rad]. Loading checks every field against
the cell and raises :class:`ScenarioFileError` naming the file and the field.
"""

from __future__ import annotations

import dataclasses
import json
import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from nehmo_core.errors import NehmoError
from nehmo_core.robots.loader import is_cell_file, load_cell
from nehmo_core.robots.model import Cell
from nehmo_core.sim.scenarios import Scenario, ScenarioSet, generate_scenario_set

__all__ = [
    "SCENARIO_FORMAT",
    "SCENARIO_FORMAT_VERSION",
    "ScenarioFileError",
    "draw_scenario_set",
    "load_scenario_set",
    "save_scenario_set",
    "scenario_set_from_dict",
    "scenario_set_to_dict",
]

SCENARIO_FORMAT = "nehmo-scenarios"
SCENARIO_FORMAT_VERSION = 1


class ScenarioFileError(NehmoError):
    """A scenario file that is missing, not JSON, or does not fit its cell."""


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


def draw_scenario_set(cell_ref: str, seed: int, count: int) -> ScenarioSet:
    """``count`` scenarios of the cell ``cell_ref`` names (a shipped name or a YAML path).

    A YAML cell is recorded by its absolute path, not its name: that is what every node loading
    the set (and a later re-run) must load.
    """
    scenarios = generate_scenario_set(load_cell(cell_ref), seed, count)
    if is_cell_file(cell_ref):
        scenarios = dataclasses.replace(scenarios, cell=str(Path(cell_ref).resolve()))
    return scenarios


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
