"""Value networks: variants, symmetry invariance, gradients vs finite differences, errors."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.hjr.networks import NetworkSettings, Siren, ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import Air3D, HJISystem, TwoLinkPair


def _value_function(system: HJISystem, variant: str, seed: int = 0) -> ValueFunction:
    generator = torch.Generator().manual_seed(seed)
    settings = NetworkSettings(width=32, hidden_layers=2)
    network = ValueNetwork(system, variant, settings, generator)
    # Perturb the SIREN so the residual is far from zero (it starts small by construction).
    with torch.no_grad():
        network.siren.output.weight.mul_(20.0)
    return ValueFunction(network)


def _random_inputs(system: HJISystem, count: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    x = rng.uniform(system.lower, system.upper, size=(count, system.state_dim))
    tau = rng.uniform(0.0, system.horizon, size=count)
    return tau, x


@pytest.mark.parametrize("system", [Air3D(), TwoLinkPair()], ids=["air3d", "two_link"])
def test_bc_sym_value_is_symmetric(system: HJISystem) -> None:
    vf = _value_function(system, "bc+sym")
    tau, x = _random_inputs(system, 2000, seed=1)
    fx = system.symmetry(torch.as_tensor(x)).numpy()
    v, v_sym = vf.value(tau, x), vf.value(tau, fx)
    assert np.max(np.abs(v - v_sym)) <= 1e-5
    assert np.std(v) > 1e-2  # the check is not vacuous


@pytest.mark.parametrize("variant", ["deepreach", "bc", "bc+sym", "exact"])
@pytest.mark.parametrize("system", [Air3D(), TwoLinkPair()], ids=["air3d", "two_link"])
def test_gradient_matches_central_differences(system: HJISystem, variant: str) -> None:
    vf = _value_function(system, variant)
    vf.network.double()
    tau, x = _random_inputs(system, 64, seed=2)
    grad = vf.gradient(tau, x)
    step = 1e-6
    for i in range(system.state_dim):
        e = np.zeros(system.state_dim)
        e[i] = step
        fd = (vf.value(tau, x + e) - vf.value(tau, x - e)) / (2 * step)
        # The two-link boundary has kinks (min over link pairs, clamps): skip the few states
        # whose stencil straddles one, seen as a mismatch in one-sided differences.
        left = (vf.value(tau, x) - vf.value(tau, x - e)) / step
        right = (vf.value(tau, x + e) - vf.value(tau, x)) / step
        smooth = np.abs(left - right) < 1e-4 * (1 + np.abs(fd))
        assert smooth.mean() > 0.9
        np.testing.assert_allclose(grad[smooth, i], fd[smooth], rtol=1e-5, atol=1e-6)


def test_bc_and_exact_meet_the_boundary_at_tau_zero() -> None:
    system = TwoLinkPair()
    _, x = _random_inputs(system, 100, seed=3)
    lx = system.boundary(torch.as_tensor(x)).numpy()
    np.testing.assert_allclose(_value_function(system, "exact").value(0.0, x), lx, atol=1e-5)
    assert np.max(np.abs(_value_function(system, "bc").value(0.0, x) - lx)) > 1e-3
    tau = np.full(100, 0.3)
    assert np.max(np.abs(_value_function(system, "exact").value(tau, x) - lx)) > 1e-3


def test_air3d_value_is_denormalized() -> None:
    system = Air3D()
    vf = _value_function(system, "bc")
    _, x = _random_inputs(system, 50, seed=4)
    with torch.no_grad():
        vf.network.siren.output.weight.zero_()
        vf.network.siren.output.bias.zero_()
    lx = system.boundary(torch.as_tensor(x)).numpy()
    np.testing.assert_allclose(vf.value(0.5, x), lx, atol=1e-5)  # V = l when the residual is 0


def test_value_function_shapes_and_types() -> None:
    system = TwoLinkPair()
    vf = _value_function(system, "bc+sym")
    x = np.zeros(4)
    assert isinstance(vf.value(0.1, x), np.floating | float)
    assert vf.gradient(0.1, x).shape == (4,)
    xt = torch.zeros(5, 4)
    assert isinstance(vf.value(torch.tensor(0.2), xt), torch.Tensor)
    assert vf.value(np.full(5, 0.2), np.zeros((5, 4))).shape == (5,)


def test_siren_initialization_bounds() -> None:
    siren = Siren(
        5, NetworkSettings(width=64, hidden_layers=2), generator=torch.Generator().manual_seed(0)
    ).requires_grad_(False)
    first, second = siren.hidden[0], siren.hidden[1]
    assert isinstance(first, torch.nn.Linear) and isinstance(second, torch.nn.Linear)
    assert float(first.weight.abs().max()) <= 1 / 5
    bound = math.sqrt(6 / 64) / 30
    assert float(second.weight.abs().max()) <= bound
    assert float(siren.output.weight.abs().max()) <= bound
    assert len(siren.hidden) == 3


def test_bad_inputs_raise() -> None:
    system = TwoLinkPair()
    with pytest.raises(UnknownNameError, match=r"bc\+sym"):
        ValueNetwork(system, "sym")
    with pytest.raises(UnknownNameError, match="unit"):
        NetworkSettings(input_scaling="degrees")
    with pytest.raises(InvalidValueError, match="width"):
        NetworkSettings(width=0)
    vf = _value_function(system, "bc")
    with pytest.raises(InvalidValueError, match=r"tau"):
        vf.value(1.0, np.zeros((2, 4)))
    with pytest.raises(InvalidValueError, match=r"tau"):
        vf.value(np.zeros(3), np.zeros((2, 4)))
    with pytest.raises(InvalidValueError, match=r"\(B, 4\)"):
        vf.value(0.1, np.zeros((2, 3)))
