"""TwoLinkPair: the paper's pair of planar 2-link arms and its segment-distance boundary."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import Tensor, nn

from nehmo_core.hjr.systems.arm_pair import ArmPairSystem, JointInterval

__all__ = ["TwoLinkDistance", "TwoLinkPair", "segment_distance"]


def _point_segment_distance(p: Tensor, a: Tensor, b: Tensor) -> Tensor:
    """Distance from points ``p`` to segments ``[a, b]`` (all ``(B, 2)``), ``(B,)``."""
    ab = b - a
    t = ((p - a) * ab).sum(dim=1) / (ab * ab).sum(dim=1)
    closest = a + t.clamp(0.0, 1.0)[:, None] * ab
    squared = ((p - closest) ** 2).sum(dim=1)
    return torch.sqrt(squared.clamp_min(1e-18))  # clamp keeps the gradient finite on contact


def _cross(u: Tensor, v: Tensor) -> Tensor:
    return u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]


def segment_distance(a: Tensor, b: Tensor, c: Tensor, d: Tensor) -> Tensor:
    """Exact distance between planar segments ``[a, b]`` and ``[c, d]`` (each ``(B, 2)``) [m].

    In the plane the distance is 0 if the segments cross, else the smallest of the four
    endpoint-to-segment distances. Differentiable almost everywhere.
    """
    endpoint = torch.stack(
        [
            _point_segment_distance(a, c, d),
            _point_segment_distance(b, c, d),
            _point_segment_distance(c, a, b),
            _point_segment_distance(d, a, b),
        ],
        dim=1,
    ).amin(dim=1)
    # a proper crossing: each segment's ends strictly on both sides of the other's line. Touching
    # (an end on the other segment) and collinear overlap show in the endpoint distances, so the
    # zero cases stay out (two collinear segments apart would otherwise count as crossing).
    s1 = _cross(b - a, c - a) * _cross(b - a, d - a)
    s2 = _cross(d - c, a - c) * _cross(d - c, b - c)
    crossing = (s1 < 0.0) & (s2 < 0.0)
    return torch.where(crossing, torch.zeros_like(endpoint), endpoint)


class TwoLinkDistance(nn.Module):
    """``l(q) = min segment-segment distance − margin`` for two planar 2-link arms [m].

    Arm 1 is based at the origin with yaw 0, arm 2 at ``base2`` with yaw ``yaw2``. Each link is a
    segment; the four link pairs across the arms are checked (links of one arm are not).
    Input ``(B, 4) = (q¹₁, q¹₂, q²₁, q²₂)`` [rad], output ``(B,)``.
    """

    def __init__(
        self,
        link_lengths: tuple[float, float] = (0.5, 0.5),
        base2: tuple[float, float] = (1.4, 0.0),
        yaw2: float = math.pi,
        margin: float = 0.1,
    ) -> None:
        super().__init__()
        self.link_lengths = (float(link_lengths[0]), float(link_lengths[1]))
        self.base2 = (float(base2[0]), float(base2[1]))
        self.yaw2 = float(yaw2)
        self.margin = float(margin)

    def arm_points(self, q: Tensor, base: tuple[float, float], yaw: float) -> list[Tensor]:
        """Base, elbow and tip of one arm, each ``(B, 2)`` [m], for joint angles ``q (B, 2)``."""
        l1, l2 = self.link_lengths
        a1 = q[:, 0] + yaw
        a2 = a1 + q[:, 1]
        origin = q.new_tensor(base).expand(q.shape[0], 2)
        elbow = origin + l1 * torch.stack([torch.cos(a1), torch.sin(a1)], dim=1)
        tip = elbow + l2 * torch.stack([torch.cos(a2), torch.sin(a2)], dim=1)
        return [origin, elbow, tip]

    def forward(self, x: Tensor) -> Tensor:
        p = self.arm_points(x[:, :2], (0.0, 0.0), 0.0)
        r = self.arm_points(x[:, 2:4], self.base2, self.yaw2)
        pairs = [
            segment_distance(p[i], p[i + 1], r[j], r[j + 1]) for i in range(2) for j in range(2)
        ]
        return torch.stack(pairs, dim=1).amin(dim=1) - self.margin


@dataclass(frozen=True, eq=False)
class TwoLinkPair(ArmPairSystem):
    """The paper's "simple arm" pair: two planar 2-link arms, the authors' setting.

    Links 0.5 + 0.5 m, second base at (1.4, 0) with yaw π, ``q ∈ [−π, π]⁴``, ``T = 0.6`` s,
    ``ū = d̄ = 0.5`` rad/s, ``l = min segment distance − 0.1`` m. Symmetry ``q -> −q`` (the mirror
    across the line through both bases), ``X_train = {q²₂ ≥ 0}``.
    """

    boundary_fn: Callable[[Tensor], Tensor] = field(default_factory=TwoLinkDistance)
    n1: int = 2
    n2: int = 2
    symmetry_sign: Any = field(default_factory=lambda: -np.ones(4))
    symmetry_offset: Any = field(default_factory=lambda: np.zeros(4))
    train_region: JointInterval = field(default_factory=lambda: JointInterval(3, 0.0, math.pi))
    system_name: str = "two_link"
