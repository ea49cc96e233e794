"""CasADi export of the learned distance and the value networks vs torch; generated C cache."""

from __future__ import annotations

import os
import platform
import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
import torch

from nehmo_core.errors import NehmoError, UnknownNameError
from nehmo_core.geometry.distance_casadi import distance_function
from nehmo_core.geometry.symmetry import robot_mirror_map
from nehmo_core.hjr.casadi_export import value_functions
from nehmo_core.hjr.model_files import load_value_function
from nehmo_core.hjr.networks import NetworkSettings, ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import ArmPairSystem, JointInterval
from nehmo_core.hjr.systems.arm_pairs import SwappedBoundary
from nehmo_core.planning.models.synthetic import proxy_distance_model, random_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.numerics import codegen
from nehmo_core.planning.numerics.codegen import compile_function
from nehmo_core.robots.model import Pose

SMALL = NetworkSettings(width=32, hidden_layers=2)


def _states(n: int, count: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).uniform(-np.pi, np.pi, size=(count, n))


@pytest.mark.parametrize("pair", ["ur5_ur5", "ur5_kinova"])
def test_distance_graph_matches_torch_value_and_gradient(pair: str) -> None:
    model = proxy_distance_model(pair)
    gen = torch.Generator().manual_seed(6)
    with torch.no_grad():  # a generic MLP, not only the pass-through of the proxy
        for p in model.mlp.parameters():
            p.add_(0.05 * torch.randn(p.shape, generator=gen))
    fn = distance_function(model)
    q = _states(model.dof, 20, 1)
    ref_v, ref_g = model.distance_and_gradient(q)
    out = [fn(qi) for qi in q]
    np.testing.assert_allclose([float(o[0]) for o in out], ref_v, atol=1e-9, rtol=0)
    np.testing.assert_allclose([np.asarray(o[1]).ravel() for o in out], ref_g, atol=1e-9, rtol=0)


@pytest.mark.parametrize(
    ("pair", "variant", "scaling"),
    [
        ("ur5_ur5", "deepreach", "unit"),
        ("ur5_ur5", "bc", "raw"),
        ("ur5_ur5", "bc+sym", "unit"),
        ("ur5_kinova", "bc+sym", "unit"),
        ("ur5_kinova", "exact", "unit"),
    ],
)
@pytest.mark.parametrize("backend", ["vm", "compiled"])
def test_value_export_matches_torch(pair: str, variant: str, scaling: str, backend: str) -> None:
    settings = NetworkSettings(width=32, hidden_layers=2, input_scaling=scaling)
    vf = random_value_function(pair, variant, settings, residual_scale=1.0, seed=3)
    value, value_grad = value_functions(vf, f"test_{pair}_{variant.replace('+', '')}")
    fn = compile_function(value_grad, backend).function
    x = _states(12, 40, 2)
    for tau in (0.0, 0.3, 0.6):
        ref_v, ref_g = vf.value_and_gradient(tau, x)
        out = [fn(tau, xi) for xi in x]
        np.testing.assert_allclose([float(o[0]) for o in out], ref_v, atol=1e-9, rtol=0)
        grads = np.array([np.asarray(o[1]).ravel() for o in out])
        np.testing.assert_allclose(grads, ref_g, atol=1e-9, rtol=0)
        np.testing.assert_allclose([float(value(tau, xi)) for xi in x[:5]], ref_v[:5], atol=1e-9)


@pytest.mark.parametrize("backend", ["vm", "compiled"])
def test_swapped_boundary_export_matches_torch(backend: str) -> None:
    """kinova_ur5's l(x) is the ur5_kinova distance with the joint vectors swapped."""
    vf = load_value_function("kinova_ur5", variant="bc+sym")
    assert isinstance(vf.system, ArmPairSystem)
    boundary = vf.system.boundary_fn
    assert isinstance(boundary, SwappedBoundary)
    vf.network.double()  # the float32 distance alone differs from float64 by up to ~1e-2 m
    boundary.double()
    _, value_grad = value_functions(vf, "test_kinova_ur5_bcsym")
    fn = compile_function(value_grad, backend).function
    x = _states(12, 40, 6)  # both halves of X (folded or not)
    for tau in (0.0, 0.3, 0.6):
        ref_v, ref_g = vf.value_and_gradient(tau, x)
        out = [fn(tau, xi) for xi in x]
        np.testing.assert_allclose([float(o[0]) for o in out], ref_v, atol=1e-8, rtol=0)
        grads = np.array([np.asarray(o[1]).ravel() for o in out])
        np.testing.assert_allclose(grads, ref_g, atol=1e-8, rtol=0)


def _swapped_value_function(variant: str) -> ValueFunction:
    """A random kinova_ur5-like game on a perturbed proxy of the ur5_kinova distance."""
    distance = proxy_distance_model("ur5_kinova").double()
    with torch.no_grad():
        for p in distance.mlp.parameters():
            p.add_(0.05 * torch.randn(p.shape, generator=torch.Generator().manual_seed(7)))
    mirror = robot_mirror_map("kinova_gen3_6dof") + robot_mirror_map("ur5")
    system = ArmPairSystem(
        boundary_fn=SwappedBoundary(distance, distance.n2),
        n1=distance.n2,
        n2=distance.n1,
        symmetry_sign=np.array(mirror.sign),
        symmetry_offset=np.array(mirror.offset),
        train_region=JointInterval(joint=6, low=-np.pi / 2, high=np.pi / 2),
        system_name="kinova_ur5",
    )
    generator = torch.Generator().manual_seed(2)
    network = ValueNetwork(system, variant, SMALL, generator)
    return ValueFunction(network.double())


@pytest.mark.parametrize("variant", ["bc", "bc+sym", "exact"])
def test_swapped_value_model_matches_torch_and_has_the_swapped_geometry(variant: str) -> None:
    vf = _swapped_value_function(variant)
    model = PairValueModel.from_value_function(vf, "test_swapped", backend="vm")
    assert (model.robot1, model.robot2, model.n1, model.n2) == ("kinova_gen3_6dof", "ur5", 6, 6)
    # the UR5 seen from the Kinova: 0.6 m ahead, facing it (the inverse of ur5_kinova's base2)
    np.testing.assert_allclose(
        model.base2.matrix(), np.linalg.inv(Pose((0.6, 0, 0), (0, 0, np.pi)).matrix()), atol=1e-12
    )
    x = _states(12, 30, 7)
    v, g = model.evaluate(0.25, x)
    ref_v, ref_g = vf.value_and_gradient(0.25, x)
    np.testing.assert_allclose(v, ref_v, atol=1e-9, rtol=0)
    np.testing.assert_allclose(g, ref_g, atol=1e-9, rtol=0)


def test_export_names_a_boundary_it_cannot_export() -> None:
    vf = random_value_function("ur5_ur5", "bc", SMALL)
    system = vf.system
    assert isinstance(system, ArmPairSystem)
    odd = ArmPairSystem(
        boundary_fn=SwappedBoundary(torch.nn.Identity(), 6),
        n1=6,
        n2=6,
        symmetry_sign=system.symmetry_sign,
        symmetry_offset=system.symmetry_offset,
        train_region=system.train_region,
        system_name="odd_pair",
    )
    network = ValueNetwork(odd, "bc", SMALL, generator=torch.Generator().manual_seed(0))
    with pytest.raises(NehmoError, match=r"'odd_pair'.*SwappedBoundary around a Identity"):
        PairValueModel.from_value_function(ValueFunction(network), "test_odd", backend="vm")


def test_symmetric_export_is_invariant_under_the_mirror_map() -> None:
    vf = random_value_function("ur5_ur5", "bc+sym", SMALL, residual_scale=1.0)
    model = PairValueModel.from_value_function(vf, "test_sym", backend="vm")
    system = vf.system
    x = _states(12, 30, 4)
    mirrored = system.symmetry(torch.from_numpy(x)).numpy()
    v, _ = model.evaluate(0.3, x)
    vm, _ = model.evaluate(0.3, mirrored)
    np.testing.assert_allclose(v, vm, atol=1e-9)


def test_batched_evaluation_equals_single_calls() -> None:
    vf = random_value_function("ur5_ur5", "bc+sym", SMALL)
    model = PairValueModel.from_value_function(vf, "test_batch")
    x = _states(12, 4, 5)
    v4, g4 = model.evaluate(0.2, x)
    for i in range(4):
        v1, g1 = model.evaluate(0.2, x[i : i + 1])
        np.testing.assert_allclose(v4[i], v1[0], atol=1e-12)
        np.testing.assert_allclose(g4[i], g1[0], atol=1e-12)


def test_compiled_library_is_cached_by_content(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("NEHMO_CACHE", str(tmp_path))
    vf = random_value_function("ur5_ur5", "deepreach", SMALL)
    _, value_grad = value_functions(vf, "test_cache")
    first = compile_function(value_grad, "compiled")
    second = compile_function(value_grad, "compiled")
    assert first.backend == "compiled" and first.library == second.library
    other = random_value_function("ur5_ur5", "deepreach", SMALL, seed=9)
    assert compile_function(value_functions(other, "test_cache")[1]).library != first.library


def test_falls_back_to_the_vm_without_a_compiler(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("NEHMO_CACHE", str(tmp_path))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    vf = random_value_function("ur5_ur5", "deepreach", SMALL)
    _, value_grad = value_functions(vf, "test_fallback")
    with pytest.warns(RuntimeWarning, match="VM"):
        result = compile_function(value_grad, "auto")
    assert result.backend == "vm"
    with pytest.raises(FileNotFoundError, match="no-such-compiler"):
        compile_function(value_grad, "compiled")
    with pytest.raises(UnknownNameError, match="auto"):
        compile_function(value_grad, "jit")
    assert codegen.BACKENDS == ("auto", "compiled", "vm")


def _source(fn: ca.Function, tmp_path: Path) -> str:
    cg = ca.CodeGenerator(f"{fn.name()}.c", {"with_header": False, "verbose": False})
    cg.add(fn)
    cg.generate(str(tmp_path) + os.sep)
    return codegen._patch_kernel((tmp_path / f"{fn.name()}.c").read_text())


@pytest.mark.parametrize(("float32", "gradient"), [(False, False), (True, False), (True, True)])
def test_compact_weights_only_touches_exact_float32_constants_read_once(
    float32: bool, gradient: bool, tmp_path
) -> None:
    weights = np.random.default_rng(0).normal(size=(32, 64))
    if float32:
        weights = weights.astype(np.float32).astype(np.float64)
    x = ca.MX.sym("x", 1, 32)
    y = ca.sin(ca.mtimes(x, ca.DM(weights)))
    # with the gradient, CasADi transposes the constant at run time through the same pointer,
    # so it must stay double
    outputs = [y, ca.gradient(ca.sum2(y), x)] if gradient else [y]
    fn = ca.Function(f"tiny_{float32}_{gradient}", [x], outputs)
    source = _source(fn, tmp_path)
    compacted, counts = codegen.compact_weights(source)
    touched = float32 and not gradient
    assert counts == {"float": int(touched), "removed": 0}
    assert (compacted != source) == touched
    compiled = compile_function(fn, "compiled").function
    for xi in np.random.default_rng(1).normal(size=(5, 1, 32)):
        for a, b in zip(compiled.call([xi]), fn.call([xi]), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-13)


def test_compiled_shipped_model_stores_each_weight_once_and_matches_the_vm(tmp_path) -> None:
    _, value_grad = value_functions(load_value_function("ur5_ur5", variant="bc+sym"), "ship")
    source = _source(value_grad, tmp_path)
    compacted, counts = codegen.compact_weights(source)
    # every large matrix of the distance MLP and the SIREN is written as W and Wᵀ by CasADi
    assert counts["float"] >= 4 and counts["removed"] >= 4
    assert len(compacted) < 0.6 * len(source)
    compiled = compile_function(value_grad, "compiled").function
    for tau, xi in zip((0.0, 0.2, 0.6), _states(12, 3, 8), strict=True):
        (v, g), (v_ref, g_ref) = compiled(tau, xi), value_grad(tau, xi)
        np.testing.assert_allclose(float(v), float(v_ref), rtol=1e-12, atol=1e-14)
        np.testing.assert_allclose(np.asarray(g), np.asarray(g_ref), rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("width", [0, 34])
def test_single_precision_products_stay_within_1e6_of_the_double_ones(width: int, tmp_path) -> None:
    """The planner's default (``single=True``): the weight products in float. ``0``: the
    shipped ``ur5_ur5`` model; ``34``: a random SIREN whose width is no multiple of the
    transposed kernel's four-column step (its tail runs)."""
    if width:
        settings = NetworkSettings(width=width, hidden_layers=2)
        vf = random_value_function("ur5_ur5", "bc+sym", settings, residual_scale=1.0, seed=4)
    else:
        vf = load_value_function("ur5_ur5", variant="bc+sym")
    _, value_grad = value_functions(vf, f"single_{width}")
    compacted, counts = codegen.compact_weights(_source(value_grad, tmp_path), single=True)
    assert "float acc = 0;" in compacted and counts["removed"] >= 1
    if width:
        assert re.search(rf"nehmo_rowt_f32\(w\d+, {width}, casadi_c", compacted)
    single = compile_function(value_grad, "compiled", single=True)
    double = compile_function(value_grad, "compiled")
    assert single.library != double.library
    worst_v = worst_g = 0.0
    for tau, xi in zip((0.0, 0.06, 0.3, 0.6) * 10, _states(12, 40, 9), strict=True):
        (v, g), (v_ref, g_ref) = single.function(tau, xi), double.function(tau, xi)
        worst_v = max(worst_v, abs(float(v) - float(v_ref)))
        worst_g = max(worst_g, float(np.abs(np.asarray(g) - np.asarray(g_ref)).max()))
    assert worst_v < 1e-6 and worst_g < 1e-6
    assert worst_v > 0.0  # the float kernels ran (the double ones agree to ~1e-14)
    model = PairValueModel.from_value_function(vf, f"single_{width}")
    assert model.library == single.library  # what a planner evaluates


def _transcendental_fn(name: str) -> ca.Function:
    x = ca.MX.sym("x", 64)
    y = ca.sum1(ca.sin(3.0 * x) * ca.exp(-x * x) + ca.cos(x))
    return ca.Function(name, [x], [y, ca.gradient(y, x)])


@pytest.mark.skipif(platform.machine() != "x86_64", reason="libmvec's vector ABI is x86-64's")
def test_sin_cos_exp_loops_run_through_the_vector_math_library(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("NEHMO_CACHE", str(tmp_path))
    fn = _transcendental_fn("vector_math")
    compiled = compile_function(fn, "compiled")
    assert compiled.library is not None
    # a vector variant (of whichever width -march=native picks: AVX2 ``_ZGVdN4v_exp``, AVX-512
    # ``_ZGVeN8v_exp``, ...) is called per loop
    assert re.search(rb"_ZGV[bcde]N\d+v_exp", compiled.library.read_bytes())
    for xi in np.random.default_rng(2).uniform(-3, 3, size=(5, 64)):
        for a, b in zip(compiled.function.call([xi]), fn.call([xi]), strict=True):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=1e-13)


def test_a_failed_vector_math_build_falls_back_to_the_scalar_calls(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("NEHMO_CACHE", str(tmp_path))
    monkeypatch.setattr(codegen, "VECTOR_MATH_FLAGS", ("-lno-such-library",))
    fn = _transcendental_fn("scalar_math")
    compiled = compile_function(fn, "compiled")
    assert compiled.library is not None
    assert b"_ZGV" not in compiled.library.read_bytes()
    xi = np.linspace(-3, 3, 64)
    for a, b in zip(compiled.function.call([xi]), fn.call([xi]), strict=True):
        np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-13, atol=1e-13)
