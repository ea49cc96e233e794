"""The shipped learned distances: accuracy spot check, smoothness, symmetry, safe loading."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from nehmo_core.errors import ModelFileError, UnknownNameError
from nehmo_core.geometry.distance_data import (
    DatasetSpec,
    generate,
    pair_cell,
    uniform_samples,
)
from nehmo_core.geometry.distance_model import (
    SHIPPED_DISTANCE_MODELS,
    distance_model_path,
    load_distance_file,
    load_distance_model,
)
from nehmo_core.geometry.symmetry import robot_mirror_map
from nehmo_core.robots.registry import MODELS_DIR, arm_pair, robot_facts

PAIRS = list(SHIPPED_DISTANCE_MODELS)
BELOW_BAR = {"panda_panda_any": 0.015, "ur5_panda_any": 0.035, "ur5_ur5_far": 0.025}
"""[m] Mean error near contact held to each model's own figure where it differs from the 2 cm
bar: the Panda pair (1.3 cm; its keypoints in the collision geometry, unbiased) is held to
1.5 cm; the UR5–Panda pair (3.3 cm, a first build) and the UR5 pair's far range (2.0–2.2 cm) to
theirs (README Limitations), so they cannot regress."""
# pairs whose uniform joint samples include enough contacts for a spot check (the farther UR5
# pairs touch only when both arms reach toward each other)
CLOSE_PAIRS = ["ur5_ur5", "ur5_kinova"]


@pytest.mark.parametrize("pair", PAIRS)
def test_agrees_with_exact_distance_near_contact(pair: str) -> None:
    """A fresh spot check (the full figures come from bench/distance_nets.py): uniform samples,
    plus samples around contact where uniform ones seldom touch (the farther UR5 pairs)."""
    model = load_distance_model(pair)
    near_contact = 0 if pair in CLOSE_PAIRS else 2000
    q, d = generate(DatasetSpec(pair, 2000, near_contact, seed=123), workers=1)
    # far ranges touch seldom, near-contact draws included: draw more (fixed seeds) until the
    # contact share below is read over enough contacts
    for seed in range(124, 128):
        if (d < 0).sum() >= 200 or not near_contact:
            break
        q_more, d_more = generate(DatasetSpec(pair, 0, 4 * near_contact, seed=seed), workers=1)
        q, d = np.concatenate([q, q_more]), np.concatenate([d, d_more])
    pred = model.distance(q)
    near = d < 0.1
    assert near.sum() > 150 and (d < 0).sum() > 80
    assert np.mean(np.abs(pred[near] - d[near])) < BELOW_BAR.get(pair, 0.02)
    # contacts read at most the model's conservative level: 0 with an offset, else the level
    # its distance certificate states (an unbiased model, as pair builds make)
    card = json.loads(distance_model_path(pair).with_suffix(".json").read_text())
    unbiased = any(c.get("unbiased") for c in card.get("calibrations", []))
    level = max(c["level_m"] for c in card["certificates"]) if unbiased else 0.0
    assert not unbiased or float(model.output_offset) == 0.0
    assert np.mean(pred[d < 0] > level) < 0.05


@pytest.mark.parametrize("pair", PAIRS)
def test_gradient_matches_finite_differences(pair: str) -> None:
    model = load_distance_model(pair)
    q = uniform_samples(pair, 8, np.random.default_rng(5))
    _, grad = model.distance_and_gradient(q)
    h = 1e-6
    for j in range(q.shape[1]):
        e = np.zeros(q.shape[1])
        e[j] = h
        fd = (model.distance(q + e) - model.distance(q - e)) / (2 * h)
        np.testing.assert_allclose(grad[:, j], fd, atol=1e-6, rtol=1e-5)


@pytest.mark.parametrize("pair", PAIRS)
def test_single_and_batched_calls_agree(pair: str) -> None:
    model = load_distance_model(pair)
    q = uniform_samples(pair, 4, np.random.default_rng(6))
    d, g = model.distance_and_gradient(q)
    d0, g0 = model.distance_and_gradient(q[0])
    assert np.ndim(d0) == 0 and g0.shape == (q.shape[1],)
    assert d0 == pytest.approx(d[0]) and model.distance(q[0]) == pytest.approx(d[0])
    np.testing.assert_allclose(g0, g[0])


def _own_points(pair: str) -> bool:
    config = json.loads(distance_model_path(pair).with_suffix(".json").read_text())["config"]
    return bool(config.get("points1") or config.get("points2"))


MIRRORED = [
    p
    for p in PAIRS
    if not any(robot_facts(r).keypoint_points for r in arm_pair(p).robots) and not _own_points(p)
]
"""Pairs whose keypoints are all link-frame origins (no points fixed off a link's origin, no
points of the model's own in the collision geometry)."""


@pytest.mark.parametrize("pair", MIRRORED)
def test_invariant_under_the_pair_mirror_map(pair: str) -> None:
    """Keypoints sit on joint-frame origins, which the map mirrors exactly: l(f(x)) = l(x)."""
    cell, a, b = pair_cell(pair)
    f = robot_mirror_map(cell.arm(a).robot.name) + robot_mirror_map(cell.arm(b).robot.name)
    model = load_distance_model(pair)
    q = uniform_samples(pair, 500, np.random.default_rng(8))
    joints = q.shape[1] - model.n_cond  # a conditioned model's r is not mirrored
    mirrored = np.c_[f.apply(q[:, :joints]), q[:, joints:]]
    np.testing.assert_allclose(model.distance(mirrored), model.distance(q), atol=1e-6)


def test_model_is_periodic_in_continuous_joints() -> None:
    model = load_distance_model("ur5_ur5")
    q = uniform_samples("ur5_ur5", 20, np.random.default_rng(9))
    shifted = q + 2 * np.pi * np.array([1, -1, 0, 1, 0, 1, 0, 1, 0, 0, -1, 0])
    np.testing.assert_allclose(model.distance(shifted), model.distance(q), atol=1e-9)


def test_torch_module_differentiable_in_float64() -> None:
    model = load_distance_model("ur5_ur5")
    q = torch.from_numpy(uniform_samples("ur5_ur5", 3, np.random.default_rng(1)))
    q.requires_grad_(True)
    assert torch.autograd.gradcheck(model, (q,))


def test_unknown_model_lists_valid_names() -> None:
    with pytest.raises(UnknownNameError, match="ur5_kinova"):
        load_distance_model("ur5_ur10")


def _copy_model(tmp_path: Path) -> Path:
    for suffix in (".safetensors", ".json"):
        shutil.copy(MODELS_DIR / f"distance_ur5_ur5{suffix}", tmp_path / f"m{suffix}")
    return tmp_path / "m.safetensors"


def test_corrupted_weights_are_rejected(tmp_path: Path) -> None:
    path = _copy_model(tmp_path)
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(ModelFileError, match="cannot load weights"):
        load_distance_file(path)


def test_wrong_pair_and_version_are_rejected(tmp_path: Path) -> None:
    path = _copy_model(tmp_path)
    with pytest.raises(ModelFileError, match="not 'ur5_kinova'"):
        load_distance_file(path, expect_pair="ur5_kinova")
    card = json.loads(path.with_suffix(".json").read_text())
    card["format_version"] = 99
    path.with_suffix(".json").write_text(json.dumps(card))
    with pytest.raises(ModelFileError, match="format version 99"):
        load_distance_file(path)
    path.with_suffix(".json").write_text("{not json")
    with pytest.raises(ModelFileError, match="corrupted model card"):
        load_distance_file(path)


def test_missing_files_are_reported(tmp_path: Path) -> None:
    with pytest.raises(ModelFileError, match="not found"):
        load_distance_file(tmp_path / "none.safetensors")
