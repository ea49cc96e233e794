"""The pose-conditioned pair models against PyBullet and against the fixed-distance models.

``--pair ur5_ur5_any`` (the default) or ``--pair ur5_kinova_any`` (with its Kinova-side value
function ``kinova_ur5_any``, compared with ``ur5_kinova`` / ``kinova_ur5`` at 0.6 m):

1. Distance ``distance_ur5_ur5_any`` on a fresh labelled set (``nehmo distance generate --pair
   ur5_ur5_any --seed 1001``: random base distances in the training range and random base yaws,
   labelled by PyBullet on the real layout), per base-distance band: false-safe rate (colliding
   states the model calls free), mean and 95th-percentile error within 10 cm of contact.
2. Value ``value_ur5_ur5_any`` (bc+sym) against the fixed-distance value functions at their base
   distances (0.6 / 0.849 / 1.2 m): on uniform joint states, the mean |ΔV| and the share where
   the two disagree on the sign of ``V − ε`` (ε = 0.05 m), at τ = 0.1, 0.3 and 0.6 s.

Writes ``bench/results/any_layout.{json,md}`` (``any_layout_ur5_kinova.{json,md}`` for the
UR5-Kinova pair).

    ./run python bench/any_layout.py --test runs/distance_any/test.npz
    ./run python bench/any_layout.py --pair ur5_kinova_any --test data/ur5_kinova_any_test.npz
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

from nehmo_core.geometry.distance_cli import load_dataset
from nehmo_core.geometry.distance_model import load_distance_model
from nehmo_core.hjr.model_files import load_value_function, shipped_value_path

ROOT = Path(__file__).resolve().parents[1]
BANDS = ((0.25, 0.5), (0.5, 0.8), (0.8, 1.1), (1.1, 1.4), (1.4, 1.7))
#: conditioned value function → the fixed-distance ones it must agree with, at their distance
FIXED = {
    "ur5_ur5_any": {"ur5_ur5": 0.6, "ur5_ur5_diag": 0.6 * 2**0.5, "ur5_ur5_opposite": 1.2},
    "ur5_kinova_any": {"ur5_kinova": 0.6},
    "kinova_ur5_any": {"kinova_ur5": 0.6},
}
#: distance pair → its conditioned value functions
VALUES = {"ur5_ur5_any": ("ur5_ur5_any",), "ur5_kinova_any": ("ur5_kinova_any", "kinova_ur5_any")}
TAUS = (0.1, 0.3, 0.6)
EPSILON = 0.05


def distance_bands(pair: str, test: Path) -> list[dict[str, Any]]:
    q, d, _ = load_dataset(test)
    pred = load_distance_model(pair).distance(q)
    rows = []
    for low, high in (*BANDS, (BANDS[0][0], BANDS[-1][1])):
        band = (q[:, 12] >= low) & (q[:, 12] < high if high < BANDS[-1][1] else q[:, 12] <= high)
        coll, near = band & (d < 0), band & (np.abs(d) < 0.1)
        err = np.abs(pred - np.minimum(d, 1.0))
        rows.append(
            {
                "band_m": [low, high],
                "states": int(band.sum()),
                "colliding": int(coll.sum()),
                "false_safe_rate": float(np.mean(pred[coll] > 0)) if coll.any() else None,
                "near_contact": int(near.sum()),
                "mean_abs_error_near_m": float(err[near].mean()) if near.any() else None,
                "p95_abs_error_near_m": float(np.percentile(err[near], 95)) if near.any() else None,
            }
        )
    return rows


def value_agreement(pair: str, samples: int, seed: int) -> list[dict[str, Any]]:
    rng = np.random.default_rng(seed)
    q = rng.uniform(-np.pi, np.pi, (samples, 12))
    rows = []
    for name in VALUES[pair]:
        conditioned = load_value_function(shipped_value_path(name))
        for fixed_name, r in FIXED[name].items():
            fixed = load_value_function(shipped_value_path(fixed_name))
            x = np.c_[q, np.full(samples, r)]
            for tau in TAUS:
                t = np.full(samples, tau)
                v_any, v_fix = conditioned.value(t, x), fixed.value(t, q)
                rows.append(
                    {
                        "conditioned_model": name,
                        "fixed_model": fixed_name,
                        "r_m": r,
                        "tau_s": tau,
                        "states": samples,
                        "mean_abs_diff_m": float(np.mean(np.abs(v_any - v_fix))),
                        "sign_disagreement": float(np.mean((v_any > EPSILON) != (v_fix > EPSILON))),
                        "conditioned_safe_fixed_not": float(
                            np.mean((v_any > EPSILON) & (v_fix <= EPSILON))
                        ),
                    }
                )
    return rows


def markdown(result: dict[str, object]) -> str:
    lines = [
        f"### Pose-conditioned distance `{result['pair']}` vs PyBullet (fresh poses, seed 1001)",
        "",
        "| base distance m | states | colliding | false-safe % | near contact | mean err near mm "
        "| p95 err near mm |",
        "|---|---|---|---|---|---|---|",
    ]
    for b in result["distance"]:  # type: ignore[attr-defined]
        fs = "–" if b["false_safe_rate"] is None else f"{100 * b['false_safe_rate']:.2f}"
        me = (
            "–"
            if b["mean_abs_error_near_m"] is None
            else f"{1000 * b['mean_abs_error_near_m']:.1f}"
        )
        pe = "–" if b["p95_abs_error_near_m"] is None else f"{1000 * b['p95_abs_error_near_m']:.1f}"
        lines.append(
            f"| {b['band_m'][0]:.2f}–{b['band_m'][1]:.2f} | {b['states']} | {b['colliding']} "
            f"| {fs} | {b['near_contact']} | {me} | {pe} |"
        )
    lines += [
        "",
        f"### Conditioned value vs the fixed-distance value functions ({EPSILON} m level)",
        "",
        "| conditioned model | fixed model | r m | τ s | mean abs ΔV mm | sign disagreement % "
        "| conditioned safe, fixed not % |",
        "|---|---|---|---|---|---|---|",
    ]
    for v in result["value"]:  # type: ignore[attr-defined]
        lines.append(
            f"| {v.get('conditioned_model', 'ur5_ur5_any')} | {v['fixed_model']} "
            f"| {v['r_m']:.3f} | {v['tau_s']} "
            f"| {1000 * v['mean_abs_diff_m']:.1f} "
            f"| {100 * v['sign_disagreement']:.2f} | {100 * v['conditioned_safe_fixed_not']:.2f} |"
        )
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pair", default="ur5_ur5_any", choices=sorted(VALUES))
    parser.add_argument("--test", type=Path, required=True, help="labelled .npz (fresh seed)")
    parser.add_argument("--samples", type=int, default=20000)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--out", type=Path, default=ROOT / "bench" / "results")
    args = parser.parse_args()
    result = {
        "command": " ".join(["bench/any_layout.py", *sys.argv[1:]]),
        "pair": args.pair,
        "distance": distance_bands(args.pair, args.test),
        "value": value_agreement(args.pair, args.samples, args.seed),
        "value_seed": args.seed,
    }
    args.out.mkdir(parents=True, exist_ok=True)
    stem = "any_layout" if args.pair == "ur5_ur5_any" else "any_layout_ur5_kinova"
    (args.out / f"{stem}.json").write_text(json.dumps(result, indent=1) + "\n")
    (args.out / f"{stem}.md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
