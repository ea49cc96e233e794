"""`nehmo verify` on arm pairs: the exact margin and the visited states of fixed and
pose-conditioned pair models."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nehmo_core.eval.episode_log import EpisodeLogWriter, cell_metadata
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.hjr.systems.arm_pairs import make_arm_pair_system
from nehmo_core.robots.loader import load_cell
from nehmo_core.robots.model import Cell
from nehmo_core.verify.distributions import visited_pair_states
from nehmo_core.verify.truth import exact_margin

IRREGULAR = Path(__file__).resolve().parents[2] / "examples" / "cells" / "irregular_three_ur5.yaml"


def _joint_states(count: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-np.pi, np.pi, size=(count, 12))


def test_conditioned_margin_at_0_6_m_is_the_dual_ur5_distance() -> None:
    fixed = exact_margin(make_arm_pair_system("ur5_ur5"))
    conditioned = exact_margin(make_arm_pair_system("ur5_ur5_any"))
    try:
        q = _joint_states(60, 3)
        x = np.concatenate([q, np.full((60, 1), 0.6)], axis=1)
        np.testing.assert_allclose(conditioned(x, 1.0), fixed(q, 1.0), atol=1e-6)
        far = conditioned(np.concatenate([q, np.full((60, 1), 1.7)], axis=1), 1.0)
        assert (far >= conditioned(x, 1.0) - 1e-9).mean() > 0.9  # farther apart, mostly farther
    finally:
        fixed.close()
        conditioned.close()


def _write_episode(path: Path, cell: Cell, q: dict[str, np.ndarray]) -> None:
    with EpisodeLogWriter(path, cell) as log:
        log.scenario({"cell": cell_metadata(cell)})
        log.goals({a: v[-1] for a, v in q.items()})
        for t in range(len(next(iter(q.values())))):
            log.tick(t * 40_000_000, {a: v[t] for a, v in q.items()}, {a: np.zeros(6) for a in q})


def test_visited_states_of_the_dual_cell_are_its_joint_states_in_both_orders(
    tmp_path: Path,
) -> None:
    cell = load_cell("dual_ur5")
    q = {a.arm_id: _joint_states(5, 7)[:, :6] + i for i, a in enumerate(cell.arms)}
    _write_episode(tmp_path / "episode", cell, q)
    visited = visited_pair_states(make_arm_pair_system("ur5_ur5"), [tmp_path / "episode"])
    assert visited.states.shape == (10, 12)
    first = np.concatenate([q["ur5_0"], q["ur5_1"]], axis=1)
    np.testing.assert_allclose(np.cos(visited.states[:5]), np.cos(first), atol=1e-12)
    np.testing.assert_allclose(np.sin(visited.states[5:, :6]), np.sin(q["ur5_1"]), atol=1e-12)


def test_visited_states_of_an_irregular_cell_carry_r_and_keep_the_exact_distance(
    tmp_path: Path,
) -> None:
    cell = load_cell(str(IRREGULAR))
    rng = np.random.default_rng(5)
    ticks = 8
    q = {a.arm_id: rng.uniform(-np.pi, np.pi, size=(ticks, 6)) for a in cell.arms}
    _write_episode(tmp_path / "episode", cell, q)
    system = make_arm_pair_system("ur5_ur5_any")
    visited = visited_pair_states(system, [tmp_path / "episode"])
    pairs = len(cell.arms) * (len(cell.arms) - 1)
    assert visited.states.shape == (pairs * ticks, 13)
    bases = {a.arm_id: np.asarray(a.base.xyz[:2]) for a in cell.arms}
    expected_r = sorted(
        float(np.linalg.norm(bases[a] - bases[b])) for a in bases for b in bases if a != b
    )
    assert sorted(set(np.round(visited.states[:, 12], 9))) == pytest.approx(
        sorted(set(np.round(expected_r, 9)))
    )
    margin = exact_margin(system)
    world = CellWorld(cell)
    try:
        truth = []
        for own in cell.arms:
            for peer in cell.arms:
                if own.arm_id == peer.arm_id:
                    continue
                for t in range(ticks):
                    world.set_joint_positions(own.arm_id, q[own.arm_id][t])
                    world.set_joint_positions(peer.arm_id, q[peer.arm_id][t])
                    truth.append(world.distance(own.arm_id, peer.arm_id, 1.0))
        mapped = margin(visited.states, 1.0)
    finally:
        margin.close()
        world.close()
    error = np.abs(mapped - np.asarray(truth))
    assert (np.asarray(truth) < 1.0).all()  # every distance resolved, none cut off
    assert np.median(error) < 1e-3 and error.max() < 0.02, error
