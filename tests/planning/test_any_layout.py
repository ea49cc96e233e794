"""Any layout: the pose-conditioned pair frame, distance model, HJI system and planners."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.geometry import distance_data as dd
from nehmo_core.geometry.distance_casadi import distance_function
from nehmo_core.geometry.distance_model import load_distance_model
from nehmo_core.geometry.distance_train import new_model
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.hjr.systems.arm_pairs import make_arm_pair_system
from nehmo_core.hjr.train import resolve_device
from nehmo_core.planning.models.pair_frame import match_pair
from nehmo_core.planning.models.registry import ModelRegistry, pair_geometry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.robots.loader import cell_from_dict, load_cell, load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose

UR5 = load_robot("ur5")
ANY = pair_geometry("ur5_ur5_any")


def _random_cell(rng: np.random.Generator, r: float) -> Cell:
    theta, yaw1, yaw2 = rng.uniform(-np.pi, np.pi, 3)
    x0, y0 = rng.uniform(-1, 1, 2)
    return Cell(
        "random",
        (
            ArmSpec("a", UR5, Pose((x0, y0, 0.0), (0.0, 0.0, yaw1))),
            ArmSpec(
                "b",
                UR5,
                Pose((x0 + r * math.cos(theta), y0 + r * math.sin(theta), 0.0), (0.0, 0.0, yaw2)),
            ),
        ),
    )


def _origins(robot_base: Pose, q: np.ndarray) -> np.ndarray:
    kin = ArmKinematics(UR5, robot_base)
    with torch.no_grad():
        return kin.link_positions(torch.from_numpy(q[None])).numpy()[0]


def test_a_conditioned_mapping_preserves_every_link_to_link_distance() -> None:
    """Cell pair at any base distance and yaws ≡ the canonical frame (peer at (r, 0, 0) facing)
    with the mapped joints: every link-origin distance between the arms is the same."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        r = rng.uniform(*dd.BASE_RANGE)
        cell = _random_cell(rng, r)
        own, peer = cell.arms
        mapping = match_pair(own, peer, [ANY])
        assert mapping is not None
        assert mapping.condition == pytest.approx([r])
        q1, q2 = rng.uniform(-np.pi, np.pi, (2, 6))
        x = mapping.state(q1, q2)
        real = np.linalg.norm(
            _origins(own.base, q1)[:, None] - _origins(peer.base, q2)[None], axis=-1
        )
        canon = np.linalg.norm(
            _origins(Pose(), x[:6])[:, None]
            - _origins(Pose((r, 0.0, 0.0), (0.0, 0.0, math.pi)), x[6:12])[None],
            axis=-1,
        )
        assert np.abs(real - canon).max() < 1e-9


def test_pairs_outside_the_range_or_height_do_not_map() -> None:
    rng = np.random.default_rng(0)
    near = _random_cell(rng, dd.BASE_RANGE[0] - 0.05)
    assert match_pair(near.arms[0], near.arms[1], [ANY]) is None
    far = _random_cell(rng, dd.BASE_RANGE[1] + 0.05)
    assert match_pair(far.arms[0], far.arms[1], [ANY]) is None
    raised = Cell(
        "raised",
        (ArmSpec("a", UR5, Pose()), ArmSpec("b", UR5, Pose((0.7, 0.0, 0.2), (0.0, 0.0, 1.0)))),
    )
    assert match_pair(raised.arms[0], raised.arms[1], [ANY]) is None


def test_fixed_models_take_precedence_at_their_distance() -> None:
    cell = load_cell("dual_ur5")
    models = [pair_geometry("ur5_ur5"), ANY]
    mapping = match_pair(cell.arms[0], cell.arms[1], models)
    assert mapping is not None and mapping.model_index == 0 and len(mapping.condition) == 0


def test_conditioned_features_equal_the_fixed_geometry_at_its_distance() -> None:
    """The conditioned model's keypoint distances at r = 0.6 are the dual-UR5 model's."""
    fixed, any_ = load_distance_model("ur5_ur5"), new_model("ur5_ur5_any", (16,))
    q = torch.from_numpy(np.random.default_rng(1).uniform(-np.pi, np.pi, (64, 12)))
    r = torch.full((64, 1), 0.6, dtype=torch.float64)
    f_any = any_.features(torch.cat([q, r], dim=1))
    f_fixed = fixed.features(q)
    assert torch.allclose(f_any[:, : f_fixed.shape[1]], f_fixed, atol=1e-12)
    assert torch.allclose(f_any[:, -1], r[:, 0])


def test_conditioned_casadi_graph_matches_torch() -> None:
    model = new_model("ur5_ur5_any", (32, 32))
    f = distance_function(model)
    rng = np.random.default_rng(2)
    for _ in range(5):
        q = np.append(rng.uniform(-np.pi, np.pi, 12), rng.uniform(*dd.BASE_RANGE))
        v, g = f(q)
        qt = torch.from_numpy(q[None]).requires_grad_(True)
        d = model(qt)
        (gt,) = torch.autograd.grad(d.sum(), qt)
        assert float(v) == pytest.approx(float(d.detach()), abs=1e-9)
        assert np.abs(np.asarray(g).ravel() - gt.numpy().ravel()).max() < 1e-9


@pytest.mark.parametrize(("fixed_pair", "tolerance"), [("ur5_ur5", 0.005), ("ur5_kinova", 0.003)])
def test_conditioned_labels_are_the_real_layouts_distances(
    fixed_pair: str, tolerance: float
) -> None:
    """Labels drawn at random base yaws equal the fixed 0.6 m cell's (dual UR5, UR5-Kinova) at
    r = 0.6 up to the base links' own shapes (the joint-1 shift turns everything above them
    exactly). Posed by its inertial frame, the Kinova stood 8.4 cm low (19 mm near contact)."""
    rng = np.random.default_rng(4)
    q = dd.uniform_samples(fixed_pair, 400, rng)
    fixed = dd.exact_distances(fixed_pair, q)
    conditioned = dd.labelled(f"{fixed_pair}_any", np.c_[q, np.full(len(q), 0.6)], rng)
    near = np.abs(fixed) < 0.1
    assert near.sum() > 30
    assert np.mean(np.abs(conditioned - fixed)[near]) < tolerance
    assert np.median(np.abs(conditioned - fixed)) < 1e-3


def test_conditioned_system_keeps_r_constant_and_in_range() -> None:
    system = make_arm_pair_system("ur5_ur5_any")
    assert system.state_dim == 13 and system.periodic[12] is False
    x = system.sample_states(500, torch.Generator().manual_seed(0))
    assert float(x[:, 12].min()) >= dd.BASE_RANGE[0] and float(x[:, 12].max()) <= dd.BASE_RANGE[1]
    u, d = torch.zeros(500, 6), torch.ones(500, 6)
    assert bool((system.dynamics(x, u, d)[:, 12] == 0).all())
    p = torch.randn(500, 13, generator=torch.Generator().manual_seed(5))
    p_no_r = p.clone()
    p_no_r[:, 12] = 0
    assert torch.allclose(system.hamiltonian(x, p), system.hamiltonian(x, p_no_r))
    assert torch.equal(system.symmetry(x)[:, 12], x[:, 12])
    with torch.no_grad():
        diff = (system.boundary(x) - system.boundary(system.symmetry(x))).abs().max()
    assert float(diff) < 1e-4


def test_irregular_cell_plans_with_the_conditioned_model_for_every_pair() -> None:
    cell = load_cell("examples/cells/irregular_three_ur5.yaml")
    models = ModelRegistry().models_for("nehmo", cell)
    names = [m.name for m in models]
    assert any("ur5_ur5_any" in n for n in names)
    planner = NehmoPlanner(cell, "ur5_0", models)
    assert set(planner.pairs) == {"ur5_1", "ur5_2"} and not planner.peers_unmodelled
    for mapping in planner.pairs.values():
        assert "ur5_ur5_any" in models[mapping.model_index].name
    q = {a.arm_id: np.zeros(6) for a in cell.arms}
    result = planner.plan(q["ur5_0"], {k: v for k, v in q.items() if k != "ur5_0"}, np.full(6, 0.3))
    assert np.all(np.abs(result.velocity) <= planner.settings.opt.u_max + 1e-9)


def test_a_pair_closer_than_the_range_is_reported_not_ignored() -> None:
    cell = cell_from_dict(
        {
            "name": "crowded",
            "arms": [
                {"id": "a", "robot": "ur5"},
                {"id": "b", "robot": "ur5", "base": {"xyz": [0.2, 0.0, 0.0]}},
            ],
        }
    )
    models = ModelRegistry().models_for("nehmo", cell)
    planner = NehmoPlanner(cell, "a", models)
    assert planner.peers_unmodelled == ("b",)
    from nehmo_core.eval.planners import build_planners
    from nehmo_core.sim.scenarios import Scenario

    zero = {"a": np.zeros(6), "b": np.zeros(6)}
    with pytest.raises(NehmoError, match="b"):
        build_planners(
            cell, {"a": "nehmo", "b": "nehmo"}, Scenario(zero, zero), 0.04, ModelRegistry()
        )


def test_device_cuda_without_a_device_is_a_clear_error() -> None:
    if torch.cuda.is_available():
        pytest.skip("a CUDA device is present here")
    with pytest.raises(InvalidValueError, match=r"device.*CUDA"):
        resolve_device("cuda")
    assert resolve_device("auto").type == "cpu"
    with pytest.raises(InvalidValueError, match="device"):
        resolve_device("tpu")
