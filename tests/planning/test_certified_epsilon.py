"""The planner's margin ε follows the certificates in its models' cards; the paper keeps ε fixed."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError
from nehmo_core.hjr import NetworkSettings
from nehmo_core.planning.factory import make_planner
from nehmo_core.planning.models.synthetic import random_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell

FLOOR = PlannerSettings().hold.settled_epsilon  # the default floor of rows against a settled peer


@pytest.fixture(scope="module")
def model() -> PairValueModel:
    vf = random_value_function("ur5_ur5", "bc+sym", NetworkSettings(width=16, hidden_layers=1))
    return PairValueModel.from_value_function(vf, "certified_eps_test", backend="vm")


def _cert(tau: float, delta: float, name: str = "visited") -> dict:
    return {"tau": tau, "delta": delta, "distribution": {"name": name}, "certified": True}


def _planner(
    model: PairValueModel, kind: str = "nehmo", settings: dict[str, object] | None = None
) -> NehmoPlanner:
    planner = make_planner(
        kind, load_cell("dual_ur5"), "ur5_0", [model], PlannerSettings().override(settings or {})
    )  # type: ignore[arg-type]
    assert isinstance(planner, NehmoPlanner)
    return planner


def test_certified_level_above_the_floor_raises_epsilon(model: PairValueModel) -> None:
    certified = dataclasses.replace(
        model, certificates=(_cert(0.3, 0.07), _cert(0.3, 0.08, "uniform"), _cert(0.1, 0.2))
    )
    planner = _planner(certified)
    assert planner.settings.opt.epsilon == pytest.approx(0.08)  # the largest δ at t_safe = 0.3
    assert "0.08" in planner.epsilon_source


def test_level_below_the_floor_keeps_the_floor(model: PairValueModel) -> None:
    certified = dataclasses.replace(model, certificates=(_cert(0.3, 0.01),))
    assert _planner(certified).settings.opt.epsilon == pytest.approx(0.05)


def test_no_certificate_at_t_safe_is_said(model: PairValueModel) -> None:
    certified = dataclasses.replace(model, certificates=(_cert(0.3, 0.09),))
    planner = _planner(certified, settings={"opt.t_safe": 0.25})
    assert planner.settings.opt.epsilon == pytest.approx(0.05)
    assert "no certificate at t_safe for: certified_eps_test" in planner.epsilon_source


def test_paper_rows_keep_the_fixed_epsilon(model: PairValueModel) -> None:
    certified = dataclasses.replace(model, certificates=(_cert(0.3, 0.09),))
    assert _planner(certified, "nehmo_paper").settings.opt.epsilon == pytest.approx(0.05)
    assert _planner(
        certified, settings={"margins.certified": False}
    ).settings.opt.epsilon == pytest.approx(0.05)


def test_full_speed_rows_keep_one_epsilon_slow_rows_their_own_level(model: PairValueModel) -> None:
    loose = dataclasses.replace(model, certificates=(_cert(0.3, 0.09), _cert(0.06, 0.07)))
    tight = dataclasses.replace(model, name="tight", certificates=(_cert(0.3, 0.0),))
    planner = make_planner("nehmo", load_cell("dual_ur5"), "ur5_0", [loose, tight])
    assert isinstance(planner, NehmoPlanner)
    assert planner.settings.opt.epsilon == pytest.approx(0.09)  # the cell-wide ε: the largest δ
    assert planner.group_margin(0, 1.0) == planner.group_margin(1, 1.0) == pytest.approx(0.09)
    assert planner.group_margin(0, 0.2) == pytest.approx(0.07)  # its own level at 0.06 s
    assert planner.group_margin(1, 0.2) == pytest.approx(FLOOR)  # the 0.3 s level 0, the floor


def test_rows_against_a_slow_peer_keep_the_level_certified_at_their_horizon(
    model: PairValueModel,
) -> None:
    certs = (_cert(0.3, 0.09), _cert(0.1, 0.07), _cert(0.06, 0.02), _cert(0.06, 0.06, "uniform"))
    planner = _planner(dataclasses.replace(model, certificates=certs))
    assert planner.group_margin(0, 0.2) == pytest.approx(0.06)  # τ = 0.06: the larger δ there
    assert planner.group_margin(0, 0.3) == pytest.approx(0.07)  # τ = 0.09: the 0.1 s level
    assert planner.group_margin(0, 0.5) == pytest.approx(0.09)  # τ = 0.15: the 0.3 s level
    assert planner.group_margin(0, 1.0) == pytest.approx(0.09)  # full speed: ε
    low = dataclasses.replace(model, certificates=(_cert(0.3, 0.09), _cert(0.06, 0.01)))
    assert _planner(low).group_margin(0, 0.2) == pytest.approx(max(0.01, FLOOR))  # the floor
    paper = _planner(dataclasses.replace(model, certificates=certs), "nehmo_paper")
    assert paper.group_margin(0, 0.2) == paper.group_margin(0, 1.0) == pytest.approx(0.05)


def test_a_slow_peers_rows_carry_their_margin_into_opt(model: PairValueModel) -> None:
    certs = (_cert(0.3, 0.09), _cert(0.06, 0.0))
    planner = _planner(dataclasses.replace(model, certificates=certs))
    q = np.zeros(6)
    for bound, margin in ((1.0, 0.09), (0.2, FLOOR)):
        now = planner.current(q, {"ur5_1": q}, {"ur5_1": bound})
        problem = planner.problem(q - 0.5, now)
        assert problem.constraints.margins == pytest.approx((margin,))
        cons = problem.constraints
        c, _ = cons.evaluate(np.zeros(6))
        v, _ = cons.models[0].evaluate(cons.horizon(0), cons.groups[0][1])
        assert cons.horizon(0) == pytest.approx(bound * 0.3)
        assert c[0] == pytest.approx(v[0] - margin, abs=1e-12)  # the row is V minus its margin


def test_a_settled_floor_lowers_only_rows_against_a_settled_peer(model: PairValueModel) -> None:
    certs = (_cert(0.3, 0.09), _cert(0.06, 0.0), _cert(0.1, 0.03))
    planner = _planner(
        dataclasses.replace(model, certificates=certs), settings={"hold.settled_epsilon": 0.015}
    )
    assert planner.settings.opt.epsilon == pytest.approx(0.09)  # full-speed rows: unchanged
    assert planner.group_margin(0, 1.0) == pytest.approx(0.09)
    assert planner.group_margin(0, 0.2) == pytest.approx(0.015)  # δ = 0 at 0.06 s: the floor
    assert planner.group_margin(0, 0.3) == pytest.approx(0.03)  # δ at 0.1 s is above it
    assert "max(0.015" in planner.epsilon_source
    paper = _planner(
        dataclasses.replace(model, certificates=certs), settings={"margins.certified": False}
    )
    assert paper.group_margin(0, 0.2) == pytest.approx(0.05)


@pytest.mark.parametrize("bad", [0.0, -0.01])
def test_a_settled_floor_not_above_zero_is_rejected(bad: float) -> None:
    with pytest.raises(InvalidValueError, match=r"hold\.settled_epsilon.*must lie in \(0, 1\]"):
        PlannerSettings().override({"hold.settled_epsilon": bad})
