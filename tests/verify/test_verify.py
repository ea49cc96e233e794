"""nehmo verify: the scenario bound, bad input, certified level sets against a grid ground truth."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import torch
from scipy.interpolate import RegularGridInterpolator
from scipy.stats import binom

from nehmo_core.errors import InvalidValueError
from nehmo_core.hjr import Air3D, GroundTruth, ground_truth
from nehmo_core.verify import VerifySettings, certify, max_violations, violation_bound
from nehmo_core.verify.cards import certified_level, record_certificate
from nehmo_core.verify.certify import search_delta
from nehmo_core.verify.distributions import UniformBox
from nehmo_core.verify.truth import exact_margin

TAUS = np.round(np.arange(0.0, 0.55, 0.05), 3)
TAU = 0.5


class GridValue:
    """``V(τ, x)`` of a grid solution plus a constant ``bias``: trilinear in x, linear in τ."""

    def __init__(self, truth: GroundTruth, bias: float = 0.0) -> None:
        self.system = Air3D()
        self.taus = truth.taus
        self.bias = bias
        coords = truth.coordinate_vectors
        self.tables = []
        for values in truth.values.astype(np.float64):
            grads = np.gradient(values, *coords)
            self.tables.append(
                [
                    RegularGridInterpolator(coords, f, bounds_error=False, fill_value=None)
                    for f in [values, *grads]
                ]
            )

    def _at(self, tau: float, x: np.ndarray) -> np.ndarray:
        k = int(np.clip(np.searchsorted(self.taus, tau) - 1, 0, len(self.taus) - 2))
        w = (tau - self.taus[k]) / (self.taus[k + 1] - self.taus[k])
        a = np.stack([f(x) for f in self.tables[k]], axis=1)
        b = np.stack([f(x) for f in self.tables[k + 1]], axis=1)
        return (1 - w) * a + w * b  # (B, 4): V, ∂V/∂x

    def value(self, tau: float, x: np.ndarray) -> np.ndarray:
        return self._at(float(tau), np.asarray(x, dtype=np.float64))[:, 0] + self.bias

    def value_and_gradient(self, tau: float, x: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        out = self._at(float(tau), np.asarray(x, dtype=np.float64))
        return out[:, 0] + self.bias, out[:, 1:]


@pytest.fixture(scope="module")
def air3d_truth(tmp_path_factory: pytest.TempPathFactory) -> GroundTruth:
    directory = tmp_path_factory.mktemp("air3d_grid")
    return ground_truth(Air3D(), (41, 41, 41), TAUS, accuracy="medium", directory=directory)


SETTINGS = VerifySettings(
    tau=TAU, alpha=0.05, beta=0.01, samples=400, search_samples=400, attempts=2, seed=3
)


def _true_unsafe_share(model: GridValue, truth: GridValue, delta: float) -> tuple[float, int]:
    """Share of fresh uniform states in the certified set ``{V ≥ δ}`` that the grid calls unsafe."""
    x = UniformBox(Air3D()).draw(20000, np.random.default_rng(99))
    inside = model.value(TAU, x) >= delta
    unsafe = truth.value(TAU, x) < 0.0
    return float((inside & unsafe).sum() / inside.sum()), int(inside.sum())


def test_bound_matches_the_binomial_tail() -> None:
    assert violation_bound(3000, 0, 1e-3) == pytest.approx(1 - 1e-3 ** (1 / 3000), rel=1e-9)
    for n, k in [(3000, 0), (3000, 7), (500, 3)]:
        eps = violation_bound(n, k, 1e-3)
        assert binom.cdf(k, n, eps) == pytest.approx(1e-3, rel=1e-6)
    k = max_violations(3000, 0.01, 1e-3)
    assert violation_bound(3000, k, 1e-3) <= 0.01 < violation_bound(3000, k + 1, 1e-3)


@pytest.mark.parametrize(
    ("field", "value", "rule"),
    [
        ("alpha", 1.5, "must lie in"),
        ("beta", 0.0, "must lie in"),
        ("tau", -0.1, "must be > 0"),
        ("samples", 100, "must be >= 797"),
        ("adversaries", ("learned", "oracle"), "must each be one of"),
    ],
)
def test_bad_settings_name_the_parameter(field: str, value: object, rule: str) -> None:
    with pytest.raises(InvalidValueError, match=rf"`{field}` {rule}"):
        VerifySettings(**{"tau": 0.3, field: value})  # type: ignore[arg-type]


def test_search_finds_the_level_above_every_violation() -> None:
    rng = np.random.default_rng(0)
    values = rng.uniform(0.0, 0.3, 4000)
    violated = values < 0.1  # everything below 0.1 m fails, nothing above
    delta = search_delta(values, violated, VerifySettings(tau=0.3))
    assert 0.095 <= delta <= 0.101


def test_faithful_value_certifies_a_level_near_zero(air3d_truth: GroundTruth) -> None:
    model = GridValue(air3d_truth)
    cert = certify(model, exact_margin(model.system), UniformBox(model.system), SETTINGS)
    assert cert.certified
    assert cert.delta <= 0.05
    share, n = _true_unsafe_share(model, model, cert.delta)
    assert n > 10000 and share <= SETTINGS.alpha


def test_overconfident_value_is_caught_and_its_certified_set_is_truly_safe(
    air3d_truth: GroundTruth,
) -> None:
    truth = GridValue(air3d_truth)
    model = GridValue(air3d_truth, bias=0.15)  # claims 15 cm more safety than there is
    cert = certify(model, exact_margin(model.system), UniformBox(model.system), SETTINGS)
    assert cert.certified
    assert cert.search["violations_at_0"] > 0
    assert 0.1 <= cert.delta <= 0.25  # the bias is found, not a vacuous level
    share, _ = _true_unsafe_share(model, truth, cert.delta)
    assert share <= SETTINGS.alpha
    # the level set the uncertified model calls safe holds truly unsafe states
    assert _true_unsafe_share(model, truth, 0.0)[0] > SETTINGS.alpha


def test_certificate_is_repeatable_and_recorded_in_a_card(
    air3d_truth: GroundTruth, tmp_path: Path
) -> None:
    model = GridValue(air3d_truth, bias=0.15)
    margin = exact_margin(model.system)
    small = VerifySettings(
        tau=0.2, alpha=0.05, beta=0.01, samples=200, search_samples=100, attempts=1
    )
    first = certify(model, margin, UniformBox(model.system), small)
    again = certify(model, margin, UniformBox(model.system), small)
    assert (first.delta, first.violations) == (again.delta, again.violations)
    card = tmp_path / "value_test.json"
    card.write_text(json.dumps({"card": {"what": "test"}}))
    record_certificate(card, first)
    record_certificate(card, again)  # same τ and distribution: replaced, not added
    meta = json.loads(card.read_text())
    assert len(meta["card"]["certificates"]) == 1
    level = certified_level(meta["card"], 0.2)
    assert level is not None and level[0] == pytest.approx(first.delta)
    assert certified_level(meta["card"], 0.3) is None
