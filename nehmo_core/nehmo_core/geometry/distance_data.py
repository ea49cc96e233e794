"""Seeded datasets of exact arm-arm signed distances, stratified toward contact.

A pair is two arms of a shipped cell (``ur5_ur5``: the dual-UR5 cell, ``ur5_kinova``: the
UR5-Kinova cell) or, for a pose-conditioned pair (``ur5_ur5_any``, ``ur5_kinova_any``), two
robots with arm 2 at any base distance ``r`` in front of arm 1 (``r`` is then a model input).
Samples are joint vectors ``q = (q¹, q²)`` (N, n1 + n2) [rad] drawn uniformly over each arm's
sampling box, plus "boundary" samples: uniform samples whose distance is below ``near`` [m],
perturbed by Gaussian noise so that the set concentrates around contact.
Labels come from PyBullet on the arms' collision geometry (negative in penetration), clipped
at ``cutoff`` [m].
"""

from __future__ import annotations

import math
import multiprocessing as mp
from dataclasses import dataclass
from typing import Any

import numpy as np
from tqdm import tqdm

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots import registry
from nehmo_core.robots.loader import load_cell, load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose, RobotModel

PAIRS: dict[str, tuple[str, str, str]] = registry.FIXED_PAIRS
"""Pair name → (cell, arm 1, arm 2) (:data:`~nehmo_core.robots.registry.ARM_PAIRS`). Arm 1 sits
at the origin, arm 2 facing it, 0.6 m away (0.849 m for ``ur5_ur5_diag``, the diagonal
neighbours of the five-UR5 cell; 1.2 m for ``ur5_ur5_opposite``, the outer arms of the three-
and five-UR5 cells facing each other)."""
CONDITIONED_PAIRS: dict[str, tuple[str, str]] = registry.CONDITIONED_PAIRS
"""Pair name → (robot 1, robot 2). Arm 1 at the origin, arm 2 at (r, 0, 0) facing it, for any
base distance r in BASE_RANGE: the pose-conditioned models (one for every layout)."""
SWAPPED_PAIRS: dict[str, str] = registry.SWAPPED_PAIRS
"""Arm-pair system name → the pair whose learned distance it reuses with the arms' roles
exchanged (its arm 1 is the pair's arm 2): the Kinova's side of the UR5-Kinova pairs."""
BASE_RANGE = registry.DEFAULT_BASE_RANGE
"""Base distances [m] the hand-registered conditioned models are trained on (Ha et al.'s
layouts: 0.31-1.60); a built pair's own range: :func:`.registry.pair_base_range`."""
CUTOFF = 1.0
"""Distances are resolved up to this value [m]; farther pairs are labelled with it."""


def pair_cell(pair: str) -> tuple[Cell, str, str]:
    """The cell and the two arm ids of a named arm pair.

    For a conditioned pair the cell has arm 2 at the origin facing arm 1 (``r = 0``): the
    canonical frame that the base distance then shifts along x.
    """
    if pair in CONDITIONED_PAIRS:
        r1, r2 = CONDITIONED_PAIRS[pair]
        arms = (
            ArmSpec("arm_0", load_robot(r1), Pose()),
            ArmSpec("arm_1", load_robot(r2), Pose((0.0, 0.0, 0.0), (0.0, 0.0, math.pi))),
        )
        return Cell(pair, arms), "arm_0", "arm_1"
    if pair not in PAIRS:
        raise UnknownNameError("arm pair", pair, [*PAIRS, *CONDITIONED_PAIRS])
    cell_name, a, b = PAIRS[pair]
    return load_cell(cell_name), a, b


def system_pair_cell(name: str) -> tuple[Cell, str, str]:
    """The cell of an arm-pair system and its two arm ids in the system's order (arm 1, arm 2).

    A pair of :data:`PAIRS` or :data:`CONDITIONED_PAIRS` is its own cell. A swapped system
    (:data:`SWAPPED_PAIRS`) is its pair's cell seen from the other base: the arms swap. For a
    fixed pair that is the same cell (a rigid motion); for a conditioned one the cell is rebuilt
    in the swapped game's canonical frame (its arm 1 at the origin, its arm 2 at the origin
    facing it, to be moved to ``(r, 0, 0)``), which is the pair's frame seen from arm 2 because
    arm 2 faces arm 1 along x.
    """
    if name not in SWAPPED_PAIRS:
        if name not in PAIRS and name not in CONDITIONED_PAIRS:
            raise UnknownNameError(
                "arm-pair system", name, [*PAIRS, *CONDITIONED_PAIRS, *SWAPPED_PAIRS]
            )
        return pair_cell(name)
    pair = SWAPPED_PAIRS[name]
    cell, a, b = pair_cell(pair)
    if pair in CONDITIONED_PAIRS:
        facing = Pose((0.0, 0.0, 0.0), (0.0, 0.0, math.pi))
        arm_a, arm_b = cell.arm(a), cell.arm(b)
        cell = Cell(
            name,
            (
                ArmSpec(arm_a.arm_id, arm_a.robot, facing),
                ArmSpec(arm_b.arm_id, arm_b.robot, Pose()),
            ),
        )
    return cell, b, a


def sampling_box(robot: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint sampling bounds [rad]: (−π, π] for wrapping joints, the limits otherwise."""
    lo = np.where(robot.continuous, -np.pi, np.maximum(robot.lower, -np.pi))
    hi = np.where(robot.continuous, np.pi, np.minimum(robot.upper, np.pi))
    return lo, hi


JOINT_SLACK = 0.3
"""[rad] How far a ``limits``-domain pair's models reach beyond each limited joint's limits:
what a joint moves at 0.5 rad/s within the value function's 0.6 s horizon."""


def joint_domain(robot: RobotModel, yaw_first: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(low, high, periodic)`` per joint of a ``limits``-domain pair model: the base-yaw joint
    (``yaw_first``: a conditioned pair's, which also turns with the layout) and continuous joints
    over (−π, π], periodic; every other joint within its limits widened by :data:`JOINT_SLACK`."""
    periodic = np.array(robot.continuous, dtype=bool)
    if yaw_first:
        periodic[0] = True
    lo = np.where(periodic, -np.pi, robot.lower - JOINT_SLACK)
    hi = np.where(periodic, np.pi, robot.upper + JOINT_SLACK)
    return lo, hi, periodic


def pair_joint_domain(pair: str) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Both arms' :func:`joint_domain` for a ``limits``-domain pair (in the system's order);
    None for a ``circle`` pair."""
    if registry.arm_pair(pair).domain != "limits":
        return None
    cell, a, b = system_pair_cell(pair)
    conditioned = SWAPPED_PAIRS.get(pair, pair) in CONDITIONED_PAIRS
    parts = [joint_domain(cell.arm(x).robot, conditioned) for x in (a, b)]
    return tuple(np.concatenate([p[i] for p in parts]) for i in range(3))  # type: ignore[return-value]


@dataclass(frozen=True)
class DatasetSpec:
    pair: str
    n_uniform: int
    n_boundary: int
    seed: int = 0
    near: float = 0.15
    noise: float = 0.08
    seed_search: int = 2_000_000
    """Uniform draws at most (the set's own included) in search of near-contact seeds."""

    def __post_init__(self) -> None:
        if self.pair not in PAIRS and self.pair not in CONDITIONED_PAIRS:
            raise UnknownNameError("arm pair", self.pair, [*PAIRS, *CONDITIONED_PAIRS])
        for name in ("n_uniform", "n_boundary"):
            if getattr(self, name) < 0:
                raise InvalidValueError(name, "must be >= 0", getattr(self, name))
        if self.n_uniform + self.n_boundary == 0:
            raise InvalidValueError(
                "n_uniform", "must be > 0 when no boundary samples are asked for", 0
            )


_WORLD: tuple[CellWorld, str, str] | None = None
_YAW_SIGNS: tuple[float, float] = (1.0, 1.0)
_PAIR = ""  # the pair whose world _WORLD holds


def _label_on_worker(pair: str, chunk: np.ndarray) -> np.ndarray:
    """:func:`_label` in a cluster worker, which keeps the pair's world between chunks."""
    if _WORLD is None or pair != _PAIR:
        if _WORLD is not None:
            _WORLD[0].close()
        _init_worker(pair)
    return _label(chunk)


def _init_worker(pair: str) -> None:
    global _WORLD, _YAW_SIGNS, _PAIR
    cell, a, b = pair_cell(pair)
    _WORLD = (CellWorld(cell), a, b)
    _PAIR = pair
    if pair in CONDITIONED_PAIRS:
        from nehmo_core.planning.models.pair_frame import base_yaw_joint

        signs = [base_yaw_joint(cell.arm(x).robot) for x in (a, b)]
        if signs[0] is None or signs[1] is None:
            raise InvalidValueError(
                "pair", "a conditioned pair needs arms whose first joint is a base yaw", pair
            )
        _YAW_SIGNS = (signs[0], signs[1])


def _label(q: np.ndarray) -> np.ndarray:
    """Exact distances of rows ``(q¹, q²)``, or for a conditioned pair ``(q¹, q², r, α¹, α²)``.

    Conditioned rows are in the canonical frame; they are labelled on a real layout: arm 1 turned
    by ``α¹`` about its base axis, arm 2 at ``(r, 0, 0)`` turned by ``α²``, and each first joint
    shifted back by the same angle (the same pose up to the base links' own shapes, which the
    labels thus carry).
    """
    assert _WORLD is not None
    world, a, b = _WORLD
    n1 = world.cell.arm(a).robot.dof
    n2 = world.cell.arm(b).robot.dof
    conditioned = q.shape[1] == n1 + n2 + 3
    out = np.empty(len(q))
    for i, qi in enumerate(q):
        q1, q2 = qi[:n1].copy(), qi[n1 : n1 + n2].copy()
        if conditioned:
            r, yaw1, yaw2 = qi[n1 + n2 :]
            world.set_base_pose(a, Pose((0.0, 0.0, 0.0), (0.0, 0.0, float(yaw1))))
            world.set_base_pose(b, Pose((float(r), 0.0, 0.0), (0.0, 0.0, math.pi + float(yaw2))))
            q1[0] = _wrap(q1[0] - _YAW_SIGNS[0] * yaw1)
            q2[0] = _wrap(q2[0] - _YAW_SIGNS[1] * yaw2)
        world.set_joint_positions(a, q1)
        world.set_joint_positions(b, q2)
        out[i] = world.distance(a, b, CUTOFF)
    return out


def _wrap(angle: float) -> float:
    return float((angle + math.pi) % (2.0 * math.pi) - math.pi)


def exact_distances(
    pair: str, q: np.ndarray, workers: int = 1, desc: str = "", executor: Any = None
) -> np.ndarray:
    """Exact signed distances (N,) for joint vectors ``q`` (N, n1 + n2), in parallel: over
    ``workers`` local processes, or chunk by chunk on ``executor`` (a Ray cluster's,
    :mod:`nehmo_core.cluster`) when given; the labels are the same either way."""
    chunks = np.array_split(q, max(1, len(q) // 2000))
    if executor is not None:
        futures = [executor.submit(_label_on_worker, pair, c) for c in chunks]
        bar = tqdm(futures, desc=desc or pair, unit="chunk", leave=False)
        parts = [f.result() for f in bar]
    elif workers <= 1:
        _init_worker(pair)
        parts = [_label(c) for c in tqdm(chunks, desc=desc or pair, unit="chunk", leave=False)]
    else:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_init_worker, initargs=(pair,)) as pool:
            it = pool.imap(_label, chunks)
            parts = list(tqdm(it, total=len(chunks), desc=desc or pair, unit="chunk", leave=False))
    return np.concatenate(parts) if parts else np.zeros(0)


def pair_box(pair: str) -> tuple[np.ndarray, np.ndarray]:
    """Sampling bounds of a pair's model input: both arms' joints [rad] (and ``r`` [m])."""
    domain = pair_joint_domain(pair)
    if domain is not None:
        lo, hi = domain[0], domain[1]
    else:
        cell, a, b = pair_cell(pair)
        lo1, hi1 = sampling_box(cell.arm(a).robot)
        lo2, hi2 = sampling_box(cell.arm(b).robot)
        lo, hi = np.concatenate([lo1, lo2]), np.concatenate([hi1, hi2])
    if pair in CONDITIONED_PAIRS:
        r_lo, r_hi = registry.pair_base_range(pair)
        lo, hi = np.append(lo, r_lo), np.append(hi, r_hi)
    return lo, hi


def uniform_samples(pair: str, n: int, rng: np.random.Generator) -> np.ndarray:
    lo, hi = pair_box(pair)
    return rng.uniform(lo, hi, size=(n, len(lo)))


def labelled(
    pair: str,
    q: np.ndarray,
    rng: np.random.Generator,
    workers: int = 1,
    desc: str = "",
    executor: Any = None,
) -> np.ndarray:
    """Exact distances (N,) of model inputs ``q``; a conditioned pair's are labelled at random
    base yaws (see :func:`_label`)."""
    if pair in CONDITIONED_PAIRS:
        yaws = rng.uniform(-np.pi, np.pi, size=(len(q), 2))
        return exact_distances(pair, np.concatenate([q, yaws], axis=1), workers, desc, executor)
    return exact_distances(pair, q, workers, desc, executor)


def generate(
    spec: DatasetSpec, workers: int = 2, executor: Any = None
) -> tuple[np.ndarray, np.ndarray]:
    """Generate (q (N, n), d (N,)) for ``spec``: uniform samples, then boundary samples (labelled
    on ``executor``'s workers when given, with the same result)."""
    rng = np.random.default_rng(spec.seed)
    lo, hi = pair_box(spec.pair)
    q_u = uniform_samples(spec.pair, spec.n_uniform, rng)
    d_u = labelled(spec.pair, q_u, rng, workers, "uniform", executor)
    qs, ds = [q_u], [d_u]
    seeds = q_u[np.abs(d_u) < spec.near]
    searched, n = spec.n_uniform, max(spec.n_uniform, 1000)
    while spec.n_boundary > 0 and not len(seeds) and searched < spec.seed_search:
        # near contact is rare (e.g. a pair's far base distances): more uniform draws, twice as
        # many each round, used only as seeds of the boundary samples, never part of the set
        n = min(2 * n, spec.seed_search - searched)
        q_s = uniform_samples(spec.pair, n, rng)
        d_s = labelled(spec.pair, q_s, rng, workers, "seeds", executor)
        seeds = q_s[np.abs(d_s) < spec.near]
        searched += n
    if spec.n_boundary > 0 and not len(seeds):
        raise InvalidValueError(
            "n_boundary",
            f"needs near-contact seeds (|d| < {spec.near} m), and none of {searched} uniform "
            "draws is: can the arms touch at these base distances?",
            spec.n_boundary,
        )
    made = 0
    while made < spec.n_boundary and len(seeds):
        n = min(spec.n_boundary - made, 100_000)
        base = seeds[rng.integers(0, len(seeds), n)]
        q_b = np.clip(base + rng.normal(0.0, spec.noise, base.shape), lo, hi)
        d_b = labelled(spec.pair, q_b, rng, workers, "boundary", executor)
        qs.append(q_b)
        ds.append(d_b)
        seeds = np.concatenate([seeds, q_b[np.abs(d_b) < spec.near]])
        made += n
    return np.concatenate(qs), np.concatenate(ds)
