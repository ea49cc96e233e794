"""A trained arm-pair value function as CasADi functions ``V(τ, x)`` and ``∇ₓV(τ, x)``.

The graph reproduces :class:`~nehmo_core.hjr.networks.ValueFunction` for an
:class:`~nehmo_core.hjr.systems.ArmPairSystem` whose boundary is a
:class:`~nehmo_core.geometry.distance_model.PairDistanceModel`:

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

import casadi as ca
import numpy as np
import torch

from nehmo_core.errors import NehmoError
from nehmo_core.geometry.distance_casadi import distance_expression
from nehmo_core.geometry.distance_model import PairDistanceModel
from nehmo_core.hjr.networks import Siren, ValueFunction, ValueNetwork
from nehmo_core.hjr.systems import ArmPairSystem

__all__ = ["siren_expression", "value_expression", "value_functions", "wrap_expression"]


def _numpy(t: torch.Tensor) -> np.ndarray:
    return t.detach().cpu().double().numpy()


def wrap_expression(angle: ca.MX) -> ca.MX:
    """Wrap to ``(−π, π]`` like ``wrap_to_pi`` (floor-based; derivative 1 almost everywhere)."""
    period = 2.0 * math.pi
    a = math.pi - angle
    return math.pi - (a - period * ca.floor(a / period))


def _wrap_periodic(x: ca.MX, periodic: tuple[bool, ...]) -> ca.MX:
    rows = [wrap_expression(x[i]) if p else x[i] for i, p in enumerate(periodic)]
    return ca.vertcat(*rows)


def _fold(system: ArmPairSystem, x: ca.MX) -> ca.MX:
    """``x`` if ``x ∈ X_train`` else ``f⁻¹(x)`` (``x`` already wrapped)."""
    region = system.train_region
    q = x[region.joint]
    if system.periodic[region.joint]:
        q = wrap_expression(q)
    keep = ca.logic_and(q >= region.low, q <= region.high)
    sign = ca.DM(np.asarray(system.symmetry_sign, dtype=np.float64))
    offset = ca.DM(np.asarray(system.symmetry_offset, dtype=np.float64))
    inverse = _wrap_periodic(sign * (x - offset), system.periodic)
    return ca.if_else(keep, x, inverse)


def siren_expression(siren: Siren, z: ca.MX) -> ca.MX:
    """The SIREN on its input ``z`` (n + 1,); returns the scalar output."""
    h = z
    for layer in siren.hidden:
        pre = ca.mtimes(ca.DM(_numpy(layer.weight)), h) + ca.DM(_numpy(layer.bias))
        h = ca.sin(siren.omega0 * pre)
    out = siren.output
    return ca.mtimes(ca.DM(_numpy(out.weight)), h) + ca.DM(_numpy(out.bias))


def _network_input(network: ValueNetwork, tau: ca.MX, x: ca.MX) -> ca.MX:
    if network.settings.input_scaling == "raw":
        return ca.vertcat(tau, x)
    tau_hat = 2.0 * tau / network.system.horizon - 1.0
    center = ca.DM(_numpy(network._center))
    half = ca.DM(_numpy(network._half_width))
    return ca.vertcat(tau_hat, (x - center) / half)


def _boundary_model(system: ArmPairSystem) -> PairDistanceModel:
    fn = system.boundary_fn
    if not isinstance(fn, PairDistanceModel):
        raise NehmoError(
            f"cannot export the boundary of system {system.name!r}: it is a "
            f"{type(fn).__name__}, not a PairDistanceModel"
        )
    return fn


def value_expression(network: ValueNetwork, tau: ca.MX, x: ca.MX) -> ca.MX:
    """``V(τ, x)`` in physical units for symbols ``τ`` (scalar) [s] and ``x`` (n,)."""
    system = network.system
    if not isinstance(system, ArmPairSystem):
        raise NehmoError(f"CasADi export supports arm-pair systems; got {system.name!r}")
    xs = _wrap_periodic(x, system.periodic)
    if network.uses_symmetry:
        xs = _fold(system, xs)
    nn_out = siren_expression(network.siren, _network_input(network, tau, xs))
    if network.variant == "deepreach":
        w = nn_out
    else:
        boundary = distance_expression(_boundary_model(system), xs)
        l_hat = (boundary - system.value_mean) * system.value_scale
        w = l_hat + (tau * nn_out if network.variant == "exact" else nn_out)
    return w / system.value_scale + system.value_mean


def value_functions(
    value_function: ValueFunction | ValueNetwork, name: str = "pair_value"
) -> tuple[ca.Function, ca.Function]:
    """``(V, VG)``: ``V(tau, x) -> v`` and ``VG(tau, x) -> (v, grad)`` with ``grad = ∇ₓV`` (n,).

    ``VG`` is reverse-mode differentiation of the same graph (the symmetry chain rule included).
    """
    network = (
        value_function.network if isinstance(value_function, ValueFunction) else value_function
    )
    n = network.system.state_dim
    tau = ca.MX.sym("tau")
    x = ca.MX.sym("x", n)
    v = value_expression(network, tau, x)
    grad = ca.gradient(v, x)
    value = ca.Function(name, [tau, x], [v], ["tau", "x"], ["v"])
    value_grad = ca.Function(f"{name}_grad", [tau, x], [v, grad], ["tau", "x"], ["v", "grad"])
    return value, value_grad
