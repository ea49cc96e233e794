"""State distributions of a certificate: uniform over the box, or the states a planner visited.

``uniform``: i.i.d. uniform over the system's state box (for arm pairs every joint in
``(−π, π]``). ``visited``: i.i.d. draws (with replacement) from the pair states of evaluation
episodes — every logged tick, every ordered (own arm, peer) pair of the episode's cell that maps
onto the model's pair (:func:`~nehmo_core.planning.models.pair_frame.match_pair`, the planner's own
mapping) — so the certificate speaks of the states the closed-loop planner actually meets.
Either can be restricted to a level set ``V(τ, x) ≥ δ`` by rejection (:func:`draw_level_set`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.eval.episode_log import read_episode_log
from nehmo_core.hjr.systems import ArmPairSystem, HJISystem
from nehmo_core.planning.models.pair_frame import (
    ModelGeometry,
    match_pair,
    pose_from_matrix,
    relative_pose,
)
from nehmo_core.robots.model import wrap_angle
from nehmo_core.verify.truth import pair_arms


class StateDistribution(Protocol):
    """Draws i.i.d. states ``(count, n)`` from a seeded generator."""

    def describe(self) -> dict[str, Any]: ...

    def draw(self, count: int, rng: np.random.Generator) -> np.ndarray: ...


@dataclass(frozen=True)
class UniformBox:
    """Uniform over the system's state box."""

    system: HJISystem

    def describe(self) -> dict[str, Any]:
        return {
            "name": "uniform",
            "what": "i.i.d. uniform over the state box",
            "lower": self.system.lower.tolist(),
            "upper": self.system.upper.tolist(),
        }

    def draw(self, count: int, rng: np.random.Generator) -> np.ndarray:
        lo, hi = self.system.lower, self.system.upper
        return lo + (hi - lo) * rng.random((count, self.system.state_dim))


@dataclass(frozen=True)
class VisitedStates:
    """The empirical distribution of a pool of visited pair states ``(M, n)``."""

    states: np.ndarray
    sources: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        if self.states.ndim != 2 or self.states.shape[0] == 0:
            raise InvalidValueError("states", "must be a non-empty (M, n) array", self.states.shape)

    def describe(self) -> dict[str, Any]:
        return {
            "name": "visited",
            "what": "i.i.d. draws with replacement from the pair states of evaluation episodes",
            "pool_size": int(self.states.shape[0]),
            "sources": list(self.sources),
        }

    def draw(self, count: int, rng: np.random.Generator) -> np.ndarray:
        return self.states[rng.integers(0, self.states.shape[0], size=count)]


def pair_model_geometry(system: ArmPairSystem) -> ModelGeometry:
    """``(robot 1, robot 2, base of arm 2 seen from arm 1[, base-distance range])`` of a shipped
    arm-pair system, as :func:`~nehmo_core.planning.models.pair_frame.match_pair` takes it."""
    cell, a, b = pair_arms(system.name)
    arm1, arm2 = cell.arm(a), cell.arm(b)
    pose = pose_from_matrix(relative_pose(arm1.base, arm2.base))
    if system.conditions:
        return arm1.robot.name, arm2.robot.name, pose, system.conditions[0]
    return arm1.robot.name, arm2.robot.name, pose


def visited_pair_states(system: ArmPairSystem, episodes: Sequence[str | Path]) -> VisitedStates:
    """Every (own, peer) pair state of the episode logs that maps onto ``system``'s pair."""
    model = [pair_model_geometry(system)]
    pools: list[np.ndarray] = []
    for path in episodes:
        log = read_episode_log(path)
        for own in log.cell.arms:
            for peer in log.cell.arms:
                if own.arm_id == peer.arm_id:
                    continue
                mapping = match_pair(own, peer, model)
                if mapping is None:
                    continue
                q_own = log.positions[own.arm_id] + mapping.own_shift
                q_peer = log.positions[peer.arm_id] + mapping.peer_shift
                condition = np.tile(mapping.condition, (q_own.shape[0], 1))  # (T, 0) or (T, 1)
                pools.append(np.concatenate([wrap_angle(q_own), wrap_angle(q_peer), condition], 1))
    if not pools:
        raise NehmoError(f"no pair of the {len(episodes)} episode logs maps onto {system.name!r}")
    states = np.asarray(np.concatenate(pools), dtype=np.float64)
    return VisitedStates(states, tuple(str(p) for p in episodes))


def episode_logs(directories: Sequence[str | Path]) -> list[Path]:
    """Every episode bag below the given directories (a directory holding a ``.mcap``)."""
    found = sorted({p.parent for d in directories for p in Path(d).rglob("*.mcap")})
    if not found:
        raise NehmoError(f"no episode logs (*.mcap) below {[str(d) for d in directories]}")
    return found


def draw_level_set(
    value: Any,
    distribution: StateDistribution,
    tau: float,
    delta: float,
    count: int,
    rng: np.random.Generator,
    max_draws: int = 200,
) -> tuple[np.ndarray, np.ndarray, float]:
    """``count`` i.i.d. states of ``distribution`` restricted to ``V(τ, x) ≥ δ``, by rejection.

    Returns the states ``(count, n)``, their values ``(count,)`` and the accepted share.
    """
    kept: list[np.ndarray] = []
    values: list[np.ndarray] = []
    have = drawn = 0
    for _ in range(max_draws):
        x = distribution.draw(max(count, 1024), rng)
        v = np.asarray(value.value(tau, x), dtype=np.float64)
        drawn += x.shape[0]
        keep = v >= delta
        kept.append(x[keep])
        values.append(v[keep])
        have += int(keep.sum())
        if have >= count:
            break
    if have < count:
        raise NehmoError(
            f"only {have} of {drawn} drawn states have V({tau}) >= {delta}; need {count}"
        )
    return np.concatenate(kept)[:count], np.concatenate(values)[:count], have / drawn
