"""The HJI game against the shipped value functions at the planner's margin: do the arms touch?

For each shipped ``bc+sym`` model: states drawn i.i.d. (uniform over the joint box, and the pair
states of the ``nehmo`` episodes of development seed 31, as in ``bench/certify_models.py``) with
``V(t_safe, x) ≥ ε``, where ε = max(0.05, the model's own δ certified at t_safe) is the smallest
margin any planner keeps with that model; each is rolled out for ``t_safe`` with exact PyBullet
geometry, the learned safe control against every adversary of ``nehmo verify``. The contact rate
and its upper bound at confidence 0.999 are compared with α = 1 %. For ``ur5_ur5`` the value
bands of the original falsification (``V(0.6 s) ∈ [0, 0.1], [0.05, 0.15], [0.1, 0.2]``, uniform
states, rollouts of 0.6 s) are rerun as well. Writes ``bench/results/falsification.{json,md}``.

    OMP_NUM_THREADS=1 ./run python bench/falsification.py --episodes-dir runs/episodes
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from nehmo_core.hjr import load_value_function
from nehmo_core.hjr.systems import ArmPairSystem
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.verify.bound import violation_bound
from nehmo_core.verify.certify import VerifySettings, worst_margins
from nehmo_core.verify.distributions import (
    StateDistribution,
    UniformBox,
    draw_level_set,
    episode_logs,
    visited_pair_states,
)
from nehmo_core.verify.truth import exact_margin

ROOT = Path(__file__).resolve().parents[1]
MODELS = {  # pair -> episode setups whose logs hold its pair states
    "ur5_ur5": ("dual_ur5", "five_ur5"),
    "ur5_ur5_diag": ("five_ur5",),
    "ur5_ur5_opposite": ("five_ur5",),
    "ur5_kinova": ("ur5_kinova_challenging",),
    "kinova_ur5": ("ur5_kinova_challenging",),
    "ur5_ur5_any": ("ha_tasks",),
    "ur5_kinova_any": ("ur5_kinova_any",),
    "kinova_ur5_any": ("ur5_kinova_any",),
}
BANDS = ((0.0, 0.1), (0.05, 0.15), (0.1, 0.2))
ALPHA, BETA = 0.01, 1e-3


def _band_states(
    value: object,
    dist: StateDistribution,
    tau: float,
    band: tuple[float, float],
    count: int,
    rng: np.random.Generator,
) -> np.ndarray:
    """``count`` i.i.d. states of ``dist`` with ``V(τ) ∈ [lo, hi)``, by rejection."""
    kept: list[np.ndarray] = []
    have = 0
    while have < count:
        x, v, _ = draw_level_set(value, dist, tau, band[0], count, rng)
        x = x[v < band[1]]
        kept.append(x)
        have += x.shape[0]
    return np.concatenate(kept)[:count]


def _row(
    value: object, margin: object, x: np.ndarray, tau: float, rng: np.random.Generator
) -> dict:
    settings = VerifySettings(tau=tau)
    m, who = worst_margins(value, margin, x, settings, rng, f"τ={tau:g}")  # type: ignore[arg-type]
    bad = m <= 0.0
    k = int(bad.sum())
    return {
        "states": int(x.shape[0]),
        "contacts": k,
        "rate": k / x.shape[0],
        "bound": violation_bound(x.shape[0], k, BETA),
        "by": sorted({n for n, b in zip(who, bad, strict=True) if b}),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes-dir", type=Path, required=True)
    parser.add_argument("--samples", type=int, default=3000)
    parser.add_argument("--band-samples", type=int, default=1000)
    parser.add_argument("--only", help="comma-separated pair names")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    t_safe = PlannerSettings().opt.t_safe
    floor = PlannerSettings().opt.epsilon
    only = set(args.only.split(",")) if args.only else None
    out = ROOT / "bench" / "results" / "falsification"
    previous = (
        json.loads(out.with_suffix(".json").read_text())
        if out.with_suffix(".json").exists()
        else {}
    )
    rows = [r for r in previous.get("rows", []) if only and r["pair"] not in only]
    bands = previous.get("bands", []) if only and "ur5_ur5" not in only else []
    for pair, setups in MODELS.items():
        if only and pair not in only:
            continue
        value = load_value_function(pair, variant="bc+sym")
        certs = value.card.get("certificates", ())
        level = max([floor, *(c["delta"] for c in certs if abs(c["tau"] - t_safe) < 1e-6)])
        margin = exact_margin(value.system)
        system = value.system
        assert isinstance(system, ArmPairSystem)
        visited = visited_pair_states(system, episode_logs([args.episodes_dir / s for s in setups]))
        try:
            for dist in (UniformBox(value.system), visited):
                rng = np.random.default_rng(args.seed)
                start = time.perf_counter()
                x, _, share = draw_level_set(value, dist, t_safe, level, args.samples, rng)
                row = _row(value, margin, x, t_safe, rng)
                row.update(
                    pair=pair,
                    distribution=dist.describe()["name"],
                    epsilon=level,
                    tau=t_safe,
                    accepted_share=share,
                    wall_s=time.perf_counter() - start,
                )
                rows.append(row)
                print(row, flush=True)
            if pair == "ur5_ur5":
                for band in BANDS:
                    rng = np.random.default_rng(args.seed)
                    horizon = value.system.horizon
                    x = _band_states(
                        value, UniformBox(value.system), horizon, band, args.band_samples, rng
                    )
                    row = _row(value, margin, x, horizon, rng)
                    row.update(band=list(band), tau=horizon)
                    bands.append(row)
                    print(row, flush=True)
        finally:
            margin.close()
    out.with_suffix(".json").write_text(json.dumps({"rows": rows, "bands": bands}, indent=2) + "\n")
    lines = [
        "# The HJI game at the planner's margin",
        "",
        f"Shipped `bc+sym` models; states with `V(t_safe = {t_safe:g} s) ≥ ε`, "
        f"ε = max({floor:g}, the model's own δ certified at t_safe) (the smallest margin a "
        "planner keeps with it), rolled "
        "out for t_safe with exact PyBullet geometry: the learned safe control against the "
        "adversaries of `nehmo verify` (learned worst case, pursuit, two box corners, switching "
        f"corners). Bound: Clopper-Pearson at confidence {1 - BETA:g}; target α = {ALPHA:.0%}. "
        "Visited: `nehmo` episodes of seed 31 (of seed 0, Table IV, for the conditioned "
        f"UR5-Kinova models). Sampling seed {args.seed}. "
        "`bench/falsification.py`.",
        "",
        "| model | distribution | ε [m] | states | contacts | rate | bound | ≤ α | adversaries |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['pair']} | {r['distribution']} | {r['epsilon']:.3f} | {r['states']} | "
            f"{r['contacts']} | {r['rate']:.2%} | {r['bound']:.2%} | "
            f"{'yes' if r['bound'] <= ALPHA else 'no'} | {', '.join(r['by']) or '–'} |"
        )
    if bands:
        lines += [
            "",
            "## `ur5_ur5`: value bands at the full horizon (descriptive)",
            "",
            "Uniform states with `V(0.6 s)` in the band, rolled out for 0.6 s as above.",
            "",
            "| V(0.6 s) band [m] | states | contacts | rate |",
            "|---|---|---|---|",
        ]
        for r in bands:
            lines.append(
                f"| [{r['band'][0]:g}, {r['band'][1]:g}) | {r['states']} | {r['contacts']} | "
                f"{r['rate']:.2%} |"
            )
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
