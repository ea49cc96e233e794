"""Training and evaluation of :class:`PairDistanceModel` on exact-distance datasets."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from nehmo_core.errors import InvalidValueError
from nehmo_core.geometry.collision_points import collision_points
from nehmo_core.geometry.distance_data import (
    CONDITIONED_PAIRS,
    CUTOFF,
    PAIRS,
    pair_cell,
)
from nehmo_core.geometry.distance_model import DistanceModelConfig, PairDistanceModel
from nehmo_core.robots.registry import pair_base_range

KEYPOINT_SOURCES = ("links", "geometry")
"""``links``: the robot description's keypoints (link origins, segments, points); ``geometry``:
points in the bulk of each link's collision geometry
(:func:`~nehmo_core.geometry.collision_points.collision_points`), stored in the model's card."""


@dataclass(frozen=True)
class DistanceTrainSettings:
    """Optimizer settings. ``near_weight``/``near_scale`` up-weight samples close to contact;
    ``collision_margin`` [m] is the margin the penalty on colliding samples pushes them below;
    ``keypoints`` is where the model's keypoints come from (:data:`KEYPOINT_SOURCES`).
    ``lr`` is the one-cycle schedule's peak rate and ``grad_clip`` the largest gradient norm of a
    step: at a peak of 2e-3 without a clip the Kinova-Panda distance blew up at the peak (loss
    2e-3 to 0.46) and ended 30 times above the Kinova pair's (5 cm mean error)."""

    hidden: tuple[int, ...] = (128, 128, 128)
    epochs: int = 40
    batch: int = 2048
    lr: float = 1e-3
    grad_clip: float = 1.0
    weight_decay: float = 1e-5
    near_weight: float = 9.0
    near_scale: float = 0.05
    collision_weight: float = 10.0
    collision_margin: float = 0.01
    calibration_share: float = 0.05
    target_false_safe: float = 0.015
    seed: int = 0
    keypoints: str = "links"

    def __post_init__(self) -> None:
        if self.keypoints not in KEYPOINT_SOURCES:
            raise InvalidValueError(
                "keypoints", f"must be one of {KEYPOINT_SOURCES}", self.keypoints
            )
        for name in ("epochs", "batch"):
            if getattr(self, name) <= 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        for name in ("lr", "grad_clip"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))


def new_model(pair: str, hidden: tuple[int, ...], keypoints: str = "links") -> PairDistanceModel:
    cell, a, b = pair_cell(pair)
    arm2 = cell.arm(b)
    assert cell.arms[0].base.xyz == (0.0, 0.0, 0.0), "arm 1 of a pair cell sits at the origin"
    points1 = points2 = None
    if keypoints == "geometry":
        points1 = collision_points(cell.arm(a).robot)
        points2 = collision_points(arm2.robot)
    cfg = DistanceModelConfig(
        robot1=cell.arms[0].robot.name,
        robot2=arm2.robot.name,
        base2_xyz=arm2.base.xyz,
        base2_rpy=arm2.base.rpy,
        hidden=hidden,
        base2_range=pair_base_range(pair) if pair in CONDITIONED_PAIRS else None,
        points1=points1,
        points2=points2,
    )
    return PairDistanceModel(cfg)


def compute_features(model: PairDistanceModel, q: np.ndarray, chunk: int = 16384) -> torch.Tensor:
    """Raw features (N, F) as float32, computed in chunks without gradients."""
    out = []
    with torch.no_grad():
        for i in range(0, len(q), chunk):
            out.append(model.features(torch.from_numpy(q[i : i + chunk])).float())
    return torch.cat(out)


def _loss(pred: torch.Tensor, d: torch.Tensor, s: DistanceTrainSettings) -> torch.Tensor:
    w = 1.0 + s.near_weight * torch.exp(-d.abs() / s.near_scale)
    fit = (w * (pred - d) ** 2).mean()
    colliding = (d < 0).float()
    push = (colliding * torch.relu(pred + s.collision_margin) ** 2).mean()
    return fit + s.collision_weight * push


def train(
    pair: str, q: np.ndarray, d: np.ndarray, settings: DistanceTrainSettings
) -> tuple[PairDistanceModel, dict[str, float]]:
    """Fit a model on (q, d); returns the model and a summary (wall time, final losses)."""
    if pair not in PAIRS and pair not in CONDITIONED_PAIRS:
        raise InvalidValueError(
            "pair", f"must be one of {sorted([*PAIRS, *CONDITIONED_PAIRS])}", pair
        )
    torch.manual_seed(settings.seed)
    t0 = time.perf_counter()
    model = new_model(pair, settings.hidden, settings.keypoints)
    # Hold out a calibration split: the output offset is chosen on it, never on test data.
    order = np.random.default_rng(settings.seed).permutation(len(q))
    n_cal = int(settings.calibration_share * len(q))
    q_cal, d_cal = q[order[:n_cal]], d[order[:n_cal]]
    q, d = q[order[n_cal:]], d[order[n_cal:]]
    feats = compute_features(model, q)
    mean, std = feats.mean(0), feats.std(0).clamp_min(1e-6)
    with torch.no_grad():
        model.feat_mean.copy_(mean.double())
        model.feat_std.copy_(std.double())
    z = (feats - mean) / std
    target = torch.from_numpy(np.minimum(d, CUTOFF)).float()
    mlp = model.mlp.float()
    opt = torch.optim.AdamW(mlp.parameters(), lr=settings.lr, weight_decay=settings.weight_decay)
    steps_per_epoch = math.ceil(len(z) / settings.batch)
    total = settings.epochs * steps_per_epoch
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, settings.lr, total_steps=total)
    gen = torch.Generator().manual_seed(settings.seed)
    bar = tqdm(range(settings.epochs), desc=f"train {pair}", unit="epoch")
    last = math.nan
    for _ in bar:
        perm = torch.randperm(len(z), generator=gen)
        acc = 0.0
        for i in range(steps_per_epoch):
            idx = perm[i * settings.batch : (i + 1) * settings.batch]
            loss = _loss(mlp(z[idx]).squeeze(-1), target[idx], settings)
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(mlp.parameters(), settings.grad_clip)
            opt.step()
            sched.step()
            acc += float(loss.detach())
        last = acc / steps_per_epoch
        bar.set_postfix(loss=f"{last:.3e}")
    model.mlp.double()
    model.eval()
    offset = calibrate_offset(model, q_cal, d_cal, settings.target_false_safe)
    summary = {
        "train_wall_time_s": time.perf_counter() - t0,
        "final_loss": last,
        "output_offset_m": offset,
        "calibration_samples": n_cal,
    }
    return model, summary


def calibrate_offset(
    model: PairDistanceModel, q: np.ndarray, d: np.ndarray, target_false_safe: float
) -> float:
    """Smallest offset [m] (0 to 3 cm) whose subtraction brings the share of colliding
    calibration samples predicted safe (> 0) to ``target_false_safe``; stored in the model."""
    with torch.no_grad():
        model.output_offset.zero_()
        pred = model.head(compute_features(model, q).double()).numpy()
    colliding = pred[d < 0]
    offset = 0.0
    if len(colliding) and np.mean(colliding > 0) > target_false_safe:
        offset = float(np.quantile(colliding, 1.0 - target_false_safe))
    offset = min(max(offset, 0.0), 0.03)
    with torch.no_grad():
        model.output_offset.fill_(offset)
    return offset


def evaluate(model: PairDistanceModel, q: np.ndarray, d: np.ndarray) -> dict[str, float]:
    """Accuracy figures on labelled samples (true distances ``d`` [m])."""
    if len(d) == 0:
        raise InvalidValueError("d", "must hold at least one labelled sample", len(d))
    feats = compute_features(model, q).double()
    with torch.no_grad():
        pred = model.head(feats).numpy()
    dt = np.minimum(d, CUTOFF)
    err = np.abs(pred - dt)
    near = dt < 0.1
    coll = dt < 0
    return {
        "n": len(d),
        "mae_m": float(err.mean()),
        "mae_near_m": float(err[near].mean()) if near.any() else math.nan,
        "n_near": int(near.sum()),
        "p95_err_near_m": float(np.percentile(err[near], 95)) if near.any() else math.nan,
        "collision_accuracy": float(np.mean((pred < 0) == coll)),
        "false_safe_rate": float(np.mean(pred[coll] > 0)) if coll.any() else math.nan,
        "false_unsafe_rate": float(np.mean(pred[~coll] <= 0)) if (~coll).any() else math.nan,
        "n_colliding": int(coll.sum()),
    }
