"""The bridge's broad phase: the same collision reports as the exact checks, at the same step."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from nehmo_core.robots import load_cell
from nehmo_core.robots.model import Cell
from nehmo_core.sim.cell_sim import CellSimulator
from sim_bridge.broadphase import BroadPhaseSimulator, link_spheres, rotations


def _random_q(cell: Cell, rng: np.random.Generator, spread: float) -> dict[str, np.ndarray]:
    """Joint positions within the limits (at most ±``spread`` rad on wrapping joints)."""
    return {
        a.arm_id: rng.uniform(np.maximum(a.robot.lower, -spread), np.minimum(a.robot.upper, spread))
        for a in cell.arms
    }


@pytest.mark.parametrize("cell_name", ["triple_ur5", "ur5_kinova"])
def test_reports_equal_the_exact_checks(cell_name: str) -> None:
    cell = load_cell(cell_name)
    rng = np.random.default_rng(7)
    with BroadPhaseSimulator(cell, substeps=1) as sim:
        world, colliding = sim.world, 0
        for k in range(150):
            world.set_configuration(_random_q(cell, rng, np.pi if k % 2 else 1.5))
            for self_collision in (True, False):
                expected = world.collisions(self_collision=self_collision)
                assert sim.broad_phase.collisions(self_collision) == expected
            colliding += bool(expected)
    assert 10 <= colliding <= 140  # both outcomes were exercised


@pytest.mark.parametrize("cell_name", ["triple_ur5", "ur5_kinova"])
def test_sphere_bounds_never_exceed_the_exact_distance(cell_name: str) -> None:
    cell = load_cell(cell_name)
    rng = np.random.default_rng(3)
    with BroadPhaseSimulator(cell, substeps=1) as sim:
        bp, client = sim.broad_phase, sim.world.client
        for _ in range(40):
            sim.world.set_configuration(_random_q(cell, rng, np.pi))
            bounds = bp.bounds()
            for check in bp.checks:
                if check.group < 0:
                    continue
                if check.links is None:
                    a, b = bp.bodies[check.arm_a], bp.bodies[check.arm_b]
                    pts = pb.getClosestPoints(a, b, 10.0, physicsClientId=client)
                else:
                    body = bp.bodies[check.arm_a]
                    _, _, ia, ib = check.links
                    pts = pb.getClosestPoints(body, body, 10.0, ia, ib, physicsClientId=client)
                exact = min((p[8] for p in pts), default=np.inf)
                assert exact >= bounds[check.group] - 1e-9, check


def test_stepping_matches_the_plain_simulator_step_by_step() -> None:
    cell = load_cell("triple_ur5")
    rng = np.random.default_rng(11)
    start = _random_q(cell, rng, 1.0)
    with CellSimulator(cell, substeps=1) as plain, BroadPhaseSimulator(cell, substeps=1) as fast:
        plain.reset(start)
        fast.reset(start)
        hits = 0
        for _ in range(300):
            u = {a.arm_id: rng.uniform(-1.0, 1.0, a.robot.dof) for a in cell.arms}
            expected, got = plain.step(u, 0.05), fast.step(u, 0.05)
            assert got.collisions == expected.collisions
            assert got.time == expected.time
            for a in cell.arm_ids:
                np.testing.assert_array_equal(fast.q[a], plain.q[a])
            hits += expected.collided
        assert hits > 0


def test_spheres_cover_every_link() -> None:
    cell = load_cell("triple_ur5")
    spheres = link_spheres(cell.arm("ur5_0").robot)
    with BroadPhaseSimulator(cell, substeps=1) as sim:
        body, client = sim.world.body("ur5_0"), sim.world.client
        assert [s.link for s in spheres] == list(range(-1, pb.getNumJoints(body, client)))
        for name in cell.arm("ur5_0").robot.links:
            assert sim.world.link_index("ur5_0", name) in {s.link for s in spheres}
    for s in spheres:
        assert s.centers.shape == (len(s.radii), 3) and np.all(s.radii > 0)


def test_rotations_match_pybullet() -> None:
    rng = np.random.default_rng(5)
    q = rng.normal(size=(20, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    expected = [np.reshape(pb.getMatrixFromQuaternion(x), (3, 3)) for x in q]
    np.testing.assert_allclose(rotations(q), expected, atol=1e-12)
