"""The learned pair distance as a CasADi graph (for solvers and generated C code).

:func:`distance_expression` rebuilds :class:`~nehmo_core.geometry.distance_model.PairDistanceModel`
symbolically: forward kinematics of both arms from the URDF chain (the fixed transforms, joint
axes and joint indices that :class:`~nehmo_core.geometry.kinematics.ArmKinematics` flattened),
the keypoints (link-frame origins and points between them), their pairwise distances and soft
minima, then the SiLU MLP with the model's feature normalization and output offset. Weights
become constants of the graph, so a generated C function carries them. Everything is float64;
the graph equals the torch model up to rounding (the tests check 1e-9).
:func:`swapped_distance_value_and_gradient` feeds the model the two arms' joint vectors in the
other order (the boundary of a game whose controlled arm is the model's second arm).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np
from torch import nn

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.geometry.distance_model import PairDistanceModel
from nehmo_core.geometry.kinematics import ArmKinematics

__all__ = [
    "distance_expression",
    "distance_function",
    "distance_value_and_gradient",
    "features_expression",
    "keypoints_expression",
    "mlp_value_and_gradient",
    "swapped_distance_value_and_gradient",
]

_DIST_EPS = 1e-12  # the model's clamp on squared distances [m²]


def _numpy(t: Any) -> np.ndarray:
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
    for link, offset in keypoints.points:  # type: ignore[union-attr]
        T = tf[link]
        pts.append(T[:3, 3] + ca.mtimes(T[:3, :3], ca.DM(offset)))
    return ca.horzcat(*pts)


def features_expression(model: PairDistanceModel, q: ca.MX) -> ca.MX:
    """Raw features (F,): pairwise keypoint distances (row-major) [m] and their soft minima."""
    n = model.n1 + model.n2
    p1 = keypoints_expression(model.kp1, q[: model.n1])  # (3, P)
    p2 = keypoints_expression(model.kp2, q[model.n1 : n])  # (3, Q)
    if model.n_cond:  # conditioned: arm 2's base shifted by r along x
        p2 = p2 + ca.repmat(ca.vertcat(q[n], 0.0, 0.0), 1, p2.shape[1])
    n_p, n_q = p1.shape[1], p2.shape[1]
    # |a − b|² = |a|² + |b|² − 2 a·b, clamped at 1e-12 m², exactly as the torch model computes it
    # (a feature with a tiny standard deviation amplifies any other rounding of it).
    sq = ca.repmat(ca.sum1(p1 * p1).T, 1, n_q) + ca.repmat(ca.sum1(p2 * p2), n_p, 1)
    d2 = sq - 2.0 * ca.mtimes(p1.T, p2)  # (P, Q)
    dist = ca.sqrt(ca.fmax(ca.reshape(d2.T, 1, n_p * n_q), _DIST_EPS))  # row-major (1, P·Q)
    lowest = ca.mmin(dist)
    soft = [
        lowest - ca.log(ca.sum2(ca.exp(-beta * (dist - lowest)))) / beta
        for beta in model.config.softmin_betas
    ]
    extra = [q[n:]] if model.n_cond else []
    return ca.vertcat(dist.T, *soft, *extra)


def _dense_row(h: ca.MX, layer: nn.Linear) -> ca.MX:
    """``h W^T + b`` for a row vector ``h`` (1, n_in) → (1, n_out).

    The row form makes generated C read the constant matrix contiguously (one dot product per
    output), which is ~5× faster than CasADi's column-major matrix-vector loop.
    """
    return ca.mtimes(h, ca.DM(_numpy(layer.weight).T)) + ca.DM(_numpy(layer.bias)[None, :])


def _silu(h: ca.MX) -> tuple[ca.MX, ca.MX]:
    """``(silu(h), silu'(h))`` elementwise."""
    sig = 1.0 / (1.0 + ca.exp(-h))
    return h * sig, sig * (1.0 + h * (1.0 - sig))


def mlp_value_and_gradient(mlp: nn.Sequential, z: ca.MX) -> tuple[ca.MX, ca.MX]:
    """A ``Linear``/``SiLU`` stack with one output on ``z`` (F,): ``(out, ∂out/∂z (F,))``.

    The backward pass is written out (reverse mode by hand) with contiguous constant matrices;
    CasADi's own reverse mode would transpose every weight matrix at run time.
    """
    h = z.T
    layers: list[nn.Linear] = []
    slopes: list[ca.MX | None] = []
    for layer in mlp:
        if isinstance(layer, nn.Linear):
            h = _dense_row(h, layer)
            layers.append(layer)
            slopes.append(None)
        elif isinstance(layer, nn.SiLU):
            h, slope = _silu(h)
            slopes[-1] = slope
        else:
            raise NehmoError(f"cannot export layer {type(layer).__name__} of a distance MLP")
    g: Any = ca.MX(ca.DM.ones(1, 1))
    for linear, gain in zip(reversed(layers), reversed(slopes), strict=True):
        if gain is not None:
            g = g * gain
        g = ca.mtimes(g, ca.DM(_numpy(linear.weight)))
    return h, g.T


def _distance_graph(model: PairDistanceModel, q: ca.MX) -> tuple[ca.MX, ca.MX]:
    """``(l, ∇_q l)`` for a purely symbolic ``q`` (reverse mode needs a symbol)."""
    features = features_expression(model, q)
    std = ca.DM(_numpy(model.feat_std))
    z = (features - ca.DM(_numpy(model.feat_mean))) / std
    value, grad_z = mlp_value_and_gradient(model.mlp, z)
    offset = getattr(model, "output_offset", None)  # conservative calibration [m], if any
    if offset is not None:
        value = value - float(offset)
    grad_q = ca.jtimes(features, q, grad_z / std, True)  # reverse mode through FK and features
    return value, grad_q


def distance_value_and_gradient(model: PairDistanceModel, q: ca.MX) -> tuple[ca.MX, ca.MX]:
    """``(l, ∇_q l)`` [m], [m/rad] for the pair joint vector ``q`` (n1 + n2,) [rad].

    ``q`` may be any expression: the model is embedded as a call of :func:`distance_function`.
    """
    value, grad = distance_function(model)(q)
    return value, grad


def swapped_distance_value_and_gradient(
    model: PairDistanceModel, q: ca.MX, n_first: int
) -> tuple[ca.MX, ca.MX]:
    """``(l, ∇_q l)`` of ``l(q) = d(q₂, q₁[, r])`` for ``q = (q₁, q₂[, r])``, ``d`` = ``model``.

    ``q`` (n1 + n2 [+ 1],) [rad] holds the model's second arm first (``n_first`` = its joint
    count), then its first arm, then a conditioned model's base distance ``r`` [m], as
    :class:`~nehmo_core.hjr.systems.arm_pairs.SwappedBoundary` does in torch.
    """
    if n_first != model.n2:
        raise InvalidValueError(
            "n_first", f"must equal the joint count of the model's second arm ({model.n2})", n_first
        )
    if q.shape[0] != model.dof:
        raise InvalidValueError("q", f"must have {model.dof} rows", q.shape[0])
    n = model.n1 + model.n2
    swapped = ca.vertcat(q[n_first:n], q[:n_first], q[n:])
    value, grad = distance_value_and_gradient(model, swapped)
    return value, ca.vertcat(grad[model.n1 : n], grad[: model.n1], grad[n:])


def distance_expression(model: PairDistanceModel, q: ca.MX) -> ca.MX:
    """Signed distance [m] for the pair joint vector ``q`` (n1 + n2,) [rad]."""
    return distance_value_and_gradient(model, q)[0]


def distance_function(model: PairDistanceModel, name: str = "pair_distance") -> ca.Function:
    """``name(q) -> (l, grad)``: the model and its gradient as a CasADi function of ``q``."""
    q = ca.MX.sym("q", model.dof)
    value, grad = _distance_graph(model, q)
    return ca.Function(name, [q], [value, grad], ["q"], ["l", "grad"])
