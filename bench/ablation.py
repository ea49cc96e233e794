"""Every stage beyond the paper switched off alone, beside the full planner: does it earn its place?

    ./run python bench/ablation.py run --out out/ablation                # the runs (resumable)
    ./run python bench/ablation.py report --out out/ablation             # docs/ablation.md

Rows: the five- and three-UR5 setups and the UR5 beside the reckless Kinova (``nehmo/reckless``,
challenging scenarios), each on two fresh scenario seeds (``--seeds``, 50 episodes each by
default), and Ha et al.'s shared tasks (46 without obstacles). Variants: the full ``nehmo``
planner and one per stage with that stage off (``VARIANTS``). Two workers, the real 40 ms solve
deadline, as the tables run.

The verdict per stage is paired: both planners run the same scenarios (the same tasks), so each
episode of the full planner has a twin with the stage off. The stage earns its place when, in
some row, the episodes that only the full planner gets right (a success; no collision) outnumber
those that only the stage-off planner gets right by more than two standard errors (McNemar's
test: ``(b − c) / √(b + c) > 2``), or when switching it off brings a collision into a row where
the full planner has none (the bar for cooperating arms is zero). A stage that does none of these
in any row changes nothing beyond noise: it is removed. (The first rule compared the pooled
rates unpaired, which ignores that the twins share a scenario; ``unpaired`` in the JSON keeps
what it said.)
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "ablation.md"
RESULTS = ROOT / "bench" / "results" / "ablation.json"

#: variant → (dotted planner settings, the stage it switches off)
VARIANTS: dict[str, tuple[dict[str, str], str]] = {
    "full": ({}, "none (the default `nehmo` planner)"),
    "no_hold": ({"hold.bound": "1.0"}, "hold announcer (`hold`)"),
    "no_exact_guard": ({"exact_guard.gap": "0"}, "exact guard (`exact_guard`)"),
    "no_self_clearance": ({"self_clearance.enabled": "false"}, "self-clearance rows"),
    "no_escape": ({"escape.enabled": "false"}, "stall escape (`escape`)"),
    "no_silent_watch": ({"silent_watch.lookahead": "0"}, "silent-path watch (`silent_watch`)"),
    "single_fail_safe": ({"fail_safe.kind": "single"}, "maximin fail-safe (removed since)"),
}
#: variants whose stage this ablation removed: reported from the runs made before, not run again
REMOVED_STAGES = ("single_fail_safe",)
#: row name → (setup, planners row); ``ha`` runs Ha et al.'s tasks instead of a setup
ROWS: dict[str, tuple[str, str]] = {
    "five_ur5": ("five_ur5", "nehmo"),
    "triple_ur5": ("triple_ur5", "nehmo"),
    "ur5_kinova_challenging": ("ur5_kinova_challenging", "nehmo/reckless"),
    "ha": ("ha", "nehmo"),
}
HA_TASKS = ROOT.parent / "shared" / "ha_benchmark" / "tasks"


def _dirs(out: Path, row: str, seeds: list[int]) -> list[tuple[int | None, Path]]:
    if row == "ha":
        return [(None, out / "ha")]
    return [(s, out / f"{row}_s{s}") for s in seeds]


def run(out: Path, seeds: list[int], episodes: int, tasks: Path, rows: list[str]) -> None:
    for row, (setup, planners) in ROWS.items():
        if row not in rows:
            continue
        for variant, (settings, _) in VARIANTS.items():
            if variant in REMOVED_STAGES:
                continue
            for seed, base in _dirs(out, row, seeds):
                dest = base / variant
                if (dest / "summary.json").exists():
                    continue
                args = [sys.executable, "-m", "nehmo_core.eval.cli", "--planners", planners]
                if seed is None:
                    args += ["--tasks", str(tasks)]
                else:
                    args += ["--setup", setup, "--episodes", str(episodes), "--seed", str(seed)]
                for key, value in settings.items():
                    args += ["--planner-setting", f"{key}={value}"]
                args += ["--workers", "2", "--no-progress", "--out", str(dest)]
                print(f"{row} seed {seed} {variant}", file=sys.stderr, flush=True)
                subprocess.run(args, check=False)  # an error row stays visible in the report


def _outcomes(summary: dict[str, Any]) -> dict[str, str]:
    """Episode (scenario index or task id) → outcome."""
    return {
        str(e.get("scenario", e.get("task"))): e["outcome"] for e in summary["rows"][0]["episodes"]
    }


def _counts(summary: dict[str, Any]) -> dict[str, int]:
    ours = summary["rows"][0]["ours"]
    return {
        "episodes": ours["episodes"],
        "successes": ours["successes"],
        "inter_arm": ours["collisions"] - ours["self_collisions"],
        "self": ours["self_collisions"],
        "stuck": ours["stuck"],
        "errors": ours["errors"],
    }


def collect(out: Path, seeds: list[int]) -> dict[str, dict[str, dict[str, Any]]]:
    """row → variant → per-seed counts and their pooled sum (missing runs are left out)."""
    table: dict[str, dict[str, dict[str, Any]]] = {}
    for row in ROWS:
        for variant in VARIANTS:
            per_seed: dict[str, dict[str, Any]] = {}
            for seed, base in _dirs(out, row, seeds):
                path = base / variant / "summary.json"
                if path.exists():
                    summary = json.loads(path.read_text())
                    key = "tasks" if seed is None else str(seed)
                    per_seed[key] = {**_counts(summary), "outcomes": _outcomes(summary)}
            if per_seed:
                pooled = _pool(per_seed, list(per_seed))
                table.setdefault(row, {})[variant] = {"seeds": per_seed, "pooled": pooled}
    return table


def _pool(per_seed: dict[str, dict[str, Any]], seeds: list[str]) -> dict[str, int]:
    keys = [k for k in next(iter(per_seed.values())) if k != "outcomes"]
    return {k: sum(per_seed[s][k] for s in seeds) for k in keys}


def paired(
    full: dict[str, dict[str, Any]], off: dict[str, dict[str, Any]], seeds: list[str], good: str
) -> tuple[int, int, float]:
    """Twins where only the full planner is good, only the stage-off one is, and McNemar's z;
    ``good``: ``success`` or ``no_collision``."""
    b = c = 0
    for s in seeds:
        for episode, outcome in full[s]["outcomes"].items():
            twin = off[s]["outcomes"].get(episode)
            if twin is None:
                continue
            ok = (outcome == "success", twin == "success")
            if good == "no_collision":
                ok = (outcome != "collision", twin != "collision")
            b += ok[0] and not ok[1]
            c += ok[1] and not ok[0]
    return b, c, (b - c) / math.sqrt(b + c) if b + c else 0.0


def _sr(c: dict[str, int]) -> float:
    return 100.0 * c["successes"] / max(c["episodes"], 1)


def _beyond_noise(high: dict[str, int], low: dict[str, int], key: str) -> bool:
    """``high[key]``'s rate above ``low[key]``'s by more than two standard errors."""
    p1, p2 = high[key] / high["episodes"], low[key] / low["episodes"]
    se = math.sqrt(p1 * (1 - p1) / high["episodes"] + p2 * (1 - p2) / low["episodes"])
    return p1 - p2 > 2 * se and p1 > p2


def verdicts(
    table: dict[str, dict[str, dict[str, Any]]], paired_test: bool = True
) -> dict[str, list[str]]:
    """variant → the rows where switching its stage off mattered (and how): by the paired test,
    or (``paired_test=False``) by the first, unpaired rule."""
    found: dict[str, list[str]] = {v: [] for v in VARIANTS if v != "full"}
    for row, variants in table.items():
        if "full" not in variants:
            continue
        for variant, data in variants.items():
            if variant == "full":
                continue
            # on the seeds both ran (a contested stage may have more than the rest)
            both = sorted(set(data["seeds"]) & set(variants["full"]["seeds"]))
            full = _pool(variants["full"]["seeds"], both)
            off = _pool(data["seeds"], both)
            reasons = found[variant]
            if paired_test:
                for good, label in (("success", "successes"), ("no_collision", "collision-free")):
                    b, c, z = paired(variants["full"]["seeds"], data["seeds"], both, good)
                    if z > 2:
                        reasons.append(
                            f"{row}: {b} episodes {label} only with it, {c} only without "
                            f"(z = {z:.1f}; SR {_sr(full):.0f} → {_sr(off):.0f} %)"
                        )
            elif _beyond_noise(full, off, "successes"):
                reasons.append(f"{row}: SR {_sr(full):.0f} → {_sr(off):.0f} %")
            for kind, label in (
                ("inter_arm", "collisions between arms"),
                ("self", "self-collisions"),
            ):
                unpaired = not paired_test and _beyond_noise(off, full, kind)
                if unpaired or full[kind] == 0 < off[kind]:
                    n = f"{full['episodes']} and {off['episodes']} episodes"
                    reasons.append(f"{row}: {label} {full[kind]} → {off[kind]} ({n})")
    return found


def _seeds_used(table: dict[str, dict[str, dict[str, Any]]]) -> str:
    used = []
    for row, variants in table.items():
        seeds = sorted({s for v in variants.values() for s in v["seeds"] if s != "tasks"})
        if seeds:
            used.append(f"{row} {', '.join(seeds)}")
    return "; ".join(used)


def _cell(c: dict[str, int]) -> str:
    n = c["episodes"]
    text = f"{_sr(c):.0f} / {c['inter_arm']} / {c['self']} / {100 * c['stuck'] / max(n, 1):.0f}"
    return text + (f" ({c['errors']} err)" if c["errors"] else "")


def markdown(table: dict[str, dict[str, dict[str, Any]]], seeds: list[int], note: str) -> str:
    out = [
        "# Ablation: each stage beyond the paper switched off alone\n\n",
        "Written by `./run python bench/ablation.py report` from the runs of "
        "`bench/ablation.py run` (how they are run and judged: the script's docstring). "
        f"Fresh scenario seeds (never used to tune anything): {_seeds_used(table)}; "
        "and Ha et al.'s 46 shared tasks without obstacles.",
        f" {note}\n\n" if note else "\n\n",
        "Each cell: SR % / collisions between arms (episodes) / self-collisions (episodes) / "
        "stuck %, pooled over the seeds; the per-seed numbers are in "
        "[`bench/results/ablation.json`](../bench/results/ablation.json).\n\n",
    ]
    rows = [r for r in ROWS if r in table]
    main = [str(s) for s in seeds] + ["tasks"]

    def cell(row: str, variant: str, keys: list[str]) -> dict[str, int] | None:
        per_seed = table[row].get(variant, {}).get("seeds", {})
        have = [k for k in keys if k in per_seed]
        return _pool(per_seed, have) if have else None

    sizes = {r: (cell(r, "full", main) or {"episodes": 0})["episodes"] for r in rows}
    out.append("| stage off | " + " | ".join(f"{r} ({sizes[r]})" for r in rows) + " |\n")
    out.append("|---" * (len(rows) + 1) + "|\n")
    for variant, (_, label) in VARIANTS.items():
        cells = [cell(r, variant, main) for r in rows]
        out.append(f"| {label} | " + " | ".join(_cell(c) if c else "–" for c in cells) + " |\n")
    extra = [
        (r, v, sorted(data["seeds"]))
        for r in rows
        for v, data in table[r].items()
        if set(data["seeds"]) - set(main)
    ]
    if extra:
        out.append(
            "\nMore seeds for the stages whose verdict the first two left open, run for the full "
            "planner and that stage off (pooled over every seed each ran):\n\n"
            "| row | planner | seeds | SR / between arms / self / stuck |\n|---|---|---|---|\n"
        )
        for r, v, keys in extra:
            c = cell(r, v, keys)
            out.append(
                f"| {r} | {VARIANTS[v][1]} | {', '.join(keys)} | {_cell(c) if c else '–'} |\n"
            )
    out.append("\n## Verdicts\n\n")
    for variant, reasons in verdicts(table).items():
        label = VARIANTS[variant][1]
        if reasons:
            out.append(f"- **{label}** earns its place: {'; '.join(reasons)}.\n")
        else:
            out.append(f"- **{label}**: no row changed beyond noise when it was off.\n")
    return "".join(out)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("action", choices=("run", "report"))
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "ablation")
    parser.add_argument("--seeds", type=int, nargs="+", default=[49, 50])
    parser.add_argument(
        "--extra-seeds", type=int, nargs="*", default=[], help="seeds run for some variants only"
    )
    parser.add_argument("--episodes", type=int, default=50, help="episodes per seed and row")
    parser.add_argument("--tasks", type=Path, default=HA_TASKS, help="Ha et al.'s task files")
    parser.add_argument("--rows", nargs="+", choices=list(ROWS), default=list(ROWS))
    parser.add_argument("--note", default="", help="a sentence added to the page's introduction")
    args = parser.parse_args()
    if args.action == "run":
        run(args.out, args.seeds, args.episodes, args.tasks, args.rows)
        return
    table = collect(args.out, args.seeds + args.extra_seeds)
    report = {
        "seeds": args.seeds,
        "extra_seeds": args.extra_seeds,
        "verdicts": verdicts(table),
        "unpaired": verdicts(table, paired_test=False),
        "rows": table,
    }
    RESULTS.write_text(json.dumps(report, indent=1) + "\n")
    PAGE.write_text(markdown(table, args.seeds, args.note))
    print(f"wrote {PAGE} and {RESULTS}", file=sys.stderr)


if __name__ == "__main__":
    main()
