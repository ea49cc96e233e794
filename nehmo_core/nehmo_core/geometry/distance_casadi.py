"""The learned pair distance as a CasADi graph (for solvers and generated C code).

:func:`distance_expression` rebuilds :class:`~nehmo_core.geometry.distance_model.PairDistanceModel`
symbolically: forward kinematics of both arms from the URDF chain (the fixed transforms, joint
axes and joint indices that :class:`~nehmo_core.geometry.kinematics.ArmKinematics` flattened),
the keypoints (link-frame origins and points between them), their pairwise distances and soft
minima, then the SiLU MLP with the model's feature normalization. Weights become constants of
the graph, so a generated C function carries them. Everything is float64; the graph equals the
torch model up to rounding (the tests check 1e-9).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import torch
from torch import nn

from nehmo_core.errors import NehmoError
from nehmo_core.geometry.distance_model import PairDistanceModel
from nehmo_core.geometry.kinematics import ArmKinematics

__all__ = ["distance_expression", "distance_function", "keypoints_expression", "mlp_expression"]

_DIST_EPS = 1e-12  # the model's sqrt regularizer [m²]


def _numpy(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().double().numpy()


def _rotation(axis: np.ndarray, angle: ca.MX) -> ca.MX:
    """Homogeneous rotation (4, 4) about a unit ``axis`` by ``angle`` [rad] (Rodrigues)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    k4 = np.zeros((4, 4))
    k4[:3, :3] = k
    k2 = np.zeros((4, 4))
    k2[:3, :3] = k @ k
    return ca.DM(np.eye(4)) + ca.sin(angle) * ca.DM(k4) + (1.0 - ca.cos(angle)) * ca.DM(k2)


def link_transforms_expression(kin: ArmKinematics, q: ca.MX) -> dict[str, ca.MX]:
    """``T_world_link`` (4, 4) per link of ``kin``'s chain for joint angles ``q`` (dof,) [rad]."""
    T: ca.MX = ca.MX(ca.DM(_numpy(kin.T_world_base)))
    out = {kin.root_link: T}
    for step in kin._steps:
        T = ca.mtimes(T, ca.DM(_numpy(step.T_parent_joint)))
        if step.axis is not None:
            T = ca.mtimes(T, _rotation(_numpy(step.axis), q[step.q_index]))
        out[step.link] = T
    return out


def keypoints_expression(keypoints: nn.Module, q: ca.MX) -> ca.MX:
    """Keypoints (3, P) [m] of one arm, in the same order as the torch ``_Keypoints`` module."""
    tf = link_transforms_expression(keypoints.kin, q)  # type: ignore[arg-type]
    pts = [tf[name][:3, 3] for name in keypoints.origins]  # type: ignore[union-attr]
    for a, b, k in keypoints.segments:  # type: ignore[union-attr]
        pa, pb = tf[a][:3, 3], tf[b][:3, 3]
        for i in range(1, k + 1):
            s = i / (k + 1)
            pts.append((1.0 - s) * pa + s * pb)
    return ca.horzcat(*pts)


def _selection(rows: int, other: int, first: bool) -> ca.DM:
    """Sparse (rows, rows·other) matrix repeating columns in row-major pair order."""
    cols = rows * other
    r, c = [], []
    for i in range(rows if first else other):
        for j in range(other if first else rows):
            r.append(i if first else j)
            c.append(i * other + j if first else i * rows + j)
    sp = ca.Sparsity.triplet(rows, cols, r, c)
    return ca.DM(sp, 1.0)


def features_expression(model: PairDistanceModel, q: ca.MX) -> ca.MX:
    """Raw features (F,): pairwise keypoint distances (row-major) [m] and their soft minima."""
    p1 = keypoints_expression(model.kp1, q[: model.n1])  # (3, P)
    p2 = keypoints_expression(model.kp2, q[model.n1 :])  # (3, Q)
    n_p, n_q = p1.shape[1], p2.shape[1]
    rep1 = ca.mtimes(p1, _selection(n_p, n_q, first=True))  # p1[i] at column i·Q + j
    rep2 = ca.mtimes(p2, _selection(n_q, n_p, first=False))  # p2[j] at column i·Q + j
    diff = rep1 - rep2
    dist = ca.sqrt(ca.sum1(diff * diff) + _DIST_EPS)  # (1, P·Q)
    lowest = ca.mmin(dist)
    soft = [
        lowest - ca.log(ca.sum2(ca.exp(-beta * (dist - lowest)))) / beta
        for beta in model.config.softmin_betas
    ]
    return ca.vertcat(dist.T, *soft)


def mlp_expression(mlp: nn.Sequential, z: ca.MX) -> ca.MX:
    """A ``Linear``/``SiLU`` stack on ``z`` (F,); returns the output (1,)."""
    h = z
    for layer in mlp:
        if isinstance(layer, nn.Linear):
            h = ca.mtimes(ca.DM(_numpy(layer.weight)), h) + ca.DM(_numpy(layer.bias))
        elif isinstance(layer, nn.SiLU):
            h = h / (1.0 + ca.exp(-h))
        else:
            raise NehmoError(f"cannot export layer {type(layer).__name__} of a distance MLP")
    return h


def distance_expression(model: PairDistanceModel, q: ca.MX) -> ca.MX:
    """Signed distance [m] for the pair joint vector ``q`` (n1 + n2,) [rad]."""
    features = features_expression(model, q)
    mean = ca.DM(_numpy(model.feat_mean))
    std = ca.DM(_numpy(model.feat_std))
    return mlp_expression(model.mlp, (features - mean) / std)


def distance_function(model: PairDistanceModel, name: str = "pair_distance") -> ca.Function:
    """``name(q) -> l``: the model as a CasADi function of ``q`` (n1 + n2,) [rad] → [m]."""
    q = ca.MX.sym("q", model.dof)
    return ca.Function(name, [q], [distance_expression(model, q)], ["q"], ["l"])
