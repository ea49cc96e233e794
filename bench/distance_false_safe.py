"""Learned distances on the closed-loop distribution: false-safe rates beside their own ones.

For each shipped distance model: the pair states the ``nehmo`` planner visited in evaluation
episodes (development seed 31, as for ``bench/certify_models.py``), the same states with every
joint perturbed by N(0, 0.1²) and N(0, 0.3²) rad, and the card's own held-out rate. Writes
``bench/results/distance_false_safe.{json,md}`` and records the closed-loop rates in each card
(``closed_loop_false_safe``).

    OMP_NUM_THREADS=1 ./run python bench/distance_false_safe.py --episodes-dir runs/episodes
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from nehmo_core.errors import NehmoError
from nehmo_core.geometry.distance_model import load_distance_model
from nehmo_core.hjr import make_system
from nehmo_core.robots.registry import MODELS_DIR
from nehmo_core.verify.distance import NearVisited, certify_distance, false_safe, jittered
from nehmo_core.verify.distributions import UniformBox, episode_logs, visited_pair_states
from nehmo_core.verify.truth import exact_margin

ROOT = Path(__file__).resolve().parents[1]
PAIRS = {
    "ur5_ur5": ("dual_ur5", "five_ur5"),
    "ur5_ur5_diag": ("five_ur5",),
    "ur5_ur5_opposite": ("five_ur5",),
    "ur5_kinova": ("ur5_kinova_challenging",),
    "ur5_ur5_any": ("ha_tasks",),
}
STATES = 20000
SIGMAS = (0.1, 0.3)
CERT_SAMPLES = 3000  # contact states per certificate
# near-visited draws before a pair is reported as too rarely in contact (the 1.2 m pair touches
# about once in 10⁴ draws there; the ball-cover prefilter makes 10⁷ draws a matter of minutes)
CERT_MAX_DRAWS = 64_000_000


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes-dir", type=Path, required=True)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    rows = []
    for pair, setups in PAIRS.items():
        rng = np.random.default_rng(args.seed)
        system = make_system(pair)
        logs = episode_logs([args.episodes_dir / s for s in setups])
        pool = visited_pair_states(system, logs)  # type: ignore[arg-type]
        visited = pool.draw(STATES, rng)
        model, margin = load_distance_model(pair), exact_margin(system)
        joints = system.state_dim - len(getattr(system, "conditions", ()))
        results = [false_safe(model, margin, visited, "visited")]
        for sigma in SIGMAS:
            near = jittered(visited, sigma, rng, joints)
            results.append(false_safe(model, margin, near, f"visited + N(0, {sigma}²) rad"))
        certificates = []
        for dist, cap in (
            (UniformBox(system), 4_000_000),
            (NearVisited(pool, joints), CERT_MAX_DRAWS),
        ):
            try:
                cert = certify_distance(
                    model, margin, dist, rng, samples=CERT_SAMPLES, max_draws=cap, progress=True
                ).to_dict()
            except NehmoError as err:
                cert = {
                    "distribution": dist.describe()["name"],
                    "certified": False,
                    "why": str(err),
                }
            cert["what"] = dist.describe()["what"]
            certificates.append(cert)
            print(pair, cert, flush=True)
        margin.close()
        card_path = MODELS_DIR / f"distance_{pair}.json"
        card = json.loads(card_path.read_text())
        card["closed_loop_false_safe"] = {
            "episodes": f"nehmo planner, seed 31: {', '.join(setups)} ({len(logs)} episodes)",
            "command": "bench/distance_false_safe.py",
            "seed": args.seed,
            "results": [r.to_dict() for r in results],
        }
        card["certificates"] = [
            {**c, "command": "bench/distance_false_safe.py", "seed": args.seed}
            for c in certificates
        ]
        card_path.write_text(json.dumps(card, indent=1) + "\n")
        own = card["accuracy_held_out"]["false_safe_rate"]
        rows.append(
            {
                "pair": pair,
                "own_held_out": own,
                "results": [r.to_dict() for r in results],
                "certificates": certificates,
            }
        )
        print(pair, own, [(r.distribution, r.colliding, r.false_safe) for r in results], flush=True)
    out = ROOT / "bench" / "results" / "distance_false_safe"
    out.with_suffix(".json").write_text(json.dumps(rows, indent=2) + "\n")
    lines = [
        "# Learned distances: false-safe rates on the closed-loop distribution",
        "",
        f"{STATES} states per distribution drawn from the pair states of `nehmo` evaluation "
        f"episodes (seed 31), exact PyBullet distance; rate = false-safe / colliding, bound at "
        f"confidence 0.999. Sampling seed {args.seed}. `bench/distance_false_safe.py`.",
        "",
        "| pair | own held-out | distribution | colliding | false-safe | rate | bound | "
        "mean abs err < 10 cm [mm] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        for r in row["results"]:
            rate = "–" if r["colliding"] == 0 else f"{r['rate']:.2%}"
            lines.append(
                f"| {row['pair']} | {row['own_held_out']:.2%} | {r['distribution']} | "
                f"{r['colliding']} | {r['false_safe']} | {rate} | {r['bound']:.2%} | "
                f"{1000 * r['mean_abs_error_near_m']:.1f} |"
            )
    lines += [
        "",
        "## Certificates",
        "",
        f"{CERT_SAMPLES} i.i.d. contact states (exact distance ≤ 0) per distribution, drawn by "
        "rejection; the certified level c is the smallest with at most the allowed number of "
        "contacts read above it (α = 1 %, β = 1e-3): with confidence 0.999, at most 1 % of the "
        "distribution's contacts have a learned distance above c. Every planner margin ε ≥ c "
        "keeps it (the value function's own certificate, taken against exact geometry, is the "
        "planner's guarantee; `certificates.md`).",
        "",
        "| pair | distribution | drawn | contacts | read > 0 | certified level c [mm] | "
        "read > c | bound |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        for c in row["certificates"]:
            if not c["certified"]:
                lines.append(
                    f"| {row['pair']} | {c['what']} | – | – | – | "
                    f"not certified: {c['why']} | – | – |"
                )
                continue
            lines.append(
                f"| {row['pair']} | {c['what']} | {c['states']} | {c['colliding']} | "
                f"{c['false_safe_at_zero']} | {1000 * c['level_m']:.1f} | {c['false_safe']} | "
                f"{c['bound']:.2%} |"
            )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
