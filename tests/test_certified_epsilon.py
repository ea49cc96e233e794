"""The planner's margin ε follows the certificates in its models' cards; the paper keeps ε fixed."""

from __future__ import annotations

import dataclasses

import pytest

from nehmo_core.hjr import NetworkSettings
from nehmo_core.planning.factory import make_planner
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.synthetic import random_value_function
from nehmo_core.planning.value_model import PairValueModel
from nehmo_core.robots import load_cell


@pytest.fixture(scope="module")
def model() -> PairValueModel:
    vf = random_value_function("ur5_ur5", "bc+sym", NetworkSettings(width=16, hidden_layers=1))
    return PairValueModel.from_value_function(vf, "certified_eps_test", backend="vm")


def _cert(tau: float, delta: float, name: str = "visited") -> dict:
    return {"tau": tau, "delta": delta, "distribution": {"name": name}, "certified": True}


def _planner(model: PairValueModel, kind: str = "nehmo", **settings: object) -> NehmoPlanner:
    planner = make_planner(
        kind, load_cell("dual_ur5"), "ur5_0", [model], PlannerSettings(**settings)
    )  # type: ignore[arg-type]
    assert isinstance(planner, NehmoPlanner)
    return planner


def test_certified_level_above_the_floor_raises_epsilon(model: PairValueModel) -> None:
    certified = dataclasses.replace(
        model, certificates=(_cert(0.3, 0.07), _cert(0.3, 0.08, "uniform"), _cert(0.1, 0.2))
    )
    planner = _planner(certified)
    assert planner.settings.epsilon == pytest.approx(0.08)  # the largest δ at t_safe = 0.3
    assert "0.08" in planner.epsilon_source


def test_level_below_the_floor_keeps_the_floor(model: PairValueModel) -> None:
    certified = dataclasses.replace(model, certificates=(_cert(0.3, 0.01),))
    assert _planner(certified).settings.epsilon == pytest.approx(0.05)


def test_no_certificate_at_t_safe_is_said(model: PairValueModel) -> None:
    certified = dataclasses.replace(model, certificates=(_cert(0.3, 0.09),))
    planner = _planner(certified, t_safe=0.25)
    assert planner.settings.epsilon == pytest.approx(0.05)
    assert "no certificate at t_safe for: certified_eps_test" in planner.epsilon_source


def test_paper_rows_keep_the_fixed_epsilon(model: PairValueModel) -> None:
    certified = dataclasses.replace(model, certificates=(_cert(0.3, 0.09),))
    assert _planner(certified, "nehmo_paper").settings.epsilon == pytest.approx(0.05)
    assert _planner(certified, certified_epsilon=False).settings.epsilon == pytest.approx(0.05)
