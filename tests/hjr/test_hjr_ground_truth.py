"""Grid ground truth: boundary condition, monotonicity in τ, symmetry, cache, validation."""

from __future__ import annotations

from pathlib import Path

import hj_reachability  # noqa: F401  (a dependency: fail, never skip, when it is missing)
import numpy as np
import pytest
import torch

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.hjr.ground_truth import GroundTruth, cache_dir, ground_truth, validate
from nehmo_core.hjr.networks import NetworkSettings, ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import Air3D

TAUS = [0.0, 0.55, 1.1]


@pytest.fixture(scope="module")
def coarse(tmp_path_factory: pytest.TempPathFactory) -> tuple[GroundTruth, Path]:
    directory = tmp_path_factory.mktemp("gt")
    return ground_truth(
        Air3D(), (21, 21, 21), TAUS, accuracy="medium", directory=directory
    ), directory


def test_coarse_air3d_boundary_and_monotone(coarse: tuple[GroundTruth, Path]) -> None:
    truth, _ = coarse
    system = Air3D()
    boundary = system.boundary(torch.as_tensor(truth.states())).numpy().reshape(truth.shape)
    np.testing.assert_allclose(truth.value_at(0.0), boundary, atol=1e-6)
    assert np.all(np.diff(truth.values, axis=0) <= 1e-6)  # V non-increasing in τ
    assert (truth.value_at(1.1) <= 0).mean() > (truth.value_at(0.0) <= 0).mean()


def test_coarse_air3d_brt_shape(coarse: tuple[GroundTruth, Path]) -> None:
    truth, _ = coarse
    v = truth.value_at(1.1)
    x1, x2, x3 = truth.coordinate_vectors
    mid = len(x2) // 2
    # Symmetry V(x1, x2, x3) = V(x1, −x2, −x3) on the grid (x3 periodic, 21 points).
    flip = (len(x3) - np.arange(len(x3))) % len(x3)
    assert np.max(np.abs(v - v[:, ::-1, :][:, :, flip])) < 0.02
    # Head-on (θ ≈ π, the last x3 sample): the tube reaches far ahead of the evader (x1 > 0),
    # not behind it; heading the same way (θ = 0): barely larger than the target.
    head_on = v[:, mid, -1]
    assert head_on[x1 > 0.5].min() <= 0.0 and head_on[x1 < -0.5].min() > 0.0
    same = v[:, mid, np.argmin(np.abs(x3))]
    assert (same <= 0).sum() < (head_on <= 0).sum()


def test_cache_reuses_solution(coarse: tuple[GroundTruth, Path]) -> None:
    truth, directory = coarse
    files = list(Path(directory).glob("air3d_21x21x21_*.npz"))
    assert len(files) == 1
    again = ground_truth(Air3D(), (21, 21, 21), TAUS, accuracy="medium", directory=directory)
    np.testing.assert_array_equal(again.values, truth.values)
    assert again.solve_seconds == truth.solve_seconds


def test_validate_reports_errors(coarse: tuple[GroundTruth, Path]) -> None:
    truth, _ = coarse
    system = Air3D()
    network = ValueNetwork(
        system,
        "bc",
        NetworkSettings(width=8, hidden_layers=1),
        generator=torch.Generator().manual_seed(0),
    )
    with torch.no_grad():
        network.siren.output.weight.zero_()
        network.siren.output.bias.zero_()
    rows = validate(ValueFunction(network), truth=truth)  # V = l at every τ
    assert [r.tau for r in rows] == TAUS
    assert rows[0].mean_abs_error < 1e-5 and rows[0].falsely_safe == 0.0
    last = rows[-1]
    assert last.mean_abs_error > 0 and last.falsely_safe > 0 and last.falsely_unsafe == 0.0
    assert last.brt_volume_learned == pytest.approx(rows[0].brt_volume_true)
    with pytest.raises(InvalidValueError, match="tau"):
        validate(ValueFunction(network), truth=truth, taus=[0.3])


def test_bad_inputs_raise(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("NEHMO_CACHE", str(tmp_path))
    assert cache_dir() == tmp_path / "groundtruth"
    with pytest.raises(InvalidValueError, match="grid_shape"):
        ground_truth(Air3D(), (21, 21))
    with pytest.raises(InvalidValueError, match="taus"):
        ground_truth(Air3D(), (5, 5, 5), [0.1, 0.2])
    with pytest.raises(InvalidValueError, match="taus"):
        ground_truth(Air3D(), (5, 5, 5), [0.0, 2.0])
    with pytest.raises(UnknownNameError, match="very_high"):
        ground_truth(Air3D(), (5, 5, 5), [0.0], accuracy="ultra")
