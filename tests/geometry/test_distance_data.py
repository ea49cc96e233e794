"""Distance data generation: a boundary request that cannot be met is an error, not a no-op."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from nehmo_core.cli import main as cli_main
from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.distance_data import DatasetSpec, generate


def test_boundary_samples_without_near_contact_seeds_are_an_error() -> None:
    # with a 1 µm "near" band, 3 uniform draws and a search of 3000 more hold no seed
    spec = DatasetSpec(
        pair="ur5_ur5_opposite", n_uniform=3, n_boundary=10, seed=0, near=1e-6, seed_search=3000
    )
    with pytest.raises(InvalidValueError, match=r"n_boundary.*near-contact seeds.*3000 uniform"):
        generate(spec, workers=1)


def test_rare_near_contact_is_searched_for_beyond_the_uniform_set() -> None:
    # 3 uniform draws hold no state within 5 cm of contact; the search finds seeds and the
    # set keeps its own 3 uniform samples followed by the boundary samples
    spec = DatasetSpec(
        pair="ur5_ur5_opposite", n_uniform=3, n_boundary=20, seed=0, near=0.05, seed_search=9000
    )
    q, d = generate(spec, workers=1)
    assert q.shape == (23, 12) and d.shape == (23,)
    assert np.all(np.abs(d[:3]) >= 0.05)
    assert np.mean(np.abs(d[3:]) < 0.2) > 0.5


def test_no_boundary_samples_asked_for_is_fine() -> None:
    spec = DatasetSpec(pair="ur5_ur5_opposite", n_uniform=3, n_boundary=0, seed=0)
    q, d = generate(spec, workers=1)
    assert q.shape == (3, 12) and d.shape == (3,)


@pytest.mark.parametrize(
    ("args", "expected"),
    [
        (["--uniform", "abc"], "`--uniform` must be a count like"),
        (["--uniform", "0", "--boundary", "0"], "`--uniform` must be > 0 when no boundary"),
        (["--boundary", "1.5"], "`--boundary` must be a whole count >= 0"),
        (["--workers", "0"], "`--workers` must be >= 1"),
    ],
)
def test_generate_errors_name_the_option_typed(
    tmp_path: Path, capsys: pytest.CaptureFixture, args: list[str], expected: str
) -> None:
    out = tmp_path / "d.npz"
    assert cli_main(["distance", "generate", "--pair", "ur5_ur5", "--out", str(out), *args]) == 2
    assert expected in capsys.readouterr().err
    assert not out.exists()


def test_generate_counts_accept_suffixes_and_zero(tmp_path: Path) -> None:
    out = tmp_path / "d.npz"
    args = ["--pair", "ur5_ur5_opposite", "--uniform", "0.004k", "--boundary", "0"]
    assert cli_main(["distance", "generate", *args, "--workers", "1", "--out", str(out)]) == 0
    with np.load(out) as f:
        assert f["q"].shape == (4, 12)
