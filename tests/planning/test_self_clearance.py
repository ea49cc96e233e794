"""Self-clearance rows: exact gradients, feasibility of y = 0, and closed-loop self-safety."""

from __future__ import annotations

import numpy as np
import pybullet as pb
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.geometry.world_pool import WorldPool
from nehmo_core.planning.settings import PlannerSettings, SelfClearanceSettings
from nehmo_core.planning.stages import self_clearance
from nehmo_core.planning.stages.self_clearance import SelfClearance, project_step
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose

ROBOTS = ("ur5", "kinova_gen3_6dof")


@pytest.fixture(scope="module", params=ROBOTS)
def clearance(request: pytest.FixtureRequest) -> SelfClearance:
    sc = SelfClearance(load_robot(request.param), SelfClearanceSettings(influence=0.3))
    yield sc
    sc.close()


def test_instances_share_one_world_per_robot_and_the_last_close_ends_it(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(self_clearance, "WORLDS", WorldPool())  # no users left by other tests
    a, b = SelfClearance(load_robot("ur5")), SelfClearance(load_robot("ur5"))
    client = a._world.client
    assert b._world is a._world
    q = np.array([0.0, -1.0, 2.0, 0.0, 0.5, 0.0])  # wrist 1 about 5 cm from the end effector
    before = a.rows(q)  # b has not asked yet: its answer below is a fresh query of the world
    assert before.pairs == (("wrist_1_link", "ee_link"),)
    a.close()
    a.close()  # twice is harmless
    assert pb.isConnected(physicsClientId=client)
    after = b.rows(q)  # still usable: the same rows from the world a no longer uses
    assert after.pairs == before.pairs
    np.testing.assert_allclose(after.distances, before.distances, atol=1e-9)
    assert 0.0 < after.distances[0] < b.influence
    np.testing.assert_allclose(after.A, before.A, atol=1e-9)
    b.close()
    assert not pb.isConnected(physicsClientId=client)


def _random_q(robot, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(np.maximum(robot.lower, -np.pi), np.minimum(robot.upper, np.pi))


def test_row_gradients_match_finite_differences(clearance: SelfClearance) -> None:
    robot, rng, h = clearance.robot, np.random.default_rng(7), 1e-4
    checked = 0
    for _ in range(25):
        q = _random_q(robot, rng)
        rows = clearance.rows(q)
        for grad, d, pair in zip(rows.A, rows.distances, rows.pairs, strict=True):
            if d < 0.005:  # in or at contact the witness points may jump
                continue
            fd = np.empty(robot.dof)
            for j in range(robot.dof):
                step = np.zeros(robot.dof)
                step[j] = h
                ahead, behind = clearance.distances(q + step), clearance.distances(q - step)
                fd[j] = (ahead[pair] - behind[pair]) / (2 * h)
            np.testing.assert_allclose(grad, fd, atol=2e-3, err_msg=str(pair))
            checked += 1
    assert checked > 20


def test_row_gradients_equal_pybullets_jacobians(clearance: SelfClearance) -> None:
    """The rows' ``nᵀ(J_a − J_b)`` from joint axes equal PyBullet's own point Jacobians (up to
    PyBullet's single-precision transforms, ~1e-7)."""
    robot, rng = clearance.robot, np.random.default_rng(5)
    body, client = clearance._body, clearance._client
    movable = [
        j
        for j in range(pb.getNumJoints(body, physicsClientId=client))
        if pb.getJointInfo(body, j, physicsClientId=client)[2] != pb.JOINT_FIXED
    ]
    columns = [movable.index(j) for j in clearance._world.joint_indices("self")]

    def jacobian(link: int, point: np.ndarray, q_all: list[float]) -> np.ndarray:
        if link < 0:
            return np.zeros((3, robot.dof))
        state = pb.getLinkState(body, link, computeForwardKinematics=True, physicsClientId=client)
        inv = pb.invertTransform(state[4], state[5])
        local = pb.multiplyTransforms(*inv, point.tolist(), (0, 0, 0, 1))[0]
        zeros = [0.0] * len(q_all)
        lin, _ = pb.calculateJacobian(
            body, link, local, q_all, zeros, zeros, physicsClientId=client
        )
        return np.asarray(lin)[:, columns]

    links = {(a, b): (la, lb) for a, b, la, lb in clearance._pairs}
    checked = 0
    for _ in range(20):
        q = _random_q(robot, rng)
        rows = clearance.rows(q)
        q_all = [pb.getJointState(body, j, physicsClientId=client)[0] for j in movable]
        for grad, pair in zip(rows.A, rows.pairs, strict=True):
            la, lb = links[pair]
            pts = pb.getClosestPoints(
                body, body, clearance.influence, la, lb, physicsClientId=client
            )
            p = min(pts, key=lambda h: h[8])
            p_a, p_b, normal = np.array(p[5]), np.array(p[6]), np.array(p[7])
            if clearance._swapped[pair]:
                p_a, p_b, normal = p_b, p_a, -normal
            expected = normal @ (jacobian(la, p_a, q_all) - jacobian(lb, p_b, q_all))
            np.testing.assert_allclose(grad, expected, atol=1e-6, err_msg=str(pair))
            checked += 1
    assert checked > 20


def test_rows_admit_standing_still_and_projection_keeps_them(clearance: SelfClearance) -> None:
    robot, rng = clearance.robot, np.random.default_rng(3)
    y_max = 0.05
    projected = 0
    for _ in range(40):
        q = _random_q(robot, rng)
        rows = clearance.rows(q)
        assert np.all(rows.b <= 0.0)
        assert rows.satisfied(np.zeros(robot.dof))
        target = rng.uniform(-y_max, y_max, robot.dof)
        y = project_step(target, rows, y_max)
        assert rows.satisfied(y, tol=1e-8)
        assert np.all(np.abs(y) <= y_max + 1e-12)
        if rows.satisfied(target):
            np.testing.assert_array_equal(y, target)
        else:
            projected += 1
            assert np.linalg.norm(y - target) > 0
    assert projected > 0


def _min_self_distance(world: CellWorld) -> float:
    return min((c.distance for c in world.collisions(margin=0.3)), default=0.3)


@pytest.mark.parametrize("robot_name", ROBOTS)
def test_damped_commands_keep_a_folding_arm_off_itself(robot_name: str) -> None:
    """Full speed on every joint toward folding: with the rows the arm never touches itself."""
    robot = load_robot(robot_name)
    settings = PlannerSettings()
    clearance = SelfClearance(robot, settings.self_clearance)
    world = CellWorld(Cell("one", (ArmSpec("arm", robot, Pose()),)))
    dt, t_plan, u_max = 0.01, settings.opt.t_plan, settings.opt.u_max
    rng = np.random.default_rng(11)
    undamped_hits = 0
    try:
        for _ in range(6):
            q0 = _random_q(robot, rng) * 0.5
            world.set_joint_positions("arm", q0)
            if world.in_collision():
                continue
            direction = u_max * np.sign(rng.standard_normal(robot.dof))
            for damped in (True, False):
                q = q0.copy()
                for tick in range(400):  # 4 s at full speed
                    u = direction
                    if damped and tick % 4 == 0:  # re-planned at 25 Hz, held in between
                        rows = clearance.rows(q)
                        held = project_step(t_plan * direction, rows, t_plan * u_max) / t_plan
                    u = held if damped else direction
                    q = np.clip(q + dt * u, robot.lower, robot.upper)
                    world.set_joint_positions("arm", q)
                    hit = world.in_collision()
                    if damped:
                        assert not hit, f"self-collision at tick {tick}: {world.collisions()}"
                    elif hit:
                        undamped_hits += 1
                        break
    finally:
        clearance.close()
        world.close()
    assert undamped_hits > 0  # the scenario does fold the arm without the rows


def test_settings_reject_bad_self_clearance_values() -> None:
    with pytest.raises(InvalidValueError, match=r"self_clearance\.influence"):
        PlannerSettings().override(
            {"self_clearance.influence": 0.01, "self_clearance.safety": 0.02}
        )
    with pytest.raises(InvalidValueError, match=r"self_clearance\.gain"):
        PlannerSettings().override({"self_clearance.gain": 0.0})
    assert PlannerSettings.preset("paper").self_clearance.enabled is False
    assert PlannerSettings().self_clearance.enabled is True


@pytest.mark.parametrize("robot_name", ROBOTS)
def test_the_lipschitz_bounds_hold_between_nearby_configurations(robot_name: str) -> None:
    """|d(q) − d(q')| ≤ Σ_j bound_j·|q_j − q'_j| for every pair, on random nearby pairs of
    configurations (distances read with a 2 m influence, so every pair has one)."""
    far = SelfClearance(load_robot(robot_name), SelfClearanceSettings(influence=2.0))
    rng, checked = np.random.default_rng(11), 0
    try:
        for _ in range(150):
            q = _random_q(far.robot, rng)
            q2 = q + rng.uniform(-0.3, 0.3, size=far.robot.dof)
            d, d2 = far.distances(q), far.distances(q2)
            for p, (a, b, _, _) in enumerate(far._pairs):
                if (a, b) in d and (a, b) in d2:
                    bound = float(far._slope[p] @ np.abs(q2 - q))
                    assert abs(d2[(a, b)] - d[(a, b)]) <= bound + 1e-6, (a, b)
                    checked += 1
    finally:
        far.close()
    assert checked > 1000


@pytest.mark.parametrize("robot_name", ROBOTS)
def test_pairs_skipped_by_their_bound_give_the_same_rows_as_asking_every_pair(
    robot_name: str,
) -> None:
    """Along random walks (small steps, now and then a jump), the rows with the bound's skips
    equal those of a fresh query of every pair; and most pair queries are skipped."""
    robot = load_robot(robot_name)
    skipping, exact = SelfClearance(robot), SelfClearance(robot)
    rng = np.random.default_rng(3)
    try:
        skipping.queries, ticks = 0, 0
        for _ in range(6):
            q = _random_q(robot, rng)
            for _ in range(40):
                q = np.clip(q + rng.uniform(-0.04, 0.04, size=robot.dof), robot.lower, robot.upper)
                if rng.random() < 0.05:
                    q = _random_q(robot, rng)
                exact._ref_q[:] = np.nan  # forget every earlier query: ask all pairs
                got, want = skipping.rows(q), exact.rows(q)
                assert got.pairs == want.pairs
                np.testing.assert_array_equal(got.A, want.A)
                np.testing.assert_array_equal(got.b, want.b)
                ticks += 1
        assert skipping.queries < 0.6 * ticks * len(skipping._pairs)
    finally:
        skipping.close()
        exact.close()


# dual_panda seed 81, scenario 76: panda_1 2.45 rad from its goal, its hand 5.0 mm (the safety
# distance) from link 2, 25 cm from its peer; its goal 1.2 cm clear of itself, the straight
# joint path there at least 4.9 mm clear
_RESTING = [
    -0.510291135,
    -0.869077967,
    1.243926687,
    -2.729714457,
    0.04734492,
    0.235777008,
    0.134681717,
]
_RESTING_GOAL = [
    -1.317256487,
    -0.928288996,
    1.983592259,
    -2.881063728,
    -2.100300735,
    0.299822464,
    0.545511224,
]


def test_an_arm_resting_at_the_safety_distance_can_leave_it() -> None:
    """At ``d = safety`` a row allows no closing to first order and the distance's curvature
    closes it by µm along the step: the exact check lets that reach ``slack`` below safety,
    no further; without the slack it refused every step and the arm never moved again."""
    from nehmo_core.planning.nehmo import NehmoPlanner

    cell = Cell("one_panda", (ArmSpec("panda_0", load_robot("panda"), Pose()),))
    q, goal = np.array(_RESTING), np.array(_RESTING_GOAL)
    moved = {}
    for slack in (0.001, 0.0):  # the opening (next test) would free it too: off here
        settings = PlannerSettings().override(
            {"self_clearance.slack": slack, "self_clearance.opening": 0.0}
        )
        planner = NehmoPlanner(cell, "panda_0", [], settings)
        stage = planner.stage("self_clearance")
        assert isinstance(stage, SelfClearance)
        assert min(stage.distances(q).values()) == pytest.approx(0.005, abs=1e-5)
        u = planner.plan(q, {}, goal).velocity
        end = stage.distances(q + settings.opt.tick * u)
        assert min(end.values()) >= 0.005 - slack - 1e-6
        moved[slack] = float(np.abs(u).max())
        planner.close()
    assert moved[0.001] == pytest.approx(0.5)  # full speed toward the goal
    assert moved[0.0] == 0.0  # the old check: stuck for good


# two Panda poses where every share of the step Opt returned failed the exact check (the
# distance's curvature closed a pair at 4.0-4.1 mm by up to 0.8 mm in one tick) and the arm stood
# still ~2 rad from its goal for the rest of the episode (dual_panda, development seeds 63 and
# 62, scenarios 97 and 12, panda_1 at 12 s): pose, goal
_CURVED = [
    (
        [
            -1.267547043,
            -0.858578289,
            -0.542957265,
            -2.799908749,
            -0.233887541,
            0.642248182,
            1.162305314,
        ],
        [
            -1.287547043,
            -0.797973111,
            -0.525630564,
            -2.969980977,
            -2.250058394,
            0.053169357,
            2.627594548,
        ],
    ),
    (
        [2.690657582, 1.588406487, 0.28267355, -2.371826514, 1.436034231, 2.682904852, 2.506537501],
        [2.689886121, 1.6324975, 2.20001091, -2.930633577, 1.450737044, 2.687221285, 2.506537501],
    ),
]


@pytest.mark.parametrize("case", range(len(_CURVED)))
def test_a_step_the_exact_check_refuses_is_turned_to_open_the_pair(case: int) -> None:
    """When no share of the step passes the exact check, the command nearest it that opens the
    near pairs (to first order) is checked instead: the arm keeps moving toward its goal and no
    pair ends below its floor, tick after tick; without it the arm stays still."""
    from nehmo_core.planning.nehmo import NehmoPlanner

    cell = Cell("one_panda", (ArmSpec("panda_0", load_robot("panda"), Pose()),))
    q0, goal = (np.array(v) for v in _CURVED[case])
    sc = PlannerSettings().self_clearance
    floor = min(min(_distances(q0)), sc.safety - sc.slack) - 1e-6
    for opening in (sc.opening, 0.0):
        settings = PlannerSettings().override({"self_clearance.opening": opening})
        planner = NehmoPlanner(cell, "panda_0", [], settings)
        stage = planner.stage("self_clearance")
        assert isinstance(stage, SelfClearance)
        q, pending = q0.copy(), np.zeros(7)
        for _ in range(25):  # a command planned at one tick runs during the next
            u = np.asarray(planner.plan(q, {}, goal).velocity)
            q, pending = q + settings.opt.tick * pending, u
            assert min(stage.distances(q).values()) >= floor
        planner.close()
        progress = np.linalg.norm(q0 - goal) - np.linalg.norm(q - goal)
        if opening:
            assert progress > 0.3  # 1 s of motion
        else:
            assert progress == 0.0  # the old filter: stuck for good


def _distances(q: np.ndarray) -> list[float]:
    stage = SelfClearance(load_robot("panda"))
    try:
        return list(stage.distances(q).values())
    finally:
        stage.close()
