"""The measurements of ``nehmo pair build`` that are not a ``nehmo`` command of their own.

Each runs in a fresh process (``python -m nehmo_core.pairs.probes KIND ...``), where the pair
being built is registered through its model folder, and prints its result as one JSON line
after :data:`RESULT` (PyBullet writes to stdout as well).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["RESULT", "distance_certificate", "falsify", "mirror_check", "value_check"]

RESULT = "NEHMO-RESULT "
NEAR = 0.3
"""[m] States this close to contact enter the mirror check's mean."""
MIN_COMPARED = 200
"""Fewer states than this within :data:`NEAR` (bases far apart): the mirror check compares up to
this many states closest to contact instead (below the labels' cutoff, where distances are
measured), so it never passes on no evidence."""


def mirror_check(pair: str, samples: int, seed: int) -> dict[str, Any]:
    """The exact pair distance of random states and of their mirror images: the mirror y → −y
    turns both base yaws to their negatives and maps the joints by the robots' mirror maps."""
    from nehmo_core.geometry import distance_data as dd
    from nehmo_core.hjr.systems.arm_pairs import pair_symmetry

    rng = np.random.default_rng(seed)
    q = dd.uniform_samples(pair, samples, rng)
    f = pair_symmetry(pair)
    mirrored = q.copy()
    mirrored[:, : len(f.sign)] = f.apply(q[:, : len(f.sign)])
    yaw = rng.uniform(-np.pi, np.pi, size=(samples, 2))
    d = dd.exact_distances(pair, np.c_[q, yaw])
    d_mirrored = dd.exact_distances(pair, np.c_[mirrored, -yaw])
    near = np.abs(d) < NEAR
    if near.sum() < MIN_COMPARED:  # far bases: the states closest to contact instead
        closest = np.argsort(np.abs(d))[: min(samples, MIN_COMPARED)]
        near = np.zeros(samples, dtype=bool)
        near[closest[np.maximum(d[closest], d_mirrored[closest]) < dd.CUTOFF]] = True
    diff = np.abs(d - d_mirrored)[near]
    return {
        "states": samples,
        "near_contact_states": int((np.abs(d) < NEAR).sum()),
        "compared_states": int(near.sum()),
        "compared_within_m": float(np.abs(d)[near].max()) if near.any() else 0.0,
        "mean_abs_diff_near_m": float(diff.mean()) if diff.size else 0.0,
        "max_abs_diff_near_m": float(diff.max()) if diff.size else 0.0,
        "seed": seed,
    }


def distance_certificate(
    pair: str, samples: int, seed: int, alpha: float, pool: str = ""
) -> dict[str, Any]:
    """:func:`~nehmo_core.verify.distance.certify_distance` over uniform exact contact states.

    Where contact is too rare among uniform states to draw ``samples`` of them (a pair's far base
    distances: a few in a million), and a ``pool`` of labelled states (``q``, ``d``: a held-out
    label set) is given, the certificate is made on contact states near that pool's contacts
    instead (each a pool state with ``|d| < 5 cm``, joints moved by ``N(0, σ²)``,
    ``σ ~ U[0.02, 0.1]`` rad) and says so (``distribution``: ``near_visited``).
    """
    from nehmo_core.errors import NehmoError
    from nehmo_core.geometry.distance_model import load_distance_model
    from nehmo_core.hjr.systems import make_system
    from nehmo_core.verify.distance import NearVisited, certify_distance
    from nehmo_core.verify.distributions import UniformBox, VisitedStates
    from nehmo_core.verify.truth import exact_margin

    system = make_system(pair)
    margin = exact_margin(system)
    model = load_distance_model(pair)
    rng = np.random.default_rng(seed)
    fallback = ""
    try:
        try:
            cert = certify_distance(model, margin, UniformBox(system), rng, samples, alpha)
        except NehmoError as err:
            if not pool or "in contact" not in str(err):
                raise
            fallback = f"uniform states: {err}"
            data = np.load(pool)
            near = data["q"][np.abs(data["d"]) < 0.05]
            joints = system.state_dim - len(getattr(system, "conditions", ()))
            distribution = NearVisited(VisitedStates(near, (pool,)), joints, 0.02, 0.1)
            cert = certify_distance(model, margin, distribution, rng, samples, alpha)
    finally:
        margin.close()
    out = {**cert.to_dict(), "seed": seed}
    if fallback:
        out["fallback"] = fallback
    return out


def falsify(
    game: str, variant: str, samples: int, seed: int, cluster: str = "local"
) -> dict[str, Any]:
    """States the planner would call safe, ``V(t_safe) ≥ ε`` with ε = max(the planner's floor,
    the model's δ certified at t_safe), rolled out against every adversary on exact geometry
    (on a Ray cluster's workers with ``cluster``, with the same result)."""
    from nehmo_core.cluster import make_executor, parse_cluster
    from nehmo_core.hjr import load_value_function
    from nehmo_core.planning.settings import PlannerSettings
    from nehmo_core.verify.bound import violation_bound
    from nehmo_core.verify.certify import RemoteRollouts, VerifySettings, worst_margins
    from nehmo_core.verify.distributions import UniformBox, draw_level_set
    from nehmo_core.verify.truth import exact_margin

    opt = PlannerSettings().opt
    tau = opt.t_safe
    value = load_value_function(game, variant=variant)
    certs = value.card.get("certificates", ())
    eps = max([opt.epsilon, *(c["delta"] for c in certs if abs(c["tau"] - tau) < 1e-6)])
    rng = np.random.default_rng(seed)
    margin = exact_margin(value.system)
    spec = parse_cluster(cluster)
    executor = make_executor(1, spec) if spec.is_ray else None
    remote = None if executor is None else RemoteRollouts(executor, game, variant)
    try:
        x, _, share = draw_level_set(value, UniformBox(value.system), tau, eps, samples, rng)
        m, _ = worst_margins(value, margin, x, VerifySettings(tau=tau), rng, "falsify", remote)
    finally:
        margin.close()
        if executor is not None:
            executor.shutdown()
    k = int((m <= 0).sum())
    return {
        "tau": tau,
        "epsilon": eps,
        "states": len(x),
        "contacts": k,
        "rate": k / len(x),
        "bound": violation_bound(len(x), k, 1e-3),
        "seed": seed,
        "accepted_share": share,
    }


def value_check(game: str, variant: str, samples: int, seed: int) -> dict[str, Any]:
    """An avoid value function never exceeds its boundary, ``V(τ, x) ≤ l(x)``: the share of
    uniform states where the network's ``V(T)`` does by more than 1 cm (a fit error; the
    hand-trained models keep it under 3 %; a built pair's models are evaluated with the excess
    capped, see ``ValueNetwork.cap_residual``), and the 99th percentile of the excess [m]. Also
    the network against its PDE (:func:`~nehmo_core.hjr.diagnostics.pde_diagnostics`) and whether
    that reads as a learned value (``learned``)."""
    import torch

    from nehmo_core.hjr import load_value_function
    from nehmo_core.hjr.diagnostics import learned_value, pde_diagnostics

    value = load_value_function(game, variant=variant)
    value.network.cap_residual = False  # the network's own fit, before any cap
    system = value.system
    x = np.random.default_rng(seed).uniform(system.lower, system.upper, (samples, system.state_dim))
    with torch.no_grad():
        lx = system.boundary(torch.as_tensor(x, dtype=torch.float32)).numpy()
    excess = value.value(np.full(samples, system.horizon), x) - lx
    pde = pde_diagnostics(value, samples, seed)
    return {
        "states": samples,
        "share_above_boundary_1cm": float((excess > 0.01).mean()),
        "p99_excess_m": float(np.percentile(excess, 99)),
        "seed": seed,
        "pde": pde.to_dict(),
        "learned": learned_value(pde),
    }


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nehmo_core.pairs.probes")
    sub = parser.add_subparsers(dest="kind", required=True)
    m = sub.add_parser("mirror", help="the pair distance under the mirror maps")
    d = sub.add_parser("distance-certificate", help="certify the learned distance")
    f = sub.add_parser("falsify", help="the game at the planner's margin")
    v = sub.add_parser("value-check", help="V(T) <= l(x) on uniform states")
    for p in (m, d, f, v):
        p.add_argument("pair")
        p.add_argument("--samples", type=int, required=True)
        p.add_argument("--seed", type=int, required=True)
    d.add_argument("--alpha", type=float, required=True)
    d.add_argument("--pool", default="", help="labelled states (npz: q, d) for rare contact")
    f.add_argument("--variant", required=True)
    f.add_argument("--cluster", default="local", help="where the rollouts run (docs/cluster.md)")
    v.add_argument("--variant", required=True)
    args = parser.parse_args(argv)
    if args.kind == "mirror":
        result = mirror_check(args.pair, args.samples, args.seed)
    elif args.kind == "distance-certificate":
        result = distance_certificate(args.pair, args.samples, args.seed, args.alpha, args.pool)
    elif args.kind == "value-check":
        result = value_check(args.pair, args.variant, args.samples, args.seed)
    else:
        result = falsify(args.pair, args.variant, args.samples, args.seed, args.cluster)
    print("\n" + RESULT + json.dumps(result), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
