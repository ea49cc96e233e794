"""The shipped 12-D value functions: symmetry, gradients, boundary, safe loading."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.hjr.model_files import (
    SHIPPED_VALUE_FUNCTIONS,
    load_value_function,
    shipped_value_path,
)

SHIPPED = [
    (name, variant) for name, variants in SHIPPED_VALUE_FUNCTIONS.items() for variant in variants
]


@pytest.mark.parametrize(("name", "variant"), SHIPPED)
def test_every_listed_model_is_shipped(name: str, variant: str) -> None:
    path = shipped_value_path(name, variant)
    assert path.exists() and path.with_suffix(".json").exists()


def _states(vf, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:  # type: ignore[no-untyped-def]
    rng = np.random.default_rng(seed)
    system = vf.system
    x = rng.uniform(system.lower, system.upper, size=(count, system.state_dim))
    tau = rng.uniform(0.0, system.horizon, size=count)
    return tau, x


@pytest.mark.parametrize(("name", "variant"), SHIPPED)
def test_shipped_weights_load_as_the_named_model(name: str, variant: str) -> None:
    vf = load_value_function(name, variant=variant)
    assert vf.system.name == name and vf.network.variant == variant
    card = json.loads(shipped_value_path(name, variant).with_suffix(".json").read_text())
    assert card["system"]["name"] == name and card["settings"]["variant"] == variant


@pytest.mark.parametrize(("name", "variant"), [s for s in SHIPPED if s[1] == "bc+sym"])
def test_symmetric(name: str, variant: str) -> None:
    vf = load_value_function(name, variant=variant)
    tau, x = _states(vf, 2000, seed=1)
    fx = vf.system.symmetry(torch.as_tensor(x)).numpy()
    v, v_sym = vf.value(tau, x), vf.value(tau, fx)
    assert np.max(np.abs(v - v_sym)) <= 1e-5
    assert np.std(v) > 1e-2


@pytest.mark.parametrize(("name", "variant"), SHIPPED)
def test_gradient_matches_finite_differences(name: str, variant: str) -> None:
    vf = load_value_function(name, variant=variant)
    vf.network.double()
    boundary = vf.system.boundary_fn
    assert isinstance(boundary, torch.nn.Module)
    boundary.double()
    tau, x = _states(vf, 16, seed=2)
    if variant == "bc+sym":  # stay off the fold's seam, where V is only continuous
        x = vf.system.fold(torch.as_tensor(x)).numpy()
        x[:, vf.system.train_region.joint] = np.clip(x[:, vf.system.train_region.joint], -1.4, 1.4)
    _, grad = vf.value_and_gradient(tau, x)
    h = 1e-6
    for j in range(x.shape[1]):
        e = np.zeros(x.shape[1])
        e[j] = h
        fd = (vf.value(tau, x + e) - vf.value(tau, x - e)) / (2 * h)
        np.testing.assert_allclose(grad[:, j], fd, atol=2e-5, rtol=1e-4)


@pytest.mark.parametrize(("name", "variant"), [s for s in SHIPPED if s[1] != "deepreach"])
def test_boundary_condition_holds_at_zero_time_to_go(name: str, variant: str) -> None:
    vf = load_value_function(name, variant=variant)
    _, x = _states(vf, 500, seed=3)
    with torch.no_grad():
        lx = vf.system.boundary(torch.as_tensor(x, dtype=torch.float32)).numpy()
    v0 = vf.value(np.zeros(len(x)), x)
    assert np.mean(np.abs(v0 - lx)) < 0.01
    # Time-to-go only shrinks the safe set: V(τ, x) ≤ l(x) up to the fit error.
    assert np.mean(vf.value(np.full(len(x), vf.system.horizon), x) <= lx + 0.01) > 0.97


def test_shipped_names_and_variants_are_checked() -> None:
    with pytest.raises(UnknownNameError, match="ur5_ur5"):
        load_value_function("ur5_ur10")
    with pytest.raises(UnknownNameError, match="bc\\+sym"):
        load_value_function("ur5_kinova", variant="deepreach")
    with pytest.raises(InvalidValueError, match="variant"):
        load_value_function("/some/run", variant="bc")
