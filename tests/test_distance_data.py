"""Distance data generation: a boundary request that cannot be met is an error, not a no-op."""

from __future__ import annotations

import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.distance_data import DatasetSpec, generate


def test_boundary_samples_without_near_contact_seeds_are_an_error() -> None:
    # with a 1 µm "near" band, 3 uniform draws hold no seed for the boundary samples
    spec = DatasetSpec(pair="ur5_ur5_opposite", n_uniform=3, n_boundary=10, seed=0, near=1e-6)
    with pytest.raises(InvalidValueError, match=r"n_boundary.*near-contact seeds"):
        generate(spec, workers=1)


def test_no_boundary_samples_asked_for_is_fine() -> None:
    spec = DatasetSpec(pair="ur5_ur5_opposite", n_uniform=3, n_boundary=0, seed=0)
    q, d = generate(spec, workers=1)
    assert q.shape == (3, 12) and d.shape == (3,)
