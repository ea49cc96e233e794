"""A small, smooth learned signed distance between two arms.

``PairDistanceModel`` maps a joint vector ``q = (q¹, q²)`` (B, n1 + n2) [rad] to the signed
distance [m] between the two arms' collision geometry. Instead of feeding raw angles to a large
network (the authors use 10 × 1024 units), it computes keypoints on both arms with forward
kinematics (link-frame origins and points interpolated between consecutive origins) and feeds
the pairwise keypoint distances (plus two soft minima of them) to a small SiLU MLP. This makes
the model periodic in every joint, smooth, cheap, and, because the UR5 symmetry map mirrors
every joint-frame origin exactly, invariant under that map by construction.

Arm 1 sits at the pair frame's origin, arm 2 at ``base2`` in that frame. A *pose-conditioned*
model (``base2_range`` set) takes one more input, the base distance ``r`` [m]: arm 2 then sits
at ``base2 + (r, 0, 0)``, so ``q = (q¹, q², r)``. Any two arms whose first joints turn them
about vertical base axes at the same height reduce to that frame (see
:mod:`nehmo_core.planning.models.pair_frame`), so one conditioned model serves every layout.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from safetensors.torch import load_file, save_file
from torch import nn

from nehmo_core.errors import ModelFileError, UnknownNameError
from nehmo_core.geometry.kinematics import ArmKinematics
from nehmo_core.robots.loader import load_robot
from nehmo_core.robots.model import LinkPoint, Pose, RobotModel
from nehmo_core.robots.registry import (
    OPTIONAL,
    ROBOT_NAMES,
    SHIPPED,
    distance_pairs,
    model_file,
    robot_facts,
)

FORMAT_VERSION = 1


@dataclass(frozen=True)
class DistanceModelConfig:
    """Everything needed to rebuild a :class:`PairDistanceModel` (stored in its model card)."""

    robot1: str
    robot2: str
    base2_xyz: tuple[float, float, float]
    base2_rpy: tuple[float, float, float]
    hidden: tuple[int, ...] = (128, 128, 128)
    softmin_betas: tuple[float, ...] = (20.0, 60.0)
    base2_range: tuple[float, float] | None = None  # conditioned: r [m] added to base2's x
    # Each arm's keypoints ``(link, x, y, z)`` in link frames [m], when the model has its own
    # (:func:`~nehmo_core.geometry.collision_points.collision_points`); None: the robot
    # description's keypoints (link origins, segments and points).
    points1: tuple[LinkPoint, ...] | None = None
    points2: tuple[LinkPoint, ...] | None = None

    @property
    def conditioned(self) -> bool:
        return self.base2_range is not None


class _Keypoints(nn.Module):
    """An arm's keypoints: the model's own points fixed in link frames (``points``), else the
    robot description's (``robot.facts``): link-frame origins, segments between two links'
    origins with the number of interior points to place on each, and points in link frames."""

    def __init__(
        self,
        robot: RobotModel,
        base: Pose,
        points: tuple[LinkPoint, ...] | None = None,
    ) -> None:
        super().__init__()
        self.kin = ArmKinematics(robot, base)
        if points is not None:
            self.origins: list[str] = []
            self.segments: list[tuple[str, str, int]] = []
            source = points
        else:
            if not robot.facts.keypoints:
                known = [n for n in ROBOT_NAMES if robot_facts(n).keypoints]
                raise UnknownNameError("keypoint set", robot.name, known)
            self.origins = list(robot.facts.keypoints)
            self.segments = list(robot.facts.keypoint_segments)
            source = robot.facts.keypoint_points
        self.points: list[tuple[str, tuple[float, float, float]]] = [
            (link, (x, y, z)) for link, x, y, z in source
        ]
        self.count = len(self.origins) + sum(s[2] for s in self.segments) + len(self.points)

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        tf = self.kin.link_transforms(q)
        pts = [tf[n][:, :3, 3] for n in self.origins]
        for a, b, k in self.segments:
            pa, pb = tf[a][:, :3, 3], tf[b][:, :3, 3]
            for i in range(1, k + 1):
                s = i / (k + 1)
                pts.append((1.0 - s) * pa + s * pb)
        for link, offset in self.points:
            T = tf[link]
            pts.append(T[:, :3, 3] + T[:, :3, :3] @ T.new_tensor(offset))
        return torch.stack(pts, dim=1)  # (B, P, 3)


class PairDistanceModel(nn.Module):
    """Learned signed distance [m] between two arms; ``forward(q)`` with q (B, n1 + n2)."""

    feat_mean: torch.Tensor  # (F,) feature standardization
    feat_std: torch.Tensor  # (F,)
    output_offset: torch.Tensor  # () [m] conservative calibration, subtracted from the MLP

    def __init__(self, config: DistanceModelConfig) -> None:
        super().__init__()
        self.config = config
        self.r1 = load_robot(config.robot1)
        self.r2 = load_robot(config.robot2)
        self.n1, self.n2 = self.r1.dof, self.r2.dof
        self.kp1 = _Keypoints(self.r1, Pose(), config.points1)
        self.kp2 = _Keypoints(self.r2, Pose(config.base2_xyz, config.base2_rpy), config.points2)
        self.n_cond = 1 if config.conditioned else 0
        n_feat = self.kp1.count * self.kp2.count + len(config.softmin_betas) + self.n_cond
        self.register_buffer("feat_mean", torch.zeros(n_feat, dtype=torch.float64))
        self.register_buffer("feat_std", torch.ones(n_feat, dtype=torch.float64))
        self.register_buffer("output_offset", torch.zeros((), dtype=torch.float64))
        layers: list[nn.Module] = []
        width = n_feat
        for h in config.hidden:
            layers += [nn.Linear(width, h), nn.SiLU()]
            width = h
        layers.append(nn.Linear(width, 1))
        self.mlp = nn.Sequential(*layers).double()

    @property
    def dof(self) -> int:
        """Input width: both arms' joints, plus the base distance of a conditioned model."""
        return self.n1 + self.n2 + self.n_cond

    def features(self, q: torch.Tensor) -> torch.Tensor:
        """Raw features (B, F): pairwise keypoint distances [m], their soft minima (and ``r``)."""
        n = self.n1 + self.n2
        p1 = self.kp1(q[:, : self.n1])
        p2 = self.kp2(q[:, self.n1 : n])
        if self.n_cond:
            shift = torch.zeros(q.shape[0], 1, 3, dtype=p2.dtype)
            shift[:, 0, 0] = q[:, n].to(p2.dtype)
            p2 = p2 + shift
        # |a − b|² = |a|² + |b|² − 2 a·b: one small batched product instead of a (B, P1, P2, 3)
        # difference tensor (several times faster at training batch sizes).
        sq = (p1 * p1).sum(-1)[:, :, None] + (p2 * p2).sum(-1)[:, None, :]
        d2 = sq - 2.0 * (p1 @ p2.transpose(1, 2))
        dist = torch.sqrt(d2.clamp_min(1e-12)).flatten(1)
        soft = [
            -torch.logsumexp(-beta * dist, dim=1, keepdim=True) / beta
            for beta in self.config.softmin_betas
        ]
        extra = [q[:, n:].to(dist.dtype)] if self.n_cond else []
        return torch.cat([dist, *soft, *extra], dim=1)

    def head(self, features: torch.Tensor) -> torch.Tensor:
        """The MLP on raw features (B, F) → distance (B,) [m]."""
        z = (features - self.feat_mean) / self.feat_std
        return self.mlp(z).squeeze(-1) - self.output_offset

    def forward(self, q: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(q))

    # ---- numpy convenience -------------------------------------------------------------
    def distance(self, q: np.ndarray) -> np.ndarray:
        """Batched value: ``q`` (B, n) or (n,) [rad] → distance (B,) or () [m]."""
        arr = np.asarray(q, dtype=np.float64)
        with torch.no_grad():
            out = self(torch.from_numpy(np.atleast_2d(arr))).numpy()
        return out if arr.ndim == 2 else out[0]

    def distance_and_gradient(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batched value (B,) [m] and gradient (B, n) [m/rad]; 1-D input gives unbatched output."""
        arr = np.asarray(q, dtype=np.float64)
        qt = torch.from_numpy(np.atleast_2d(arr).copy()).requires_grad_(True)
        d = self(qt)
        (g,) = torch.autograd.grad(d.sum(), qt)
        dv, gv = d.detach().numpy(), g.numpy()
        return (dv, gv) if arr.ndim == 2 else (dv[0], gv[0])

    # ---- persistence ---------------------------------------------------------------------
    def save(self, path: Path, card: dict[str, Any]) -> None:
        """Write ``path`` (.safetensors) and ``path.with_suffix('.json')`` (the model card)."""
        path.parent.mkdir(parents=True, exist_ok=True)
        tensors = {k: v.detach().contiguous() for k, v in self.state_dict().items()}
        save_file(tensors, str(path), metadata={"format_version": str(FORMAT_VERSION)})
        full = {"format_version": FORMAT_VERSION, "config": asdict(self.config), **card}
        path.with_suffix(".json").write_text(json.dumps(full, indent=2) + "\n")


def _config_from_card(card: dict[str, Any]) -> DistanceModelConfig:
    c = card["config"]
    return DistanceModelConfig(
        robot1=c["robot1"],
        robot2=c["robot2"],
        base2_xyz=tuple(c["base2_xyz"]),
        base2_rpy=tuple(c["base2_rpy"]),
        hidden=tuple(c["hidden"]),
        softmin_betas=tuple(c["softmin_betas"]),
        base2_range=tuple(c["base2_range"]) if c.get("base2_range") else None,
        points1=_points(c.get("points1")),
        points2=_points(c.get("points2")),
    )


def _points(raw: Any) -> tuple[LinkPoint, ...] | None:
    if raw is None:
        return None
    return tuple((str(link), float(x), float(y), float(z)) for link, x, y, z in raw)


def load_distance_file(path: Path, expect_pair: str | None = None) -> PairDistanceModel:
    """Load a distance model from ``path`` (.safetensors + .json card); never unpickles."""
    card_path = path.with_suffix(".json")
    if not path.exists() or not card_path.exists():
        raise ModelFileError(f"distance model files not found: {path} and {card_path}")
    try:
        card = json.loads(card_path.read_text())
    except json.JSONDecodeError as exc:
        raise ModelFileError(f"{card_path}: corrupted model card ({exc})") from exc
    if card.get("format_version") != FORMAT_VERSION:
        raise ModelFileError(
            f"{card_path}: format version {card.get('format_version')!r}, "
            f"this NeHMO reads version {FORMAT_VERSION}"
        )
    if expect_pair is not None and card.get("pair") != expect_pair:
        raise ModelFileError(
            f"{card_path}: model is for pair {card.get('pair')!r}, not {expect_pair!r}"
        )
    model = PairDistanceModel(_config_from_card(card))
    try:
        state = load_file(str(path))
        model.load_state_dict(state)
    except Exception as exc:  # safetensors raises several types on corrupted files
        raise ModelFileError(f"{path}: cannot load weights ({exc})") from exc
    model.eval()
    return model


def distance_model_path(pair: str) -> Path:
    """Where the distance model of ``pair`` lives: ``models/distance_<pair>.safetensors`` (what
    ``nehmo distance train`` and ``calibrate`` write unless given another path)."""
    return model_file(pair, f"distance_{pair}.safetensors")


OPTIONAL_DISTANCE_MODELS = distance_pairs(OPTIONAL)
"""Pairs whose code path exists but whose weights this repository does not ship: once
``nehmo distance train --pair <pair>`` has written ``models/distance_<pair>.safetensors`` (and its
card), :func:`load_distance_model` loads it and it counts as shipped."""
SHIPPED_DISTANCE_MODELS = (
    *distance_pairs(SHIPPED),
    *(p for p in OPTIONAL_DISTANCE_MODELS if distance_model_path(p).exists()),
)
"""Pairs whose learned distance is in ``models/`` (the optional ones as found at import; both
lists come from :data:`~nehmo_core.robots.registry.ARM_PAIRS`)."""
DISTANCE_MODELS = tuple(dict.fromkeys([*SHIPPED_DISTANCE_MODELS, *OPTIONAL_DISTANCE_MODELS]))
"""Every pair :func:`load_distance_model` knows by name."""


def load_distance_model(pair: str) -> PairDistanceModel:
    """Load a shipped learned distance: ``load_distance_model("ur5_ur5")``.

    The returned model has ``distance(q)`` and ``distance_and_gradient(q)`` (numpy, batched)
    and is a torch module (``model(q)``) for use inside value functions. A pair of
    :data:`OPTIONAL_DISTANCE_MODELS` not trained yet raises :class:`ModelFileError` saying how
    to make it.
    """
    if pair not in DISTANCE_MODELS:
        raise UnknownNameError("distance model", pair, DISTANCE_MODELS)
    path = distance_model_path(pair)
    if pair in OPTIONAL_DISTANCE_MODELS and not path.exists():
        raise ModelFileError(
            f"the {pair} distance model is not shipped and not trained yet ({path} is missing): "
            f"make it with 'nehmo distance generate --pair {pair} ...' and "
            f"'nehmo distance train --pair {pair} --data ...' (they write {path.name})"
        )
    return load_distance_file(path, expect_pair=pair)
