"""Tables II–IV over several scenario seeds, side by side, with the paper's numbers and the bars.

    for s in 39 40; do OMP_NUM_THREADS=1 ./run python bench/evaluate_tables.py --seed $s \
        --out bench/results/fresh/seed$s --skip-rows ROWS; done
    ./run python bench/seed_tables.py --seeds 39,40           # bench/results/fresh/tables.md

(``ROWS``: the rows left out, e.g. the slow centralized baselines.) Reads
``table_<id>_<setup>.json`` of each seed's directory and writes one markdown table: per
row, SR / CR / self / stuck [%] for each seed, the pooled numbers over all seeds, the paper's SR
/ CR and, for the rows that have one, the target this implementation holds itself to.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

from nehmo_core.eval.paper import TABLES

FRESH = Path(__file__).resolve().parent / "results" / "fresh"

#: (setup, row) → (min SR %, max CR between arms %): what the implementation aims for.
TARGETS: dict[tuple[str, str], tuple[float, float]] = {
    ("dual_ur5", "nehmo"): (95, 0),
    ("triple_ur5", "nehmo"): (90, 0),
    ("five_ur5", "nehmo"): (80, 0),
    ("ur5_kinova_challenging", "nehmo/nehmo"): (84, 0),
    ("ur5_kinova_challenging", "nehmo/reckless"): (0, 34),
}


#: What each reported seed has seen: a seed whose failures were read to change the planner is no
#: longer untouched, and says so.
SEED_NOTES: dict[int, str] = {
    34: "Seed 34's and 35's two five-UR5 collisions were read to find the fail-safe's "
    "lexicographic tolerance (`../options/failsafe_maximin.md`), so their three- and five-UR5 "
    "rows were rerun after that change and are no longer untouched",
    36: "Seeds 36 and 37 were first run after that change",
    39: "Seeds 39 and 40 were first run after the threat test learned to tell announcing peers "
    "from silent ones (`../options/certified_margins.md`), with every row at that code; seeds "
    "34–37 (`seed34/` … `seed37/`) are of the code before it. Seed 38 is left out: its one "
    "three-UR5 collision with a 2 cm settled floor was read to keep the floor at 5 cm",
    45: "Seed 45's stuck three-UR5 episodes were read (logs only, no change made) before the "
    "hold release; that change was found and tuned on development seeds 30 and 31 "
    "(`../options/README.md`). Seeds 43, 44 and 45 were rerun at its code",
    46: "Seeds 46 and 47 were first run at the hold release's code. The Kinova-reckless rows "
    "of seeds 43–47 were rerun after the silent-path watch (`../options/silent_paths.md`, tuned "
    "on development seeds 30–32); their other rows are of the code before it, which acts "
    "differently only against peers that announce nothing",
    48: "Seed 48 was first run at the silent-path watch's code, every row",
}


def _cell(o: dict[str, Any]) -> str:
    errors = o.get("errors") or 0  # episodes that could not be evaluated: failures, counted
    return (
        f"{o['sr']:.0f} / {o['cr_inter_arm']:.0f} / {o['self_collision_rate']:.0f} / "
        f"{o['stuck_rate']:.0f}" + (f" ({errors} errors)" if errors else "")
    )


def _pooled(rows: list[dict[str, Any]]) -> dict[str, Any]:
    n = sum(r["episodes"] for r in rows)
    share = {
        "sr": sum(r["successes"] for r in rows),
        "cr_inter_arm": sum(r["cr_inter_arm"] * r["episodes"] / 100 for r in rows),
        "self_collision_rate": sum(r["self_collisions"] for r in rows),
        "stuck_rate": sum(r["stuck"] for r in rows),
    }
    errors = sum(r.get("errors") or 0 for r in rows)
    return {"episodes": n, "errors": errors, **{k: 100.0 * v / n for k, v in share.items()}}


def _met(target: tuple[float, float] | None, runs: list[dict[str, Any]]) -> str:
    if target is None:
        return ""
    sr, cr = target
    ok = all(r["sr"] >= sr and r["cr_inter_arm"] <= cr for r in runs)
    text = f"SR ≥ {sr:g}, CR ≤ {cr:g}" if sr else f"CR ≤ {cr:g}"
    return f"{text}: {'met' if ok else 'not met'}"


def table(seeds: list[int]) -> str:
    head = " | ".join(f"seed {s}" for s in seeds)
    lines = [
        "# Tables II–IV on fresh scenario seeds",
        "",
        f"Seeds {', '.join(map(str, seeds))}: scenario sets that were not used for tuning "
        "(the development seeds are 30, 31 and 32, `../options/README.md`). "
        + "".join(SEED_NOTES[s] + ". " for s in seeds if s in SEED_NOTES)
        + "100 episodes per row and seed, "
        "`nehmo` with its defaults (announced speed bounds, certified "
        "margins: `../options/certified_margins.md`; the same rows with ε = 0.05 m everywhere: "
        "`fixed_eps/`), the baselines as in `../table_II.md`. Cells: SR / CR between arms / "
        "self-collision / stuck [%]. A target is met when every seed meets it.",
        "",
        f"| table | setup | row | {head} | pooled | paper SR / CR | target |",
        "|---|---|---|" + "---|" * len(seeds) + "---|---|---|",
    ]
    for tid, setups in TABLES.items():
        for setup, rows in setups:
            files = [FRESH / f"seed{s}" / f"table_{tid}_{setup}.json" for s in seeds]
            if not all(f.exists() for f in files):
                continue
            summaries = [json.loads(f.read_text()) for f in files]
            for row in rows:
                runs = [next((r for r in s["rows"] if r["row"] == row), None) for s in summaries]
                if any(r is None for r in runs):
                    continue
                ours = [r["ours"] for r in runs]  # type: ignore[index]
                paper = runs[0]["paper"]  # type: ignore[index]
                paper_text = f"{paper['sr']:g} / {paper['cr']:g}" if paper else "–"
                cells = " | ".join(_cell(o) for o in ours)
                met = _met(TARGETS.get((setup, row)), ours)
                lines.append(
                    f"| {tid} | {setup} | {row} | {cells} | {_cell(_pooled(ours))} | "
                    f"{paper_text} | {met} |"
                )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="39,40", help="comma-separated scenario seeds")
    args = parser.parse_args()
    seeds = [int(s) for s in args.seeds.split(",") if s]
    out = FRESH / "tables.md"
    out.write_text(table(seeds))
    print(out.read_text())


if __name__ == "__main__":
    main()
