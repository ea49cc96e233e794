"""A trained arm-pair value function as CasADi functions ``V(τ, x)`` and ``∇ₓV(τ, x)``.

The graph reproduces :class:`~nehmo_core.hjr.networks.ValueFunction` for an
:class:`~nehmo_core.hjr.systems.ArmPairSystem` whose boundary is a
:class:`~nehmo_core.geometry.distance_model.PairDistanceModel` or a
:class:`~nehmo_core.hjr.systems.arm_pairs.SwappedBoundary` around one (see :func:`pair_boundary`):

1. periodic state coordinates are wrapped to ``(−π, π]`` (the planner's predicted states may
   cross ±π; the torch function expects states in the domain already, where this is the
   identity);
2. ``bc+sym`` folds ``X_sym`` into ``X_train`` with ``if_else`` (``x`` or ``f⁻¹(x)``);
3. the network input ``(τ̂, x̂)`` is scaled as ``ValueNetwork.network_input`` does;
4. the SIREN, plus the normalized boundary for ``bc``/``bc+sym``/``exact``;
5. ``V = W / value_scale + value_mean``.

Time ``τ`` is time-to-go [s] and is never mapped by the symmetry. Weights (float32 or float64 in
torch) become float64 constants, so the graph matches a ``.double()`` copy of the network.
"""

from __future__ import annotations

import math
from typing import Any

import casadi as ca
import numpy as np

from nehmo_core.errors import NehmoError
from nehmo_core.geometry.distance_casadi import (
    distance_value_and_gradient,
    swapped_distance_value_and_gradient,
)
from nehmo_core.geometry.distance_model import PairDistanceModel
from nehmo_core.hjr.networks import Siren, ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import ArmPairSystem
from nehmo_core.hjr.systems.arm_pairs import SwappedBoundary

__all__ = [
    "pair_boundary",
    "siren_expression",
    "siren_value_and_gradient",
    "value_and_gradient_expression",
    "value_expression",
    "value_functions",
    "wrap_expression",
]


def _numpy(t: Any) -> np.ndarray:
    return t.detach().cpu().double().numpy()


def wrap_expression(angle: ca.MX) -> ca.MX:
    """Wrap to ``(−π, π]`` like ``wrap_to_pi`` (floor-based; derivative 1 almost everywhere)."""
    period = 2.0 * math.pi
    a = math.pi - angle
    return math.pi - (a - period * ca.floor(a / period))


def _wrap_periodic(x: ca.MX, periodic: tuple[bool, ...]) -> ca.MX:
    rows = [wrap_expression(x[i]) if p else x[i] for i, p in enumerate(periodic)]
    return ca.vertcat(*rows)


def _fold(system: ArmPairSystem, x: ca.MX) -> tuple[ca.MX, Any]:
    """``(x_folded, Df)``: ``x`` if ``x ∈ X_train`` else ``f⁻¹(x)`` (``x`` already wrapped), and
    the diagonal of the fold's Jacobian (1 or the map's sign per coordinate)."""
    region = system.train_region
    q = x[region.joint]
    if system.periodic[region.joint]:
        q = wrap_expression(q)
    keep = ca.logic_and(q >= region.low, q <= region.high)
    sign = ca.DM(np.asarray(system.symmetry_sign, dtype=np.float64))
    offset = ca.DM(np.asarray(system.symmetry_offset, dtype=np.float64))
    inverse = _wrap_periodic(sign * (x - offset), system.periodic)
    ones = ca.DM.ones(x.shape[0], 1)
    return ca.if_else(keep, x, inverse), ca.if_else(keep, ones, sign)


def siren_value_and_gradient(siren: Siren, z: ca.MX) -> tuple[ca.MX, ca.MX]:
    """The SIREN on its input ``z`` (n + 1,): ``(out, ∂out/∂z (n + 1,))``.

    Layers are row-vector products with contiguous constant matrices and the backward pass is
    written out, which generated C evaluates several times faster than CasADi's reverse mode
    (that transposes each weight matrix at run time).
    """
    h = z.T
    slopes = []
    for layer in siren.hidden:
        pre = ca.mtimes(h, ca.DM(_numpy(layer.weight).T)) + ca.DM(_numpy(layer.bias)[None, :])
        h = ca.sin(siren.omega0 * pre)
        slopes.append(siren.omega0 * ca.cos(siren.omega0 * pre))
    out = siren.output
    value = ca.mtimes(h, ca.DM(_numpy(out.weight).T)) + ca.DM(_numpy(out.bias))
    g: Any = ca.MX(ca.DM(_numpy(out.weight)))  # (1, width)
    for layer, slope in zip(reversed(siren.hidden), reversed(slopes), strict=True):
        g = ca.mtimes(g * slope, ca.DM(_numpy(layer.weight)))
    return value, g.T


def siren_expression(siren: Siren, z: ca.MX) -> ca.MX:
    """The SIREN on its input ``z`` (n + 1,); returns the scalar output."""
    return siren_value_and_gradient(siren, z)[0]


def _network_input(network: ValueNetwork, tau: ca.MX, x: ca.MX) -> tuple[ca.MX, Any]:
    """``(z, ∂z_x/∂x)``: the network input and the (diagonal) scaling of its state part."""
    n = x.shape[0]
    if network.settings.input_scaling == "raw":
        return ca.vertcat(tau, x), ca.DM.ones(n, 1)
    tau_hat = 2.0 * tau / network.system.horizon - 1.0
    center = ca.DM(_numpy(network._center))
    half = ca.DM(_numpy(network._half_width))
    return ca.vertcat(tau_hat, (x - center) / half), 1.0 / half


def pair_boundary(system: object) -> tuple[PairDistanceModel, int | None]:
    """``(distance, n_first)``: the learned distance behind an arm-pair system's ``l(x)``.

    ``n_first`` is None when ``l = distance``, and the controlled arm's joint count when ``l`` is
    a :class:`~nehmo_core.hjr.systems.arm_pairs.SwappedBoundary` (``l(x) = distance(x₂, x₁)``, a
    conditioned pair's ``r`` last in both: the distance's second arm is the system's first).
    Anything else raises :class:`NehmoError`.
    """
    name = getattr(system, "name", type(system).__name__)
    if not isinstance(system, ArmPairSystem):
        raise NehmoError(f"system {name!r} is not an arm-pair system; it has no pair distance")
    fn = system.boundary_fn
    if isinstance(fn, PairDistanceModel):
        if (fn.n1, fn.n2) != (system.n1, system.n2):
            raise NehmoError(
                f"boundary of system {name!r} has arms of {fn.n1} and {fn.n2} joints, "
                f"the system {system.n1} and {system.n2}"
            )
        return fn, None
    if isinstance(fn, SwappedBoundary) and isinstance(fn.distance, PairDistanceModel):
        inner = fn.distance
        # a conditioned distance needs the arms' split given, to keep ``r`` last
        fits_second = fn.n_second == inner.n1 or (fn.n_second is None and not inner.n_cond)
        if not fn.n_first == inner.n2 == system.n1 or inner.n1 != system.n2 or not fits_second:
            raise NehmoError(
                f"swapped boundary of system {name!r} (n_first={fn.n_first}, "
                f"n_second={fn.n_second}) does not fit its "
                f"distance (arms of {inner.n1} and {inner.n2} joints) and the system "
                f"(n1={system.n1}, n2={system.n2})"
            )
        return inner, fn.n_first
    inner_type = type(getattr(fn, "distance", None)).__name__
    detail = f" around a {inner_type}" if isinstance(fn, SwappedBoundary) else ""
    raise NehmoError(
        f"cannot export the boundary of system {name!r}: it is a {type(fn).__name__}{detail}, "
        "not a PairDistanceModel or a SwappedBoundary around one"
    )


def _boundary_value_and_gradient(system: ArmPairSystem, x: ca.MX) -> tuple[ca.MX, ca.MX]:
    """``(l, ∇ₓl)`` of the system's boundary for the (wrapped, folded) state ``x``."""
    distance, n_first = pair_boundary(system)
    if n_first is None:
        return distance_value_and_gradient(distance, x)
    return swapped_distance_value_and_gradient(distance, x, n_first)


def value_and_gradient_expression(
    network: ValueNetwork, tau: ca.MX, x: ca.MX
) -> tuple[ca.MX, ca.MX]:
    """``(V, ∇ₓV)`` in physical units for symbols ``τ`` (scalar) [s] and ``x`` (n,)."""
    system = network.system
    if not isinstance(system, ArmPairSystem):
        raise NehmoError(f"CasADi export supports arm-pair systems; got {system.name!r}")
    xs = _wrap_periodic(x, system.periodic)
    fold_jac: Any = ca.DM.ones(x.shape[0], 1)
    if network.uses_symmetry:
        xs, fold_jac = _fold(system, xs)
    z, z_scale = _network_input(network, tau, xs)
    nn_out, nn_grad = siren_value_and_gradient(network.siren, z)
    nn_grad_x = nn_grad[1:] * z_scale
    if network.variant == "deepreach":
        w, grad_w = nn_out, nn_grad_x
    else:
        boundary, boundary_grad = _boundary_value_and_gradient(system, xs)
        l_hat = (boundary - system.value_mean) * system.value_scale
        if network.variant == "exact":
            w, grad_w = l_hat + tau * nn_out, boundary_grad * system.value_scale + tau * nn_grad_x
        elif network.cap_residual:  # l̂ + min(residual, 0), as the torch network
            below = nn_out < 0
            w = l_hat + ca.fmin(nn_out, 0)
            grad_w = boundary_grad * system.value_scale + ca.if_else(
                below, nn_grad_x, 0 * nn_grad_x
            )
        else:
            w, grad_w = l_hat + nn_out, boundary_grad * system.value_scale + nn_grad_x
    value = w / system.value_scale + system.value_mean
    return value, fold_jac * grad_w / system.value_scale


def value_expression(network: ValueNetwork, tau: ca.MX, x: ca.MX) -> ca.MX:
    """``V(τ, x)`` in physical units for symbols ``τ`` (scalar) [s] and ``x`` (n,)."""
    return value_and_gradient_expression(network, tau, x)[0]


def value_functions(
    value_function: ValueFunction | ValueNetwork, name: str = "pair_value"
) -> tuple[ca.Function, ca.Function]:
    """``(V, VG)``: ``V(tau, x) -> v`` and ``VG(tau, x) -> (v, grad)`` with ``grad = ∇ₓV`` (n,).

    ``VG``'s gradient is reverse mode written out through the networks (CasADi's AD through the
    kinematics), with the symmetry chain rule; the tests check it against torch autograd.
    """
    network = (
        value_function.network if isinstance(value_function, ValueFunction) else value_function
    )
    n = network.system.state_dim
    tau = ca.MX.sym("tau")
    x = ca.MX.sym("x", n)
    v, grad = value_and_gradient_expression(network, tau, x)
    value = ca.Function(name, [tau, x], [v], ["tau", "x"], ["v"])
    value_grad = ca.Function(f"{name}_grad", [tau, x], [v, grad], ["tau", "x"], ["v", "grad"])
    return value, value_grad
