"""Certify a shipped value function: the smallest level set that keeps the arms apart.

    ./run python examples/04_verify_model.py --samples 3000 --alpha 0.01

States are drawn uniformly from the joint box restricted to ``V(τ, x) ≥ δ``; each is rolled out
for ``τ`` with exact PyBullet geometry under the learned safe control against a set of peer
strategies (the learned worst case, a pursuit, box corners). The binomial tail bounds the share
of such states that end in contact, at confidence ``1 − β``. A shipped model's certificates
(``nehmo verify --card``) set the planner's margin ε; this script only prints one.
"""

from __future__ import annotations

import argparse

from nehmo_core.hjr import load_value_function
from nehmo_core.verify import VerifySettings, certify
from nehmo_core.verify.distributions import UniformBox
from nehmo_core.verify.truth import exact_margin


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--model", default="ur5_ur5", help="shipped pair model")
    parser.add_argument("--variant", default="bc+sym", help="bc+sym | bc | deepreach")
    parser.add_argument("--tau", type=float, default=0.3, help="time-to-go of the level set [s]")
    parser.add_argument("--alpha", type=float, default=0.05, help="target violation probability")
    parser.add_argument("--samples", type=int, default=300, help="states in the certificate (N)")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    value = load_value_function(args.model, variant=args.variant)
    settings = VerifySettings(
        tau=args.tau,
        alpha=args.alpha,
        samples=args.samples,
        search_samples=min(args.samples, 500),
        attempts=1,
        seed=args.seed,
    )
    margin = exact_margin(value.system)
    try:
        cert = certify(value, margin, UniformBox(value.system), settings, model=args.model)
    finally:
        margin.close()
    verdict = "certified" if cert.certified else "not certified"
    print(f"model {args.model} ({args.variant}), τ = {cert.tau:g} s, uniform states")
    print(f"level δ = {cert.delta:.3f} m: {cert.violations} of {cert.samples} rollouts in contact")
    print(
        f"violation probability ≤ {cert.epsilon:.4f} at confidence {cert.confidence:.3f}: "
        f"{verdict} at α = {args.alpha}"
    )


if __name__ == "__main__":
    main()
