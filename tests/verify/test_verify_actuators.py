"""`nehmo verify` under an actuator model: rollouts where the arm follows its control under
acceleration limits (starting in a full-speed reversal), certificates that say which model they
hold for, and planners that take their margin from the certificates of their actuator model."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from nehmo_core.hjr import load_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.robots import load_cell
from nehmo_core.sim.actuators import ActuatorModel, actuator_model
from nehmo_core.verify.adversaries import make_adversaries
from nehmo_core.verify.cards import certified_level, record_certificate
from nehmo_core.verify.certify import VerifySettings, certify
from nehmo_core.verify.distributions import UniformBox
from nehmo_core.verify.report import certificates_table
from nehmo_core.verify.rollout import rollout_margins
from nehmo_core.verify.truth import exact_margin

TAU = 0.3
UR5 = load_cell("dual_ur5").arm("ur5_0").robot


@pytest.fixture(scope="module")
def near() -> tuple[object, object, np.ndarray]:
    """The shipped UR5 pair model, its exact margin and 120 states with V(τ) in [0.03, 0.2] m."""
    value = load_value_function("ur5_ur5")
    x = np.random.default_rng(4).uniform(-np.pi, np.pi, size=(6000, 12)).astype(np.float32)
    v, _ = value.value_and_gradient(TAU, x)
    v = np.asarray(v, dtype=float).reshape(-1)
    pick = x[(v >= 0.03) & (v <= 0.2)][:120]
    assert len(pick) == 120
    margin = exact_margin(value.system)
    yield value, margin, pick
    margin.close()


def _margins(value, margin, x, actuator: ActuatorModel | None) -> np.ndarray:  # type: ignore[no-untyped-def]
    adversary = make_adversaries(
        value.system, ("corner+",), x.shape[0], 0.01, np.random.default_rng(0)
    )[0]
    return rollout_margins(
        value, margin, x, TAU, adversary, 0.01, contact_cutoff=1.0, actuator=actuator
    )


def test_ideal_and_unlimited_tracking_reproduce_the_ideal_rollouts(near) -> None:  # type: ignore[no-untyped-def]
    value, margin, x = near
    ideal = _margins(value, margin, x, None)
    np.testing.assert_array_equal(_margins(value, margin, x, ActuatorModel()), ideal)
    # a limit no joint reaches in a step: the velocity equals the control from the first step
    instant = ActuatorModel("fast", (1e9,) * 6)
    np.testing.assert_allclose(_margins(value, margin, x, instant), ideal, atol=1e-6)


def test_acceleration_limits_and_the_reversal_cost_clearance(near) -> None:  # type: ignore[no-untyped-def]
    value, margin, x = near
    ideal = _margins(value, margin, x, None)
    limited = _margins(value, margin, x, actuator_model("limits", UR5))
    assert np.mean(limited < ideal - 1e-3) > 0.5  # most lose at least a millimetre
    assert np.mean(limited > ideal + 1e-3) < 0.05  # (another path may pass farther, rarely)
    assert np.mean(ideal - limited) > 3e-3
    assert not np.any(ideal <= 0) and np.any(limited <= 0)  # a reversal that ends in contact
    realistic = _margins(value, margin, x, actuator_model("realistic", UR5))
    assert np.mean(ideal - realistic) > 3e-3


def test_certificates_record_their_actuator_model_and_planners_pick_theirs(
    near,
    tmp_path: Path,  # type: ignore[no-untyped-def]
) -> None:
    value, margin, _ = near
    small = VerifySettings(
        tau=TAU, alpha=0.2, beta=0.1, samples=40, search_samples=40, attempts=1, chunk=40
    )
    ideal = certify(value, margin, UniformBox(value.system), small)
    limited = certify(
        value,
        margin,
        UniformBox(value.system),
        replace(small, actuator=actuator_model("limits", UR5)),
    )
    assert limited.settings["actuator"]["name"] == "limits"
    assert tuple(limited.settings["actuator"]["accel"]) == (5.0,) * 6
    card = tmp_path / "value_test.json"
    card.write_text(json.dumps({"card": {"what": "test"}}))
    record_certificate(card, ideal)
    record_certificate(card, limited)  # same τ and distribution, another actuator model: kept
    meta = json.loads(card.read_text())
    assert [c["actuators"]["name"] for c in meta["card"]["certificates"]] == ["ideal", "limits"]
    assert certified_level(meta["card"], TAU)[0] == pytest.approx(ideal.delta)  # type: ignore[index]
    found = certified_level(meta["card"], TAU, "limits")
    assert found is not None and found[0] == pytest.approx(limited.delta)
    model = replace(_any_model(), certificates=tuple(meta["card"]["certificates"]))
    # under an actuator model the ideal levels at the same τ count too
    assert model.certified_level(TAU, "limits") == pytest.approx(max(limited.delta, ideal.delta))
    assert model.certified_level(TAU) == pytest.approx(ideal.delta)
    # no certificate for that model: the ideal ones count (and the planner says so)
    assert model.certified_level(TAU, "realistic") == pytest.approx(ideal.delta)
    assert not model.certified_under("realistic")


def _any_model() -> PairValueModel:
    from nehmo_core.planning.models.registry import ModelRegistry

    return ModelRegistry().models_for("nehmo", load_cell("dual_ur5"))[0]


def test_a_planner_takes_its_margin_from_its_actuator_models_certificates() -> None:
    from nehmo_core.planning.models.margins import CertifiedMargins

    base = _any_model()
    certs = (
        {"tau": TAU, "delta": 0.07, "distribution": {"name": "uniform"}},
        {
            "tau": TAU,
            "delta": 0.11,
            "distribution": {"name": "uniform"},
            "actuators": {"name": "realistic"},
        },
    )
    model = replace(base, certificates=certs)
    ideal = CertifiedMargins([model], [0], 0.05, 0.01, TAU)
    real = CertifiedMargins([model], [0], 0.05, 0.01, TAU, actuators="realistic")
    limits = CertifiedMargins([model], [0], 0.05, 0.01, TAU, actuators="limits")
    assert (ideal.epsilon, real.epsilon, limits.epsilon) == (0.07, 0.11, 0.07)
    assert real.source.startswith("[realistic actuators]")
    assert "ideal-tracking certificates for" in limits.source
    # a distribution certified only with ideal tracking keeps its level under realistic
    visited = {"tau": TAU, "delta": 0.13, "distribution": {"name": "visited"}}
    both = CertifiedMargins(
        [replace(base, certificates=(*certs, visited))], [0], 0.05, 0.01, TAU, actuators="realistic"
    )
    assert both.epsilon == 0.13


def test_the_certificates_table_names_each_rows_actuator_model() -> None:
    """Two certificates of one model, τ and distribution differ only in how the arm tracked its
    control: the table tells them apart (they once read as duplicates)."""
    base = {
        "model": "ur5_ur5 (bc+sym)",
        "tau": 0.3,
        "distribution": {"name": "uniform"},
        "delta": 0.011,
        "samples": 3000,
        "violations": 8,
        "epsilon": 0.0076,
        "certified": True,
        "wall_time_s": 80.0,
        "settings": {"tau": 0.3},
    }
    real = {**base, "delta": 0.033, "settings": {"actuator": {"name": "realistic"}}}
    rows = certificates_table([base, real]).splitlines()[2:]
    assert [r.split("|")[4].strip() for r in rows] == ["ideal", "realistic"]
    assert [r.split("|")[5].strip() for r in rows] == ["0.011", "0.033"]
