"""The ``nehmo verify`` command: certify a value function's level set; JSON, Markdown, model card.

Example (the shipped UR5-UR5 model at the planner's ``t_safe``, over the states the planner
visited in evaluation episodes)::

    nehmo evaluate --setup dual_ur5 --planners nehmo --episodes 20 --seed 31 --out runs/episodes
    nehmo verify --model ur5_ur5 --tau 0.3 --distribution visited --logs runs/episodes \\
        --out runs/verify
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from dataclasses import replace
from pathlib import Path

from nehmo_core.cluster import make_executor, parse_cluster
from nehmo_core.errors import InvalidValueError, as_options
from nehmo_core.hjr import load_value_function
from nehmo_core.hjr.systems import ArmPairSystem, HJISystem
from nehmo_core.sim.actuators import ACTUATOR_MODELS, ActuatorModel, actuator_model
from nehmo_core.verify.adversaries import ADVERSARIES, DEFAULT_ADVERSARIES
from nehmo_core.verify.cards import record_certificate, shipped_card_path
from nehmo_core.verify.certify import RemoteRollouts, VerifySettings, certify
from nehmo_core.verify.distributions import (
    StateDistribution,
    UniformBox,
    episode_logs,
    visited_pair_states,
)
from nehmo_core.verify.report import certificate_markdown, certificate_stem
from nehmo_core.verify.truth import exact_margin, pair_arms

__all__ = ["add_arguments", "run"]

_OPTIONS = {
    "tau": "--tau",
    "alpha": "--alpha",
    "beta": "--beta",
    "samples": "--samples",
    "search_samples": "--search-samples",
    "delta_max": "--delta-max",
    "dt": "--dt",
    "adversaries": "--adversaries",
    "attempts": "--attempts",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--model", required=True, help="shipped pair name, run directory or .safetensors"
    )
    parser.add_argument("--variant", help="variant of a shipped model (default bc+sym)")
    parser.add_argument("--tau", type=float, required=True, help="time-to-go of the level set [s]")
    parser.add_argument("--distribution", choices=("uniform", "visited"), default="uniform")
    parser.add_argument(
        "--logs",
        type=Path,
        action="append",
        default=[],
        help="episode log directory (visited); repeatable",
    )
    parser.add_argument("--alpha", type=float, default=0.01, help="target violation probability")
    parser.add_argument("--beta", type=float, default=1e-3, help="1 - confidence")
    parser.add_argument("--samples", type=int, default=3000, help="states in the certificate (N)")
    parser.add_argument("--search-samples", type=int, default=500, help="states for the δ search")
    parser.add_argument("--delta-max", type=float, default=0.3, help="largest level searched [m]")
    parser.add_argument(
        "--attempts", type=int, default=3, help="certification attempts (β is split)"
    )
    parser.add_argument("--dt", type=float, default=0.01, help="rollout step [s]")
    parser.add_argument(
        "--actuators",
        choices=ACTUATOR_MODELS,
        default="ideal",
        help="how the controlled arm follows its control in the rollouts (the arm's actuator "
        "model from its description; each rollout starts reversing at full speed); recorded in "
        "the certificate",
    )
    parser.add_argument(
        "--adversaries",
        default=",".join(DEFAULT_ADVERSARIES),
        help=f"comma-separated subset of {list(ADVERSARIES)}",
    )
    parser.add_argument("--seed", type=int, default=0, help="makes the run reproducible")
    parser.add_argument("--out", type=Path, required=True, help="directory for the JSON + Markdown")
    parser.add_argument(
        "--card", action="store_true", help="record the certificate in the shipped model card"
    )
    parser.add_argument(
        "--cluster",
        default="local",
        help="where the rollouts run: 'local' (this process), 'ray', 'ray://HOST:PORT' or "
        "'ray:HOST:PORT' (docs/cluster.md); the certificate is the same",
    )


def _distribution(args: argparse.Namespace, system: HJISystem) -> StateDistribution:
    if args.distribution == "uniform":
        return UniformBox(system)
    if not args.logs:
        raise InvalidValueError("--logs", "is required with --distribution visited", None)
    if not isinstance(system, ArmPairSystem):
        raise InvalidValueError(
            "--distribution", "visited needs an arm-pair model", args.distribution
        )
    return visited_pair_states(system, episode_logs(args.logs))


def _actuator(name: str, system: HJISystem) -> ActuatorModel | None:
    """The controlled arm's actuator model (None: ideal)."""
    if name == "ideal":
        return None
    if not isinstance(system, ArmPairSystem):
        raise InvalidValueError("--actuators", "needs an arm pair model", name)
    cell, arm, _ = pair_arms(system.name)
    return actuator_model(name, cell.arm(arm).robot)


def run(args: argparse.Namespace) -> int:
    with as_options(_OPTIONS):
        settings = VerifySettings(
            tau=args.tau,
            alpha=args.alpha,
            beta=args.beta,
            samples=args.samples,
            search_samples=args.search_samples,
            delta_max=args.delta_max,
            attempts=args.attempts,
            dt=args.dt,
            adversaries=tuple(a.strip() for a in args.adversaries.split(",") if a.strip()),
            seed=args.seed,
        )
    card = shipped_card_path(args.model, args.variant) if args.card else None
    value = load_value_function(args.model, variant=args.variant)
    if settings.tau > value.system.horizon:
        raise InvalidValueError("--tau", f"must lie in (0, {value.system.horizon}]", settings.tau)
    distribution = _distribution(args, value.system)
    settings = replace(settings, actuator=_actuator(args.actuators, value.system))
    margin = exact_margin(value.system)
    variant = args.variant or value.variant
    cluster = parse_cluster(args.cluster)
    executor = make_executor(1, cluster) if cluster.is_ray else None
    remote = None if executor is None else RemoteRollouts(executor, args.model, args.variant)
    try:
        cert = certify(
            value, margin, distribution, settings, model=f"{args.model} ({variant})", remote=remote
        )
    finally:
        margin.close()
        if executor is not None:
            executor.shutdown()
    cert.command = "nehmo verify " + shlex.join(
        sys.argv[2:] if sys.argv[1:2] == ["verify"] else sys.argv[1:]
    )
    args.out.mkdir(parents=True, exist_ok=True)
    stem = certificate_stem(
        cert.system, variant, cert.distribution["name"], cert.tau, args.actuators
    )
    (args.out / f"{stem}.json").write_text(json.dumps(cert.to_dict(), indent=2) + "\n")
    (args.out / f"{stem}.md").write_text(certificate_markdown(cert))
    verdict = "certified" if cert.certified else "NOT certified"
    print(
        f"{cert.system} ({variant}) τ={cert.tau:g} s, {cert.distribution['name']}, "
        f"{args.actuators} actuators: "
        f"δ = {cert.delta:.3f} m, {cert.violations}/{cert.samples} violations, "
        f"ε ≤ {cert.epsilon:.4f} at {cert.confidence:.3f} ({verdict} at α = {settings.alpha}); "
        f"{cert.wall_time_s:.0f} s"
    )
    if card is not None:
        record_certificate(card, cert)
        print(f"recorded in {card}")
    print(f"wrote {args.out / stem}.json and .md")
    return 0
