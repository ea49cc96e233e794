"""Seeded datasets of exact arm-arm signed distances, stratified toward contact.

A pair is two arms of a shipped cell (``ur5_ur5``: the dual-UR5 cell, ``ur5_kinova``: the
UR5-Kinova cell). Samples are joint vectors ``q = (q¹, q²)`` (N, n1 + n2) [rad] drawn
uniformly over each arm's sampling box, plus "boundary" samples: uniform samples whose distance
is below ``near`` [m], perturbed by Gaussian noise so that the set concentrates around contact.
Labels come from PyBullet on the arms' collision geometry (negative in penetration), clipped
at ``cutoff`` [m].
"""

from __future__ import annotations

import multiprocessing as mp
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.robots.loader import load_cell
from nehmo_core.robots.model import Cell, RobotModel

PAIRS: dict[str, tuple[str, str, str]] = {
    # pair name: (cell, arm 1, arm 2). Arm 1 sits at the origin, arm 2 facing it, 0.6 m away
    # (0.849 m for ``ur5_ur5_diag``, the diagonal neighbours of the five-UR5 cell; 1.2 m for
    # ``ur5_ur5_opposite``, the outer arms of the three- and five-UR5 cells facing each other).
    "ur5_ur5": ("dual_ur5", "ur5_0", "ur5_1"),
    "ur5_ur5_diag": ("diagonal_ur5", "ur5_0", "ur5_1"),
    "ur5_ur5_opposite": ("opposite_ur5", "ur5_0", "ur5_1"),
    "ur5_kinova": ("ur5_kinova", "ur5_0", "kinova_0"),
}
CUTOFF = 1.0
"""Distances are resolved up to this value [m]; farther pairs are labelled with it."""


def pair_cell(pair: str) -> tuple[Cell, str, str]:
    """The cell and the two arm ids of a named arm pair."""
    if pair not in PAIRS:
        raise UnknownNameError("arm pair", pair, PAIRS)
    cell_name, a, b = PAIRS[pair]
    return load_cell(cell_name), a, b


def sampling_box(robot: RobotModel) -> tuple[np.ndarray, np.ndarray]:
    """Per-joint sampling bounds [rad]: (−π, π] for wrapping joints, the limits otherwise."""
    lo = np.where(robot.continuous, -np.pi, np.maximum(robot.lower, -np.pi))
    hi = np.where(robot.continuous, np.pi, np.minimum(robot.upper, np.pi))
    return lo, hi


@dataclass(frozen=True)
class DatasetSpec:
    pair: str
    n_uniform: int
    n_boundary: int
    seed: int = 0
    near: float = 0.15
    noise: float = 0.08

    def __post_init__(self) -> None:
        if self.pair not in PAIRS:
            raise UnknownNameError("arm pair", self.pair, PAIRS)
        for name in ("n_uniform", "n_boundary"):
            if getattr(self, name) < 0:
                raise InvalidValueError(name, "must be >= 0", getattr(self, name))
        if self.n_uniform + self.n_boundary == 0:
            raise InvalidValueError(
                "n_uniform", "must be > 0 when no boundary samples are asked for", 0
            )


_WORLD: tuple[CellWorld, str, str] | None = None


def _init_worker(pair: str) -> None:
    global _WORLD
    cell, a, b = pair_cell(pair)
    _WORLD = (CellWorld(cell), a, b)


def _label(q: np.ndarray) -> np.ndarray:
    assert _WORLD is not None
    world, a, b = _WORLD
    n1 = world.cell.arm(a).robot.dof
    out = np.empty(len(q))
    for i, qi in enumerate(q):
        world.set_joint_positions(a, qi[:n1])
        world.set_joint_positions(b, qi[n1:])
        out[i] = world.distance(a, b, CUTOFF)
    return out


def exact_distances(pair: str, q: np.ndarray, workers: int = 1, desc: str = "") -> np.ndarray:
    """Exact signed distances (N,) for joint vectors ``q`` (N, n1 + n2), in parallel."""
    chunks = np.array_split(q, max(1, len(q) // 2000))
    if workers <= 1:
        _init_worker(pair)
        parts = [_label(c) for c in tqdm(chunks, desc=desc or pair, unit="chunk", leave=False)]
    else:
        ctx = mp.get_context("spawn")
        with ctx.Pool(workers, initializer=_init_worker, initargs=(pair,)) as pool:
            it = pool.imap(_label, chunks)
            parts = list(tqdm(it, total=len(chunks), desc=desc or pair, unit="chunk", leave=False))
    return np.concatenate(parts) if parts else np.zeros(0)


def uniform_samples(pair: str, n: int, rng: np.random.Generator) -> np.ndarray:
    cell, a, b = pair_cell(pair)
    lo1, hi1 = sampling_box(cell.arm(a).robot)
    lo2, hi2 = sampling_box(cell.arm(b).robot)
    lo, hi = np.concatenate([lo1, lo2]), np.concatenate([hi1, hi2])
    return rng.uniform(lo, hi, size=(n, len(lo)))


def generate(spec: DatasetSpec, workers: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """Generate (q (N, n), d (N,)) for ``spec``: uniform samples, then boundary samples."""
    rng = np.random.default_rng(spec.seed)
    cell, a, b = pair_cell(spec.pair)
    lo = np.concatenate([sampling_box(cell.arm(x).robot)[0] for x in (a, b)])
    hi = np.concatenate([sampling_box(cell.arm(x).robot)[1] for x in (a, b)])
    q_u = uniform_samples(spec.pair, spec.n_uniform, rng)
    d_u = exact_distances(spec.pair, q_u, workers, "uniform")
    qs, ds = [q_u], [d_u]
    seeds = q_u[np.abs(d_u) < spec.near]
    if spec.n_boundary > 0 and not len(seeds):
        raise InvalidValueError(
            "n_boundary",
            f"needs near-contact seeds (|d| < {spec.near} m) among the uniform samples, and "
            f"none of the {spec.n_uniform} drawn is; draw more uniform samples",
            spec.n_boundary,
        )
    made = 0
    while made < spec.n_boundary and len(seeds):
        n = min(spec.n_boundary - made, 100_000)
        base = seeds[rng.integers(0, len(seeds), n)]
        q_b = np.clip(base + rng.normal(0.0, spec.noise, base.shape), lo, hi)
        d_b = exact_distances(spec.pair, q_b, workers, "boundary")
        qs.append(q_b)
        ds.append(d_b)
        seeds = np.concatenate([seeds, q_b[np.abs(d_b) < spec.near]])
        made += n
    return np.concatenate(qs), np.concatenate(ds)
