"""HJI systems: closed-form Hamiltonians vs brute force, symmetry, boundary geometry, errors."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.hjr.systems import (
    Air3D,
    ArmPairSystem,
    HJISystem,
    JointInterval,
    TwoLinkDistance,
    TwoLinkPair,
    make_system,
    wrap_to_pi,
)


def _ur5_like_pair() -> ArmPairSystem:
    """A 6+6 pair with this project's UR5 mirror map and a symmetric toy boundary."""
    sign = np.array([-1.0, -1, -1, -1, -1, -1] * 2)
    offset = np.array([math.pi, math.pi, 0, math.pi, 0, math.pi] * 2)

    def boundary(x: torch.Tensor) -> torch.Tensor:  # invariant under that map by construction
        return torch.cos(x[:, 0] - x[:, 6]) + torch.sin(x[:, 1]) * torch.sin(x[:, 7])

    return ArmPairSystem(
        boundary_fn=boundary,
        n1=6,
        n2=6,
        symmetry_sign=sign,
        symmetry_offset=offset,
        train_region=JointInterval(6, -math.pi / 2, math.pi / 2),
        system_name="toy_ur5",
    )


SYSTEMS = [Air3D(), TwoLinkPair(), _ur5_like_pair()]
IDS = ["air3d", "two_link", "arm_pair_6x6"]


def _states(system: HJISystem, count: int, seed: int = 0) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return system.sample_states(count, generator).double()


@pytest.mark.parametrize("system", SYSTEMS, ids=IDS)
def test_hamiltonian_matches_brute_force_over_box_corners(system: HJISystem) -> None:
    count = 64 if system.state_dim > 4 else 256
    x = _states(system, count)
    p = torch.randn(count, system.state_dim, generator=torch.Generator().manual_seed(1)).double()
    closed = system.hamiltonian(x, p)
    brute = system.brute_force_hamiltonian(x, p)
    torch.testing.assert_close(closed, brute, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("system", SYSTEMS, ids=IDS)
def test_optimal_inputs_attain_the_hamiltonian(system: HJISystem) -> None:
    x = _states(system, 128)
    p = torch.randn(128, system.state_dim, generator=torch.Generator().manual_seed(2)).double()
    u, d = system.optimal_control(x, p), system.worst_disturbance(x, p)
    attained = (p * system.dynamics(x, u, d)).sum(dim=1)
    torch.testing.assert_close(attained, system.hamiltonian(x, p), rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("system", SYSTEMS, ids=IDS)
def test_symmetry_preserves_boundary_and_hamiltonian(system: HJISystem) -> None:
    x = _states(system, 512)
    p = torch.randn(512, system.state_dim, generator=torch.Generator().manual_seed(3)).double()
    fx = system.symmetry(x)
    torch.testing.assert_close(system.boundary(fx), system.boundary(x), rtol=0, atol=1e-9)
    jac = system.symmetry_jacobian(x)
    p_mapped = torch.linalg.solve(jac.transpose(1, 2), p[:, :, None])[:, :, 0]  # Df⁻ᵀ p
    torch.testing.assert_close(
        system.hamiltonian(fx, p_mapped), system.hamiltonian(x, p), rtol=1e-10, atol=1e-10
    )


@pytest.mark.parametrize("system", SYSTEMS, ids=IDS)
def test_symmetry_jacobian_matches_autograd(system: HJISystem) -> None:
    x = _states(system, 8)
    jac = system.symmetry_jacobian(x)
    for i in range(x.shape[0]):
        auto = torch.autograd.functional.jacobian(lambda y: system.symmetry(y[None])[0], x[i])
        torch.testing.assert_close(jac[i], auto)


@pytest.mark.parametrize("system", SYSTEMS, ids=IDS)
def test_fold_maps_into_train_set_and_inverse_undoes_map(system: HJISystem) -> None:
    x = _states(system, 2000)
    folded = system.fold(x)
    assert bool(system.in_train(folded).all())
    assert 0.4 < float(system.in_train(x).double().mean()) < 0.6
    back = system.symmetry_inverse(system.symmetry(x))
    diff = back - x
    if any(system.periodic):
        diff = wrap_to_pi(diff)
    assert float(diff.abs().max()) < 1e-9


def test_two_link_distance_known_configurations() -> None:
    distance = TwoLinkDistance()
    # Both arms stretched toward each other along the x-axis: tips at 1.0 and 0.4 -> overlap.
    # Both arms pointing away: nearest points are the bases, 1.4 m apart.
    q = torch.tensor([[0.0, 0.0, 0.0, 0.0], [math.pi, 0.0, math.pi, 0.0]], dtype=torch.float64)
    lq = distance(q)
    assert float(lq[0]) == pytest.approx(-0.1)
    assert float(lq[1]) == pytest.approx(1.4 - 0.1)
    # Arm 1 straight up, arm 2 pointing at it along y = 0: tip of arm 2 at x = 0.4.
    q = torch.tensor([[math.pi / 2, 0.0, 0.0, 0.0]], dtype=torch.float64)
    assert float(distance(q)[0]) == pytest.approx(0.4 - 0.1)


def test_two_link_distance_matches_dense_point_sampling() -> None:
    distance = TwoLinkDistance()
    x = _states(TwoLinkPair(), 300, seed=5)
    exact = distance(x)
    s = torch.linspace(0, 1, 201, dtype=torch.float64)
    p = distance.arm_points(x[:, :2], (0.0, 0.0), 0.0)
    r = distance.arm_points(x[:, 2:], distance.base2, distance.yaw2)

    def dense(points: list[torch.Tensor]) -> torch.Tensor:
        segs = [
            a[:, None] + s[None, :, None] * (b - a)[:, None] for a, b in itertools.pairwise(points)
        ]
        return torch.cat(segs, dim=1)

    brute = torch.cdist(dense(p), dense(r)).amin(dim=(1, 2)) - 0.1
    assert float((brute - exact).min()) > -1e-9  # sampling can only over-estimate
    assert float((brute - exact).max()) < 5e-3


def test_two_link_boundary_gradient_is_finite() -> None:
    x = _states(TwoLinkPair(), 500).requires_grad_(True)
    TwoLinkDistance()(x).sum().backward()
    assert x.grad is not None and bool(torch.isfinite(x.grad).all())


def test_air3d_boundary_and_domain() -> None:
    system = Air3D()
    x = torch.tensor([[0.0, 0.0, 0.3], [0.6, 0.8, -0.5]], dtype=torch.float64)
    torch.testing.assert_close(system.boundary(x), torch.tensor([-0.25, 0.75], dtype=torch.float64))
    assert system.state_dim == 3 and system.horizon == pytest.approx(1.1)


def test_make_system_and_bad_parameters_raise() -> None:
    assert isinstance(make_system("two_link"), TwoLinkPair)
    with pytest.raises(UnknownNameError, match=r"air3d"):
        make_system("air4d")
    with pytest.raises(InvalidValueError, match="u_max"):
        TwoLinkPair(u_max=-1.0)
    with pytest.raises(InvalidValueError, match="symmetry_sign"):
        TwoLinkPair(symmetry_sign=[1.0, 0.5, 1.0, 1.0])
    with pytest.raises(InvalidValueError, match="symmetry_offset"):
        TwoLinkPair(symmetry_offset=[0.0, 0.0])
    with pytest.raises(InvalidValueError, match=r"train_region\.joint"):
        TwoLinkPair(train_region=JointInterval(7, 0.0, 1.0))
    with pytest.raises(InvalidValueError, match="horizon"):
        Air3D(horizon=0.0)
    with pytest.raises(InvalidValueError, match=r"shape \(B, 4\)"):
        TwoLinkPair().check_states(torch.zeros(3, 3))


def test_segment_distance_of_collinear_and_touching_segments() -> None:
    from nehmo_core.hjr.systems import segment_distance

    def dist(a, b, c, d):  # type: ignore[no-untyped-def]
        t = [torch.tensor([p], dtype=torch.float64) for p in (a, b, c, d)]
        return float(segment_distance(*t)[0])

    assert dist((0, 0), (1, 0), (2, 0), (3, 0)) == pytest.approx(1.0)  # collinear, apart
    assert dist((0, 0), (2, 0), (1, 0), (3, 0)) == pytest.approx(0.0, abs=1e-8)  # overlapping
    assert dist((0, 0), (1, 0), (1, 0), (1, 1)) == pytest.approx(0.0, abs=1e-8)  # touching ends
    assert dist((0, -1), (0, 1), (-1, 0), (1, 0)) == 0.0  # crossing
    assert dist((0, 0), (1, 0), (0.5, 0.5), (0.5, 2)) == pytest.approx(0.5)  # apart
