"""Any layout for a UR5 and a Kinova: the pose-conditioned ``ur5_kinova_any`` pair and its
Kinova-controls game ``kinova_ur5_any``, on untrained networks (no weights are shipped)."""

from __future__ import annotations

import copy
import dataclasses
import json
import math
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import torch

from nehmo_core.cli import main as cli_main
from nehmo_core.errors import ModelFileError, NehmoError, UnknownNameError
from nehmo_core.geometry import distance_data as dd
from nehmo_core.geometry import distance_model as dm
from nehmo_core.geometry.distance_model import (
    DistanceModelConfig,
    PairDistanceModel,
    load_distance_file,
)
from nehmo_core.geometry.distance_train import new_model
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.geometry.symmetry import robot_mirror_map
from nehmo_core.hjr import model_files
from nehmo_core.hjr.networks import NetworkSettings, ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import (
    ArmPairSystem,
    JointInterval,
    arm_pairs,
    make_system,
    system_names,
)
from nehmo_core.hjr.systems.arm_pairs import SwappedBoundary, make_arm_pair_system
from nehmo_core.planning.models import registry as planning_models
from nehmo_core.planning.models.pair_frame import match_pair
from nehmo_core.planning.models.registry import ModelRegistry, pair_geometry
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.robots import registry
from nehmo_core.robots.loader import load_cell, load_robot
from nehmo_core.robots.model import ArmSpec, Cell, Pose
from nehmo_core.verify.truth import exact_margin, pair_arms

UR5, KINOVA = load_robot("ur5"), load_robot("kinova_gen3_6dof")
SMALL = NetworkSettings(width=16, hidden_layers=1)
FACING = Pose((0.0, 0.0, 0.0), (0.0, 0.0, math.pi))


def _random_distance(seed: int = 0) -> PairDistanceModel:
    """An untrained ``ur5_kinova_any`` distance with random weights (a generic smooth MLP)."""
    model = new_model("ur5_kinova_any", (16, 16))
    generator = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.mlp.parameters():
            p.copy_(0.3 * torch.randn(p.shape, generator=generator, dtype=p.dtype))
    return model.eval()


@pytest.fixture
def untrained(monkeypatch: pytest.MonkeyPatch) -> Iterator[PairDistanceModel]:
    """``make_arm_pair_system`` builds the conditioned UR5-Kinova systems on a random distance."""
    model = _random_distance()
    real = arm_pairs.load_distance_model

    def load(pair: str) -> PairDistanceModel:
        return copy.deepcopy(model) if pair == "ur5_kinova_any" else real(pair)

    monkeypatch.setattr(arm_pairs, "load_distance_model", load)
    yield model


def _layout(r: float, rng: np.random.Generator) -> Cell:
    """A UR5 and a Kinova at base distance ``r`` [m], random place and yaws."""
    theta, yaw_u, yaw_k = rng.uniform(-np.pi, np.pi, 3)
    x0, y0 = rng.uniform(-1.0, 1.0, 2)
    kinova_at = (x0 + r * math.cos(theta), y0 + r * math.sin(theta), 0.0)
    return Cell(
        "layout",
        (
            ArmSpec("u", UR5, Pose((x0, y0, 0.0), (0.0, 0.0, yaw_u))),
            ArmSpec("k", KINOVA, Pose(kinova_at, (0.0, 0.0, yaw_k))),
        ),
    )


def _origins(robot_name: str, base: Pose, q: np.ndarray) -> np.ndarray:
    kin = ArmKinematics(load_robot(robot_name), base)
    with torch.no_grad():
        return kin.link_positions(torch.from_numpy(q[None])).numpy()[0]


# ---- names ---------------------------------------------------------------------------------


def test_the_pairs_are_known_and_name_their_files() -> None:
    assert dd.CONDITIONED_PAIRS["ur5_kinova_any"] == ("ur5", "kinova_gen3_6dof")
    assert dd.SWAPPED_PAIRS["kinova_ur5_any"] == "ur5_kinova_any"
    assert {"ur5_kinova_any", "kinova_ur5_any"} <= set(system_names())
    assert "ur5_kinova_any" in dm.DISTANCE_MODELS
    assert dm.distance_model_path("ur5_kinova_any").name == "distance_ur5_kinova_any.safetensors"
    for name in ("ur5_kinova_any", "kinova_ur5_any"):
        path = model_files.shipped_value_path(name, "bc+sym")
        assert path.name == f"value_{name}_bc_sym.safetensors"
        with pytest.raises(UnknownNameError, match=r"bc\+sym"):
            model_files.shipped_value_path(name, "bc")
    assert pair_geometry("ur5_kinova_any") == ("ur5", "kinova_gen3_6dof", FACING, dd.BASE_RANGE)
    robot1, robot2, base2, base_range = pair_geometry("kinova_ur5_any")  # type: ignore[misc]
    assert (robot1, robot2, base_range) == ("kinova_gen3_6dof", "ur5", dd.BASE_RANGE)
    np.testing.assert_allclose(base2.matrix(), FACING.matrix(), atol=1e-12)


def test_untrained_models_are_a_clear_error(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    for name in ("ur5_kinova_any", "kinova_ur5_any"):  # as if their files were elsewhere
        pair = registry.arm_pair(name)
        monkeypatch.setitem(registry._BY_NAME, name, dataclasses.replace(pair, folder=tmp_path))
    for name in ("ur5_kinova_any", "kinova_ur5_any"):  # as if not found at import
        monkeypatch.delitem(model_files.SHIPPED_VALUE_FUNCTIONS, name, raising=False)
    with pytest.raises(ModelFileError, match="nehmo distance train --pair ur5_kinova_any"):
        dm.load_distance_model("ur5_kinova_any")
    for name in ("ur5_kinova_any", "kinova_ur5_any"):
        with pytest.raises(ModelFileError, match="ur5_kinova_any"):
            make_system(name)
        with pytest.raises(ModelFileError, match=f"nehmo train --system {name} --variant bc"):
            model_files.load_value_function(name)
    with pytest.raises(UnknownNameError, match="ur5_kinova_any"):
        dm.load_distance_model("kinova_ur5_any")  # the swapped game has no distance of its own


def test_distance_cli_generates_trains_and_calibrates_the_pair(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    data, out = tmp_path / "d.npz", tmp_path / "distance_ur5_kinova_any.safetensors"
    pair = ["--pair", "ur5_kinova_any"]
    generate = ["--uniform", "300", "--boundary", "0", "--seed", "1", "--workers", "1"]
    assert cli_main(["distance", "generate", *pair, *generate, "--out", str(data)]) == 0
    with np.load(data) as f:
        q, d = f["q"], f["d"]
    assert q.shape == (300, 13) and d.shape == (300,)
    assert dd.BASE_RANGE[0] <= q[:, 12].min() and q[:, 12].max() <= dd.BASE_RANGE[1]
    more = tmp_path / "more.npz"
    generate[-3] = "2"  # another seed
    assert cli_main(["distance", "generate", *pair, *generate, "--out", str(more)]) == 0
    train = ["--hidden", "8", "--epochs", "1", "--out", str(out)]
    assert cli_main(["distance", "train", *pair, "--data", str(data), str(data), *train]) != 0
    assert "files must come from distinct seeds" in capsys.readouterr().err
    assert cli_main(["distance", "train", "--pair", "ur5_ur5_any", "--data", str(data), *train])
    assert "must hold samples of pair 'ur5_ur5_any'" in capsys.readouterr().err
    assert cli_main(["distance", "train", *pair, "--data", str(data), str(more), *train]) == 0
    card = json.loads(out.with_suffix(".json").read_text())
    assert [m["n"] for m in card["data"]["train"]] == [300, 300]
    assert card["training"]["calibration_samples"] == 30  # 5 % of the 600 joined samples
    calibrate = ["--data", str(data), "--model", str(out)]
    assert cli_main(["distance", "calibrate", *pair, *calibrate]) == 0
    model = load_distance_file(out, "ur5_kinova_any")
    assert (model.config.robot1, model.config.robot2) == ("ur5", "kinova_gen3_6dof")
    assert model.config.base2_range == dd.BASE_RANGE and model.dof == 13


# ---- exact geometry ------------------------------------------------------------------------


def test_pair_arms_swaps_the_arms_of_the_kinova_side() -> None:
    cell, a, b = pair_arms("kinova_ur5_any")
    assert (cell.arm(a).robot.name, cell.arm(b).robot.name) == ("kinova_gen3_6dof", "ur5")
    assert cell.arm(a).base == Pose()
    relative = np.linalg.inv(cell.arm(a).base.matrix()) @ cell.arm(b).base.matrix()
    np.testing.assert_allclose(relative, FACING.matrix(), atol=1e-12)
    fixed_cell, fa, fb = pair_arms("kinova_ur5")
    assert (fixed_cell.arm(fa).robot.name, fixed_cell.arm(fb).robot.name) == (
        "kinova_gen3_6dof",
        "ur5",
    )


def test_exact_margins_of_both_sides_are_the_real_cell(untrained: PairDistanceModel) -> None:
    """At r = 0.6 m both conditioned margins are the UR5-Kinova cell's distance; at any r the
    Kinova's side is the UR5's with the arms swapped; the ball-cover prefilter stays sound."""
    ur5_side = exact_margin(make_arm_pair_system("ur5_kinova_any"))
    kinova_side = exact_margin(make_arm_pair_system("kinova_ur5_any"))
    fixed = exact_margin(make_arm_pair_system("ur5_kinova"))
    try:
        rng = np.random.default_rng(3)
        q = rng.uniform(-np.pi, np.pi, size=(300, 12))
        at_cell = np.c_[q, np.full(len(q), 0.6)]
        np.testing.assert_allclose(ur5_side(at_cell, 1.0), fixed(q, 1.0), atol=1e-5)
        r = rng.uniform(*dd.BASE_RANGE, size=(len(q), 1))
        x_u = np.concatenate([q, r], axis=1)
        x_k = np.concatenate([q[:, 6:], q[:, :6], r], axis=1)
        d_u = ur5_side(x_u, 3.0)
        np.testing.assert_allclose(kinova_side(x_k, 3.0), d_u, atol=1e-5)
        assert (d_u <= 0).sum() > 5
        for margin, x in ((ur5_side, x_u), (kinova_side, x_k)):
            bound, exact = margin.lower_bound(x), margin(x, 3.0)
            apart = bound > 0.0
            assert apart.mean() > 0.3
            assert np.all(bound[apart] <= exact[apart] + 1e-9)
    finally:
        for m in (ur5_side, kinova_side, fixed):
            m.close()


def test_the_mirror_map_nearly_keeps_the_exact_distance_at_any_r(
    untrained: PairDistanceModel,
) -> None:
    """The bc+sym prior on the real geometry: the mirror y → −y keeps both bases on the x axis at
    every r, so the fixed UR5-Kinova pair's figures hold (the UR5 meshes are only nearly
    mirror-symmetric: mean 0.7 mm, max 3.3 cm there)."""
    for name in ("ur5_kinova_any", "kinova_ur5_any"):
        system = make_arm_pair_system(name)
        margin = exact_margin(system)
        try:
            rng = np.random.default_rng(2)
            x = np.c_[rng.uniform(-np.pi, np.pi, (400, 12)), rng.uniform(0.25, 1.0, 400)]
            mirrored = system.symmetry(torch.from_numpy(x)).numpy()
            d0, d1 = margin(x, 1.0), margin(mirrored, 1.0)
        finally:
            margin.close()
        near = d0 < 0.3
        err = np.abs(d0 - d1)[near]
        assert near.sum() > 100
        assert err.mean() < 0.002 and err.max() < 0.04


# ---- HJI systems ---------------------------------------------------------------------------


def test_both_systems_are_conditioned_and_mirror_symmetric(untrained: PairDistanceModel) -> None:
    ur5_side = make_arm_pair_system("ur5_kinova_any")
    kinova_side = make_arm_pair_system("kinova_ur5_any")
    assert isinstance(kinova_side.boundary_fn, SwappedBoundary)
    for system in (ur5_side, kinova_side):
        assert system.state_dim == 13 and system.conditions == (dd.BASE_RANGE,)
        assert system.periodic[12] is False
        x = system.sample_states(2000, torch.Generator().manual_seed(0))
        assert torch.equal(system.symmetry(x)[:, 12], x[:, 12])
        with torch.no_grad():
            diff = (system.boundary(x) - system.boundary(system.symmetry(x))).abs().max()
        assert float(diff) < 1e-4  # float32 model
        assert system.in_train(x).float().mean().item() == pytest.approx(0.5, abs=0.05)
    assert kinova_side.parameters()["symmetry_sign"] == [-1.0] * 12
    np.testing.assert_allclose(
        kinova_side.parameters()["symmetry_offset"],
        robot_mirror_map("kinova_gen3_6dof").offset + robot_mirror_map("ur5").offset,
    )
    x = kinova_side.sample_states(500, torch.Generator().manual_seed(1))
    swapped = torch.cat([x[:, 6:12], x[:, :6], x[:, 12:]], dim=1)
    with torch.no_grad():
        assert torch.equal(kinova_side.boundary(x), ur5_side.boundary(swapped))


def _value_function(name: str, seed: int = 2) -> ValueFunction:
    system = make_arm_pair_system(name)
    network = ValueNetwork(system, "bc+sym", SMALL, torch.Generator().manual_seed(seed))
    assert isinstance(system.boundary_fn, torch.nn.Module)
    system.boundary_fn.double()
    return ValueFunction(network.double())


def test_swapped_conditioned_value_model_exports_with_its_geometry(
    untrained: PairDistanceModel,
) -> None:
    vf = _value_function("kinova_ur5_any")
    model = PairValueModel.from_value_function(vf, "test_kinova_ur5_any", backend="vm")
    robot1, robot2, base2, base_range = model.geometry
    assert (robot1, robot2, base_range, model.state_dim) == (
        "kinova_gen3_6dof",
        "ur5",
        dd.BASE_RANGE,
        13,
    )
    np.testing.assert_allclose(base2.matrix(), FACING.matrix(), atol=1e-12)
    rng = np.random.default_rng(7)
    x = np.c_[rng.uniform(-np.pi, np.pi, (30, 12)), rng.uniform(*dd.BASE_RANGE, 30)]
    v, g = model.evaluate(0.25, x)
    ref_v, ref_g = vf.value_and_gradient(0.25, x)
    np.testing.assert_allclose(v, ref_v, atol=1e-8, rtol=0)
    np.testing.assert_allclose(g, ref_g, atol=1e-8, rtol=0)


def test_a_swapped_conditioned_pair_must_face_along_x() -> None:
    """Seen from arm 2, arm 1's base moves along x with r only when arm 2 faces arm 1."""
    config = DistanceModelConfig(
        "ur5",
        "kinova_gen3_6dof",
        (0.0, 0.0, 0.0),
        (0.0, 0.0, math.pi / 2),
        (16,),
        (20.0,),
        (0.3, 1.0),
    )
    distance = PairDistanceModel(config).double()
    mirror = robot_mirror_map("kinova_gen3_6dof") + robot_mirror_map("ur5")
    system = ArmPairSystem(
        conditions=((0.3, 1.0),),
        boundary_fn=SwappedBoundary(distance, 6, 6),
        n1=6,
        n2=6,
        symmetry_sign=np.array(mirror.sign),
        symmetry_offset=np.array(mirror.offset),
        train_region=JointInterval(joint=6, low=-np.pi / 2, high=np.pi / 2),
        system_name="sideways",
    )
    network = ValueNetwork(system, "bc", SMALL, torch.Generator().manual_seed(0))
    with pytest.raises(NehmoError, match=r"'test_sideways'.*face arm 1 along x"):
        PairValueModel.from_value_function(ValueFunction(network), "test_sideways", backend="vm")


# ---- mapping a cell ------------------------------------------------------------------------


def test_an_irregular_layout_maps_onto_the_conditioned_pair_from_either_side() -> None:
    """From the UR5's side onto ur5_kinova_any, from the Kinova's onto kinova_ur5_any, with the
    base distance as r; every link-origin distance between the arms is kept."""
    ur5_models = [pair_geometry("ur5_kinova"), pair_geometry("ur5_kinova_any")]
    kinova_models = [pair_geometry("kinova_ur5"), pair_geometry("kinova_ur5_any")]
    rng = np.random.default_rng(5)
    for _ in range(20):
        r = float(rng.uniform(*dd.BASE_RANGE))
        cell = _layout(r, rng)
        facing_at_r = Pose((r, 0.0, 0.0), (0.0, 0.0, math.pi))
        for own, peer, models in (("u", "k", ur5_models), ("k", "u", kinova_models)):
            own_arm, peer_arm = cell.arm(own), cell.arm(peer)
            mapping = match_pair(own_arm, peer_arm, models)
            assert mapping is not None and mapping.model_index == 1
            assert mapping.condition == pytest.approx([r], abs=1e-12)
            q_own = rng.uniform(-np.pi, np.pi, own_arm.robot.dof)
            q_peer = rng.uniform(-np.pi, np.pi, peer_arm.robot.dof)
            x = mapping.state(q_own, q_peer)
            n1 = own_arm.robot.dof
            real = np.linalg.norm(
                _origins(own_arm.robot.name, own_arm.base, q_own)[:, None]
                - _origins(peer_arm.robot.name, peer_arm.base, q_peer)[None],
                axis=-1,
            )
            canonical = np.linalg.norm(
                _origins(own_arm.robot.name, Pose(), x[:n1])[:, None]
                - _origins(peer_arm.robot.name, facing_at_r, x[n1:-1])[None],
                axis=-1,
            )
            assert np.abs(real - canonical).max() < 1e-7


def test_the_fixed_models_keep_the_ur5_kinova_cell_and_the_range_is_kept() -> None:
    cell = load_cell("ur5_kinova")
    u, k = cell.arm("ur5_0"), cell.arm("kinova_0")
    ur5_models = [pair_geometry("ur5_kinova"), pair_geometry("ur5_kinova_any")]
    kinova_models = [pair_geometry("kinova_ur5"), pair_geometry("kinova_ur5_any")]
    for own, peer, models in ((u, k, ur5_models), (k, u, kinova_models)):
        mapping = match_pair(own, peer, models)
        assert mapping is not None and mapping.model_index == 0 and len(mapping.condition) == 0
        assert match_pair(own, peer, models[1:]) is not None  # 0.6 m is in the range too
    rng = np.random.default_rng(0)
    for r in (dd.BASE_RANGE[0] - 0.05, dd.BASE_RANGE[1] + 0.05):
        out = _layout(r, rng)
        assert match_pair(out.arm("u"), out.arm("k"), ur5_models[1:]) is None
        assert match_pair(out.arm("k"), out.arm("u"), kinova_models[1:]) is None


# ---- the registry --------------------------------------------------------------------------

IRREGULAR = Cell(
    "irregular_ur5_kinova",
    (
        ArmSpec("u", UR5, Pose((0.0, 0.0, 0.0), (0.0, 0.0, 0.4))),
        ArmSpec("k", KINOVA, Pose((0.9, 0.2, 0.0), (0.0, 0.0, 2.0))),
    ),
)


def test_the_registry_uses_the_conditioned_models_only_when_present(
    monkeypatch: pytest.MonkeyPatch, untrained: PairDistanceModel
) -> None:
    shipped = planning_models.SHIPPED_VALUE_FUNCTIONS
    for name in ("ur5_kinova_any", "kinova_ur5_any"):
        monkeypatch.delitem(shipped, name, raising=False)
    registry = ModelRegistry(backend="vm")
    # not trained: as before, the fixed models only; the irregular pair then fits none of them
    assert registry.sources_for("nehmo", IRREGULAR) == ["ur5_kinova", "kinova_ur5"]
    shipped_models = registry.models_for("nehmo", IRREGULAR)
    for own, peer in (("u", "k"), ("k", "u")):
        planner = NehmoPlanner(IRREGULAR, own, shipped_models)
        assert planner.peers_unmodelled == (peer,) and not planner.pairs

    # trained and in models/ (here: untrained stand-ins): each side uses its conditioned model
    for name in ("ur5_kinova_any", "kinova_ur5_any"):
        monkeypatch.setitem(shipped, name, ("bc+sym",))
    assert registry.sources_for("nehmo", IRREGULAR) == [
        "ur5_kinova",
        "ur5_kinova_any",
        "kinova_ur5",
        "kinova_ur5_any",
    ]
    assert registry.sources_for("nehmo", load_cell("ur5_kinova")) == ["ur5_kinova", "kinova_ur5"]
    assert registry.sources_for("nehmo_no_sym", IRREGULAR) == ["ur5_kinova", "kinova_ur5"]

    def stand_in(source: str, variant: str | None = None) -> ValueFunction:
        assert variant == "bc+sym"
        return _value_function(source)

    monkeypatch.setattr(planning_models, "load_value_function", stand_in)
    loaded = registry.models_for("nehmo", IRREGULAR)
    r = float(np.hypot(0.9, 0.2))
    for own, peer, name in (("u", "k", "ur5_kinova_any"), ("k", "u", "kinova_ur5_any")):
        planner = NehmoPlanner(IRREGULAR, own, loaded)
        assert not planner.peers_unmodelled
        mapping = planner.pairs[peer]
        assert mapping.condition == pytest.approx([r])
        assert loaded[mapping.model_index].name == f"nehmo_{name}_bc_sym"
