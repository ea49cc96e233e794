"""Learned-distance certificates: the certified level, contact sampling and the shipped model."""

from __future__ import annotations

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.geometry.distance_model import load_distance_model
from nehmo_core.hjr.systems.arm_pairs import make_arm_pair_system
from nehmo_core.verify.bound import max_violations, violation_bound
from nehmo_core.verify.distance import (
    NearVisited,
    certified_level,
    certify_distance,
    contact_states,
    jittered,
)
from nehmo_core.verify.distributions import UniformBox, VisitedStates
from nehmo_core.verify.truth import exact_margin


def test_certified_level_is_the_smallest_level_meeting_alpha() -> None:
    learned = np.random.default_rng(4).normal(-0.02, 0.01, 3000)
    level = certified_level(learned, 0.01, 1e-3)
    allowed = max_violations(3000, 0.01, 1e-3)
    above = int((learned > level).sum())
    assert above <= allowed and violation_bound(3000, above, 1e-3) <= 0.01
    lower = np.sort(learned[learned < level])[-1]  # the next value down breaks the bound
    assert int((learned > lower).sum()) > allowed
    assert level > 0.0  # about 1 % of this sample reads above 0


def test_certified_level_is_zero_when_contacts_read_as_contacts() -> None:
    assert certified_level(np.full(3000, -0.01), 0.01, 1e-3) == 0.0


def test_too_few_contacts_certify_nothing() -> None:
    assert certified_level(np.full(100, -0.5), 0.01, 1e-3) == float("inf")  # 0/100 bounds 6.7 %


def test_jitter_keeps_the_condition_column() -> None:
    rng = np.random.default_rng(0)
    x = np.concatenate([np.zeros((500, 12)), np.full((500, 1), 0.9)], axis=1)
    moved = jittered(x, np.full((500, 1), 0.2), rng, joints=12)
    assert np.all(moved[:, 12] == 0.9)
    assert 0.15 < moved[:, :12].std() < 0.25
    assert np.all(np.abs(moved[:, :12]) <= np.pi)
    with pytest.raises(InvalidValueError, match="sigma"):
        jittered(x, 0.0, rng)


class _NeverInContact:
    def __call__(self, x: np.ndarray, scale: float) -> np.ndarray:
        return np.ones(x.shape[0])


def test_contact_sampling_stops_with_a_clear_error() -> None:
    box = UniformBox(make_arm_pair_system("ur5_ur5"))
    with pytest.raises(NehmoError, match="0 of 4000 drawn states are in contact; need count = 10"):
        contact_states(box, _NeverInContact(), 10, np.random.default_rng(0), 1000, 4000)


def test_shipped_ur5_pair_distance_is_certified_below_the_planner_margin() -> None:
    system = make_arm_pair_system("ur5_ur5")
    margin = exact_margin(system)
    try:
        rng = np.random.default_rng(7)
        cert = certify_distance(
            load_distance_model("ur5_ur5"), margin, UniformBox(system), rng, samples=700
        )
        assert cert.certified and cert.colliding == 700 and cert.states > 700
        assert cert.bound <= 0.01
        assert cert.level_m < 0.05  # the paper's ε: a planner at ε keeps the certificate
        # the drawn contacts are real contacts, and near them the sampler keeps drawing contacts
        states, _ = contact_states(UniformBox(system), margin, 50, rng)
        assert np.all(margin(states, 1.0) <= 0.0)
        near = NearVisited(VisitedStates(states), joints=12, low=0.01, high=0.02)
        assert (margin(near.draw(200, rng), 1.0) <= 0.0).mean() > 0.5
    finally:
        margin.close()


@pytest.mark.parametrize(
    "pair", ["ur5_ur5", "ur5_ur5_opposite", "ur5_kinova", "kinova_ur5", "ur5_ur5_any"]
)
def test_the_ball_covers_never_call_a_contact_apart(pair: str) -> None:
    """The prefilter is sound: where the covers are apart the arms are apart, and no closer
    than the covers say; states drawn near contacts put it to the test where it matters."""
    from nehmo_core.hjr import make_system

    system = make_system(pair)
    margin = exact_margin(system)
    try:
        rng = np.random.default_rng(3)
        uniform = UniformBox(system).draw(1500, rng)
        touching = uniform[margin(uniform, 1.0) <= 0.0]
        near = NearVisited(VisitedStates(touching), joints=12, low=0.02, high=0.1)
        x = np.concatenate([uniform, near.draw(1500, rng)])
        bound, exact = margin.lower_bound(x), margin(x, 3.0)
        apart = bound > 0.0
        assert apart.mean() > 0.3 and (exact <= 0.0).sum() > 100  # both kinds are tested
        assert np.all(exact[apart] > 0.0)
        assert np.all(bound[apart] <= exact[apart] + 1e-9)
    finally:
        margin.close()


class _NoPrefilter:
    def __init__(self, margin) -> None:  # type: ignore[no-untyped-def]
        self.margin = margin

    def __call__(self, x: np.ndarray, cutoff: float) -> np.ndarray:
        return self.margin(x, cutoff)


def test_the_prefilter_keeps_the_same_contact_states() -> None:
    system = make_arm_pair_system("ur5_kinova")
    margin = exact_margin(system)
    try:
        fast, drawn = contact_states(UniformBox(system), margin, 40, np.random.default_rng(5), 500)
        plain, drawn_plain = contact_states(
            UniformBox(system), _NoPrefilter(margin), 40, np.random.default_rng(5), 500
        )
        assert drawn == drawn_plain and np.array_equal(fast, plain)
    finally:
        margin.close()
