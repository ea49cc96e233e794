"""The one registry of robot and arm-pair facts: whatever NeHMO knows about a robot, or a pair
of robots, by name. Code outside :mod:`nehmo_core.robots` reads robot facts from the model
(``robot.facts``, attached by :func:`~nehmo_core.robots.loader.load_robot`) and pair facts from
here; it names no robot itself (``tests/test_robot_names.py`` checks that).

* a robot is its description file (:mod:`nehmo_core.robots.descriptions`): where its URDF comes
  from, its tip link and its :class:`~nehmo_core.robots.model.RobotFacts` (learned-distance
  keypoints, CHOMP's sphere radius, the evaluation protocol's joint sampling ranges);
  :func:`robot_facts` reads them.
* :data:`ARM_PAIRS`: the named arm pairs, i.e. the learned distances and HJI games, each with
  its robots (controlled robot first), its frame (arms of a shipped cell, arm 2 at any base
  distance, or another pair seen from its second arm) and which of its models ship.
* :data:`HA_BENCHMARK_ROBOT`: the robot of Ha et al.'s benchmark tasks.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import yaml

from nehmo_core.errors import InvalidValueError, ModelFileError, UnknownNameError
from nehmo_core.robots.descriptions import DATA_DIR, description_paths, load_description
from nehmo_core.robots.model import RobotFacts

__all__ = [
    "ARM_PAIRS",
    "CONDITIONED_PAIRS",
    "FIXED_PAIRS",
    "HA_BENCHMARK_ROBOT",
    "MODELS_DIR",
    "MODELS_ENV",
    "PAIR_NAMES",
    "ROBOT_NAMES",
    "SWAPPED_PAIRS",
    "ArmPair",
    "distance_pairs",
    "model_dirs",
    "model_dirs_env",
    "model_file",
    "pair_base_range",
    "pairs_by_robots",
    "read_pair_manifest",
    "robot_facts",
    "synthetic_pairs",
    "value_variants",
]

UR5 = "ur5"
KINOVA = "kinova_gen3_6dof"
PLANAR = "planar_2link"


ROBOT_NAMES: tuple[str, ...] = tuple(sorted(p.parent.name for p in DATA_DIR.glob("*/robot.yaml")))
"""The shipped robots (``robots/data/<name>/robot.yaml``; more: ``NEHMO_ROBOTS``)."""

HA_BENCHMARK_ROBOT = UR5
"""The robot of Ha et al.'s multi-arm benchmark (their task files hold its joint vectors)."""


def robot_facts(name: str) -> RobotFacts:
    """The facts of robot ``name``'s description (none for a robot that has no description)."""
    path = description_paths().get(name)
    return RobotFacts() if path is None else load_description(path).facts


SHIPPED = "shipped"
OPTIONAL = "optional"

MODELS_DIR = Path(__file__).resolve().parents[1] / "models"
"""The shipped models (distances, value functions, their cards and pair manifests)."""
MODELS_ENV = "NEHMO_MODELS"
"""Environment variable naming more model folders (separated like ``PATH``): where
``nehmo pair build`` wrote a pair."""
DEFAULT_BASE_RANGE = (0.25, 1.7)
"""[m] Base distances of the hand-registered conditioned pairs (Ha et al.'s layouts: 0.31-1.60).
A pair built by ``nehmo pair build`` derives its own range from the two robots' reach."""


@dataclass(frozen=True)
class ArmPair:
    """A named arm pair: a learned distance, an HJI game, or both.

    Its frame is one of: ``cell = (cell, arm 1, arm 2)``, two arms of a shipped cell;
    ``conditioned``, arm 1 at the origin and arm 2 at ``(r, 0, 0)`` facing it for any base
    distance ``r`` (a model input); ``swapped``, the named pair seen from its arm 2 (this pair's
    arm 1), reusing its learned distance. ``distance`` says whether its own learned distance
    ships (``shipped``), has a code path but no weights yet (``optional``) or does not exist
    (None); ``values`` / ``optional_values`` are the value-function variants that ship / that
    count as shipped once trained and copied to ``models/``.
    """

    name: str
    robots: tuple[str, str]
    cell: tuple[str, str, str] | None = None
    conditioned: bool = False
    swapped: str | None = None
    distance: str | None = None
    values: tuple[str, ...] = ()
    optional_values: tuple[str, ...] = ()
    base_range: tuple[float, float] | None = None
    """[m] A conditioned pair's base distances (None: :data:`DEFAULT_BASE_RANGE`)."""
    folder: Path = MODELS_DIR
    """Where its model files are (a pair manifest's folder)."""
    domain: str = "circle"
    """Joint domain of its models: ``circle``, every joint over (−π, π] (the pairs registered
    here); ``limits``, the base-yaw joint and continuous joints over (−π, π], every other joint
    within its limits widened by what it can move within the value function's horizon (the pairs
    of ``nehmo pair build``)."""

    def __post_init__(self) -> None:
        frames = (self.cell is not None) + self.conditioned + (self.swapped is not None)
        if frames != 1:
            raise ValueError(f"arm pair {self.name}: needs one of cell, conditioned, swapped")
        if self.swapped is not None and self.distance is not None:
            raise ValueError(f"arm pair {self.name}: reuses {self.swapped}'s distance")


ARM_PAIRS: tuple[ArmPair, ...] = (
    # Order matters: per (robot 1, robot 2), planners try the fixed base distances first, in
    # this order, then the conditioned pair (see pairs_by_robots).
    ArmPair(
        "ur5_ur5",
        (UR5, UR5),
        cell=("dual_ur5", "ur5_0", "ur5_1"),
        distance=SHIPPED,
        values=("bc+sym", "bc", "deepreach"),
    ),
    ArmPair(  # 0.849 m: the diagonal neighbours of the five-UR5 cell
        "ur5_ur5_diag",
        (UR5, UR5),
        cell=("diagonal_ur5", "ur5_0", "ur5_1"),
        distance=SHIPPED,
        values=("bc+sym",),
    ),
    ArmPair(  # 1.2 m: the outer arms of the three- and five-UR5 cells facing each other
        "ur5_ur5_opposite",
        (UR5, UR5),
        cell=("opposite_ur5", "ur5_0", "ur5_1"),
        distance=SHIPPED,
        values=("bc+sym",),
    ),
    ArmPair(
        "ur5_kinova",
        (UR5, KINOVA),
        cell=("ur5_kinova", "ur5_0", "kinova_0"),
        distance=SHIPPED,
        values=("bc+sym",),
    ),
    ArmPair("kinova_ur5", (KINOVA, UR5), swapped="ur5_kinova", values=("bc+sym",)),
    ArmPair("ur5_ur5_any", (UR5, UR5), conditioned=True, distance=SHIPPED, values=("bc+sym",)),
    ArmPair(
        "ur5_kinova_any",
        (UR5, KINOVA),
        conditioned=True,
        distance=OPTIONAL,
        optional_values=("bc+sym",),
    ),
    ArmPair("kinova_ur5_any", (KINOVA, UR5), swapped="ur5_kinova_any", optional_values=("bc+sym",)),
)

MANIFEST_SUFFIX = ".pairs.yaml"
_MANIFEST_KEYS = {"name", "robots", "conditioned", "swapped", "base_range", "values"}


def model_dirs_env() -> tuple[str, ...]:
    """The folders named in ``NEHMO_MODELS``, resolved."""
    found = [p for p in os.environ.get(MODELS_ENV, "").split(os.pathsep) if p]
    return tuple(str(Path(p).resolve()) for p in found)


def model_dirs() -> tuple[Path, ...]:
    """The model folders: the shipped ``models/``, then those named in ``NEHMO_MODELS``."""
    return tuple(dict.fromkeys([MODELS_DIR, *(Path(p) for p in model_dirs_env())]))


def read_pair_manifest(path: Path) -> tuple[ArmPair, ...]:
    """The pairs of one ``<name>.pairs.yaml`` (written by ``nehmo pair build``).

    Each entry names a pair, its robots (controlled robot first) and its frame (``conditioned``
    with ``base_range`` [m], or ``swapped``: another entry seen from its arm 2). Its models are
    files beside the manifest and count as present once they exist (until then, loading one
    says how to make it).
    """
    where = str(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ModelFileError(f"{where}: not a readable YAML file ({exc})") from exc
    if not isinstance(raw, dict) or not isinstance(raw.get("pairs"), list):
        raise InvalidValueError(where, "must be a mapping with a list 'pairs'", raw)
    out = []
    for i, entry in enumerate(raw["pairs"]):
        at = f"{where}: pairs[{i}]"
        if not isinstance(entry, dict) or set(entry) - _MANIFEST_KEYS:
            rule = f"must be a mapping with keys among {sorted(_MANIFEST_KEYS)}"
            raise InvalidValueError(at, rule, entry)
        robots = entry.get("robots")
        if not (isinstance(robots, list) and len(robots) == 2) or not all(
            isinstance(r, str) for r in robots
        ):
            raise InvalidValueError(f"{at}.robots", "must be two robot names", robots)
        base_range = entry.get("base_range")
        if base_range is not None:
            ok = isinstance(base_range, list) and len(base_range) == 2
            if not (ok and 0 < base_range[0] < base_range[1]):
                rule = "must be [low, high] with 0 < low < high [m]"
                raise InvalidValueError(f"{at}.base_range", rule, base_range)
            base_range = (float(base_range[0]), float(base_range[1]))
        swapped = entry.get("swapped")
        try:
            out.append(
                ArmPair(
                    str(entry.get("name")),
                    (robots[0], robots[1]),
                    conditioned=bool(entry.get("conditioned", False)),
                    swapped=swapped,
                    distance=None if swapped else OPTIONAL,
                    optional_values=tuple(entry.get("values", ("bc+sym",))),
                    base_range=base_range,
                    folder=path.parent,
                    domain="limits",
                )
            )
        except ValueError as exc:
            raise InvalidValueError(at, str(exc), entry) from None
    return tuple(out)


def _manifest_pairs() -> tuple[ArmPair, ...]:
    found: list[ArmPair] = []
    for folder in model_dirs():
        if not folder.is_dir():
            raise ModelFileError(f"{MODELS_ENV}: not a folder: {folder}")
        for path in sorted(folder.glob(f"*{MANIFEST_SUFFIX}")):
            found.extend(read_pair_manifest(path))
    return tuple(found)


ARM_PAIRS = (*ARM_PAIRS, *_manifest_pairs())
_BY_NAME: dict[str, ArmPair] = {}
for _pair in ARM_PAIRS:
    if _pair.name in _BY_NAME:
        raise ModelFileError(
            f"arm pair {_pair.name!r} is defined twice: in {_BY_NAME[_pair.name].folder} and in "
            f"{_pair.folder}"
        )
    _BY_NAME[_pair.name] = _pair
PAIR_NAMES: tuple[str, ...] = tuple(p.name for p in ARM_PAIRS)


def arm_pair(name: str) -> ArmPair:
    """The registered pair ``name``."""
    if name not in _BY_NAME:
        raise UnknownNameError("arm pair", name, PAIR_NAMES)
    return _BY_NAME[name]


def model_file(pair: str, filename: str) -> Path:
    """Where a model file of ``pair`` lives: beside its manifest (``models/`` for the pairs
    registered here)."""
    return arm_pair(pair).folder / filename


def pair_base_range(pair: str) -> tuple[float, float]:
    """[m] The base distances a conditioned pair's models cover (a swapped pair: its source's)."""
    p = arm_pair(pair)
    if p.swapped is not None:
        p = arm_pair(p.swapped)
    return p.base_range if p.base_range is not None else DEFAULT_BASE_RANGE


FIXED_PAIRS: dict[str, tuple[str, str, str]] = {p.name: p.cell for p in ARM_PAIRS if p.cell}
"""Pair name → (cell, arm 1, arm 2) of the pairs in a shipped cell."""
CONDITIONED_PAIRS: dict[str, tuple[str, str]] = {
    p.name: p.robots for p in ARM_PAIRS if p.conditioned
}
"""Pair name → (robot 1, robot 2) of the pairs conditioned on the base distance."""
SWAPPED_PAIRS: dict[str, str] = {p.name: p.swapped for p in ARM_PAIRS if p.swapped}
"""Pair name → the pair whose learned distance it reuses with the arms' roles exchanged."""


def distance_pairs(status: str) -> tuple[str, ...]:
    """Pairs whose own learned distance is ``shipped`` or ``optional`` (registry order)."""
    return tuple(p.name for p in ARM_PAIRS if p.distance == status)


def value_variants(status: str) -> dict[str, tuple[str, ...]]:
    """Pair → value-function variants that are ``shipped`` or ``optional`` (registry order)."""
    return {
        p.name: variants
        for p in ARM_PAIRS
        if (variants := p.values if status == SHIPPED else p.optional_values)
    }


def pairs_by_robots() -> dict[tuple[str, str], tuple[str, ...]]:
    """(controlled robot, other robot) → its pairs in registry order (the order planners try
    them in: the fixed base distances, then any distance)."""
    out: dict[tuple[str, str], tuple[str, ...]] = {}
    for p in ARM_PAIRS:
        out[p.robots] = (*out.get(p.robots, ()), p.name)
    return out


def synthetic_pairs() -> dict[tuple[str, str], str]:
    """(controlled robot, other robot) → its first pair in a shipped cell: the learned-distance
    cell that a synthetic stand-in value model is built on."""
    out: dict[tuple[str, str], str] = {}
    for p in ARM_PAIRS:
        if p.cell is not None:
            out.setdefault(p.robots, p.name)
    return out
