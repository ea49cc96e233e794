"""Wall time per stage and the figures of every pair built by ``nehmo pair build``.

Reads the pair cards (``<pair>.card.json``) in the model folders (the shipped ``models/`` and
``NEHMO_MODELS``) and writes ``bench/results/pair_builds.{json,md}``.

    ./run python bench/pair_builds.py
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from nehmo_core.robots.registry import model_dirs

ROOT = Path(__file__).resolve().parents[1]


def _mm(value: float | None) -> str:
    return "–" if value is None else f"{1000 * value:.1f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--note", action="append", default=[], metavar="PAIR=TEXT", help="a remark on a build"
    )
    args = parser.parse_args()
    notes = dict(n.split("=", 1) for n in args.note)
    cards = {
        path.name.removesuffix(".card.json"): json.loads(path.read_text())
        for folder in model_dirs()
        for path in sorted(folder.glob("*.card.json"))
    }
    out = ROOT / "bench" / "results" / "pair_builds"
    out.with_suffix(".json").write_text(json.dumps(cards, indent=2) + "\n")
    lines = [
        "# Pair builds: wall time per stage and what each stage measured",
        "",
        "From the pair cards that `nehmo pair build` writes beside the models; the command, "
        "budget, seeds and hardware of each are in its card. `bench/pair_builds.py`.",
        "",
    ]
    for pair, card in cards.items():
        stages = card["stages"]
        lines += [
            f"## {pair}",
            "",
            f"`{card['command']}` on {card['hardware']}; total "
            f"{card['total_wall_time_s'] / 60:.1f} min.",
            "",
            "| stage | wall time [min] |",
            "|---|---|",
            *(f"| {name} | {s / 60:.1f} |" for name, s in card["wall_time_s"].items()),
            "",
        ]
        check = stages["check"]["figures"]
        mirror = check["mirror_check"]
        lines.append(
            f"- Base distances modelled: {check['base_range_m'][0]}–{check['base_range_m'][1]} m "
            "(reach "
            + ", ".join(f"{r}: {v['reach_m']:.3f} m" for r, v in check["robots"].items())
            + f"). Variant: {check['variant']} ({mirror.get('why', '')})."
        )
        held = stages["calibrate"]["figures"]["held_out"]
        lines.append(
            f"- Learned distance, held out ({held.get('n')} states): mean error "
            f"{_mm(held.get('mae_m'))} mm, within 10 cm of contact {_mm(held.get('mae_near_m'))} "
            f"mm ({held.get('n_near')} states), false-safe rate "
            f"{100 * held.get('false_safe_rate', float('nan')):.2f} %, offset "
            f"{_mm(stages['calibrate']['figures'].get('output_offset_m'))} mm."
        )
        cert = stages["distance-certificate"]["figures"]
        lines.append(
            f"- Distance certificate ({cert.get('distribution', 'uniform')} contact states, "
            f"N = {cert['colliding']}, "
            f"α = {cert['alpha']}, β = {cert['beta']}): certified level "
            f"{_mm(cert['level_m']) if cert['certified'] else 'none'} mm; "
            f"{cert['false_safe_at_zero']} contacts read above 0."
        )
        for name, stage in stages.items():
            f = stage["figures"]
            if name.startswith("value:") and "below_boundary" in f:
                b = f["below_boundary"]
                lines.append(
                    f"- `{name[6:]}` value function ({f['samples'] / 1e6:.0f}M samples): the "
                    f"network's V(T) exceeds l by more than 1 cm at "
                    f"{100 * b['share_above_boundary_1cm']:.1f} % of {b['states']} uniform "
                    f"states (p99 excess {_mm(b['p99_excess_m'])} mm); the planner evaluates "
                    "it capped at l."
                )
                if "pde" in b:
                    d = b["pde"]
                    lines.append(
                        f"- `{name[6:]}` against its PDE: residual {d['residual_ratio']:.2f} of "
                        f"V = l's, slope ratio {d['slope_ratio']:.2f}, H < 0 on "
                        f"{100 * d['model_fall_share']:.0f} % of states (V = l: "
                        f"{100 * d['must_fall_share']:.0f} %), mean l − V(T) "
                        f"{_mm(d['mean_fall_at_horizon'])} mm: "
                        + ("a learned value." if b["learned"] else "**learned little**.")
                    )
                tries = f.get("attempts", [])
                if len(tries) > 1:
                    lines.append(
                        f"- `{name[6:]}` trained {len(tries)} times: "
                        + ", ".join(
                            f"--pde-loss {a['pde_loss']} residual {a['residual_ratio']:.2f}"
                            for a in tries
                        )
                        + f"; kept {f.get('pde_loss')}."
                    )
            if name.startswith(("certify:", "certify-visited:")):
                lines.append(
                    f"- `{name.split(':')[1]}` value certificate at τ = {f['tau']} s "
                    f"({f.get('distribution', 'uniform')}, N = "
                    f"{f['samples']}): δ = {_mm(f['delta'])} mm, {f['violations']} violations, "
                    f"ε ≤ {100 * f['epsilon']:.2f} %, certified: {f['certified']}."
                )
            if name == "visit":
                lines.append(
                    "- Visit cells (the planner with these models; SR % / collisions): "
                    + "; ".join(
                        f"{c['base_distance_m']} m, yaw {c['yaw_rad']:.2f}: {c['sr']:.0f} / "
                        f"{c['collisions']} of {c['episodes']}"
                        for c in f["cells"]
                    )
                    + "."
                )
            if name.startswith("falsify:"):
                lines.append(
                    f"- `{name[8:]}` falsification at ε = {_mm(f['epsilon'])} mm (at most the "
                    f"planner's margin, so no easier): {f['contacts']} contacts in {f['states']} "
                    f"rollouts (bound {100 * f['bound']:.2f} % at confidence 0.999)."
                )
        if pair in notes:
            lines.append(f"- Note: {notes[pair]}")
        lines.append("")
    out.with_suffix(".md").write_text("\n".join(lines))
    print(f"wrote {out}.json and .md ({len(cards)} pairs)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
