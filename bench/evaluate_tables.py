"""The paper's Tables II–IV with this implementation, every baseline side by side.

    OMP_NUM_THREADS=1 ./run python bench/evaluate_tables.py --workers 2 \\
        --value-model nehmo=RUN_BC_SYM --value-model nehmo_no_sym=RUN_BC \\
        --value-model opt_deepreach=RUN_DEEPREACH --value-model nehmo=RUN_KINOVA_PAIRS...

For each table (``--tables II,III,IV``) and setup, every row runs on the same seeded scenario
set (``--episodes`` each, default 100, ``--seed`` 0) through ``nehmo evaluate``'s machinery:
25 Hz control with one tick of planning latency, exact collision checks at sub-steps, one MCAP
log per episode (under ``--logs``, not committed), metrics computed from the logs. Written to
``--out`` (default ``bench/results/``):

* ``scenarios/<setup>_seed<seed>.json``: the scenario sets;
* ``table_<id>_<setup>.json`` / ``.md``: per-row metrics beside the paper's, with wall times;
* ``table_<id>.md``: the table; ``table_<id>.png``: bars of our SR/CR against the paper's;
* ``renders/<setup>.gif`` and ``renders/<setup>_distance.png``: the first NeHMO episode.

Smoke run (random stand-in value models; numbers mean nothing):

    OMP_NUM_THREADS=1 ./run python bench/evaluate_tables.py --episodes 2 \\
        --value-model synthetic --out /tmp/tables_smoke --logs /tmp/tables_smoke/logs
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

from nehmo_core.errors import NehmoError
from nehmo_core.eval.batch import BatchConfig, RowRun, run_rows
from nehmo_core.eval.metrics import evaluate_log
from nehmo_core.eval.paper import TABLES, paper_row
from nehmo_core.eval.render import render_episode
from nehmo_core.eval.report import markdown_table, setup_summary, write_summary
from nehmo_core.eval.scenario_sets import scenario_set_for
from nehmo_core.eval.setups import OPT_KINDS, get_setup, parse_row
from nehmo_core.planning.models.registry import parse_value_models, snapshot_value_models
from nehmo_core.robots.loader import cache_dir

RESULTS = Path(__file__).resolve().parent / "results"


def _bars(table: str, summaries: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    fig, axes = plt.subplots(1, len(summaries), figsize=(5.5 * len(summaries), 3.6), squeeze=False)
    for ax, summary in zip(axes[0], summaries, strict=True):
        rows = summary["rows"]
        x = np.arange(len(rows))

        def value(row: dict[str, Any], key: str, ours: bool) -> float:
            src = row["ours"] if ours else (row["paper"] or {})
            v = src.get(key)
            return float("nan") if v is None else float(v)

        series = [
            ("SR ours", "sr", True, "#2a7ab9", None),
            ("SR paper", "sr", False, "#9cc3e4", "//"),
            ("CR ours (between arms)", "cr_inter_arm", True, "#c0392b", None),
            ("CR paper", "cr", False, "#eba59d", "//"),
            ("self-collision ours", "self_collision_rate", True, "#7f8c8d", None),
        ]
        w = 0.16
        for k, (label, key, ours, colour, hatch) in enumerate(series):
            ax.bar(
                x + (k - 2) * w,
                [value(r, key, ours) for r in rows],
                w,
                label=label,
                color=colour,
                hatch=hatch,
                edgecolor="white",
            )
        ax.set_xticks(x, [r["row"] for r in rows], rotation=20, fontsize=8)
        ax.set_ylim(0, 125)
        ax.set_yticks(range(0, 101, 20))
        ax.set_ylabel("%")
        n = rows[0]["ours"]["episodes"] if rows else 0
        ax.set_title(f"Table {table}: {summary['setup']} ({n} episodes)", fontsize=9)
        ax.legend(fontsize=6, ncol=3, loc="upper center")
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _render(setup: str, runs: list[RowRun], out: Path) -> list[Path]:
    """The first episode of the first Opt row (else the first row)."""
    run = next((r for r in runs if any(k in OPT_KINDS for k in r.kinds.values())), runs[0])
    made = render_episode(run.logs[0], out / "renders" / "tmp")
    final = []
    for p in made:
        suffix = "_distance.png" if p.name.endswith("_distance.png") else ".gif"
        target = out / "renders" / f"{setup}{suffix}"
        p.replace(target)
        final.append(target)
    (out / "renders" / "tmp").rmdir()
    return final


def _merge(previous: Path, summary: dict[str, Any], order: tuple[str, ...]) -> dict[str, Any]:
    """``summary``'s rows in place of the same rows of an earlier run (``--only-rows``), in the
    table's row ``order``."""
    if not previous.exists():
        return summary
    old = json.loads(previous.read_text())
    fresh = {r["row"]: r for r in summary["rows"]}
    merged = dict(old)
    rows = [fresh.pop(r["row"], r) for r in old["rows"]] + list(fresh.values())
    rank = {row: i for i, row in enumerate(order)}
    merged["rows"] = sorted(rows, key=lambda r: rank.get(r["row"], len(rank)))
    rerun = {"rows": [r["row"] for r in summary["rows"]]}
    # a row carried over from the first run under a new name is now a fresh row of that name
    renamed = {k: v for k, v in old.get("renamed", {}).items() if v not in rerun["rows"]}
    if renamed:
        merged["renamed"] = renamed
    else:
        merged.pop("renamed", None)
    rerun.update({k: summary[k] for k in ("load_average_at_start", "wall_seconds", "workers")})
    merged["rerun"] = [*old.get("rerun", []), rerun]
    return merged


def _with_collision_kinds(summary: dict[str, Any]) -> dict[str, Any]:
    """Rows from before self-collisions were counted apart get the split from their episode
    logs (where those logs are still on disk; otherwise the row keeps its total CR only)."""
    for row in summary["rows"]:
        ours = row["ours"]
        if "self_collisions" in ours:
            continue
        hit = [e for e in row["episodes"] if e["outcome"] == "collision"]
        if not all(Path(e["log"]).exists() for e in hit):
            continue
        for e in hit:
            e["collision"] = evaluate_log(e["log"]).collision_kind
        own = sum(e["collision"] == "self" for e in hit)
        n = ours["episodes"]
        ours["self_collisions"] = own
        ours["cr_inter_arm"] = 100.0 * (ours["collisions"] - own) / n if n else None
        ours["self_collision_rate"] = 100.0 * own / n if n else None
    return summary


def _table_text(summary: dict[str, Any]) -> str:
    text = markdown_table(summary)
    renamed = {k: v for k, v in summary.get("renamed", {}).items() if k != v}
    if renamed:
        text += (
            f"\nRows {', '.join(renamed.values())} are the first run's rows "
            f"{', '.join(renamed)}: run before `nehmo` gained its self-clearance rows, with the "
            "same code as `nehmo_paper` now.\n"
        )
    runs = summary.get("rerun", [])
    if runs:
        last: dict[str, int] = {}  # row -> the last rerun that produced it
        for i, r in enumerate(runs):
            for row in r["rows"]:
                last[row] = i
        parts = []
        for i in sorted(set(last.values()), reverse=True):
            rows = [r["row"] for r in summary["rows"] if last.get(r["row"]) == i]
            parts.append(
                f"{', '.join(rows)}: rerun {i + 1} of {len(runs)} "
                f"({runs[i]['wall_seconds']:.0f} s wall)"
            )
        first = [r["row"] for r in summary["rows"] if r["row"] not in last]
        if first:
            parts.append(f"{', '.join(first)}: the first run")
        text += "\nEvery run uses the same scenarios. Rows " + "; ".join(parts) + ".\n"
    return text


def run_table(table: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    summaries = []
    for setup_name, all_rows in TABLES[table]:
        if args.report_only or (args.setups and setup_name not in args.setups):
            previous = args.out / f"table_{table}_{setup_name}.json"
            if previous.exists():  # keep it in the table's markdown and plot
                summaries.append(json.loads(previous.read_text()))
            continue
        rows = [r for r in all_rows if r not in args.skip_rows]
        if args.only_rows:
            rows = [r for r in rows if r in args.only_rows]
        setup = get_setup(setup_name)
        cell = setup.load_cell()
        for row in rows:
            parse_row(row, cell)
        scenarios = scenario_set_for(setup, args.seed, args.episodes, args.out / "scenarios")
        config = BatchConfig(
            setup=setup_name,
            out_dir=args.logs / f"seed{args.seed}" / setup_name,
            value_models=snapshot_value_models(
                parse_value_models(args.value_model), args.logs / "value_models"
            ),
            backend=args.backend,
        )
        start = time.perf_counter()
        runs = run_rows(config, rows, scenarios, args.workers, not args.no_progress)
        summary = setup_summary(
            setup_name,
            runs,
            {
                "table": table,
                "seed": scenarios.seed,
                "episodes": len(scenarios),
                "scenario_candidates": scenarios.candidates,
                "workers": args.workers,
                "value_model_sources": args.value_model,
                "load_average_at_start": os.getloadavg(),
                "wall_seconds": time.perf_counter() - start,
                "logs": str(config.out_dir),
            },
        )
        if args.only_rows:
            summary = _merge(args.out / f"table_{table}_{setup_name}.json", summary, all_rows)
        write_summary(args.out, summary, stem=f"table_{table}_{setup_name}")
        # a setup's render shows an Opt row; a rerun of other rows only keeps the one there is
        has_opt = any(k in OPT_KINDS for r in runs for k in r.kinds.values())
        if not args.no_render and (has_opt or not args.only_rows):
            for p in _render(setup_name, runs, args.out):
                print(f"rendered {p}", file=sys.stderr)
        summaries.append(summary)
    return summaries


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--tables", default="II,III,IV", help="comma-separated: II, III, IV")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0, help="scenario set")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--value-model", action="append", default=[], metavar="[KIND=]SOURCE")
    parser.add_argument("--backend", default="auto", choices=("auto", "compiled", "vm"))
    parser.add_argument("--skip-rows", default="", help="comma-separated rows to leave out")
    parser.add_argument("--setups", default="", help="comma-separated setups to run (default: all)")
    parser.add_argument(
        "--only-rows",
        default="",
        help="comma-separated rows to run again; the other rows are kept from the table's "
        "earlier results in --out (the summary lists what was rerun)",
    )
    parser.add_argument("--out", type=Path, default=RESULTS)
    parser.add_argument("--logs", type=Path, default=cache_dir() / "eval_logs")
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="run nothing: write each table's markdown, JSON and plot again from the per-setup "
        "results in --out",
    )
    parser.add_argument("--no-render", action="store_true")
    parser.add_argument("--no-progress", action="store_true")
    args = parser.parse_args(argv)
    args.skip_rows = {r for r in args.skip_rows.split(",") if r}
    args.only_rows = {r for r in args.only_rows.split(",") if r}
    args.setups = {r for r in args.setups.split(",") if r}
    tables = [t.strip() for t in args.tables.split(",") if t.strip()]
    unknown = [t for t in tables if t not in TABLES]
    if unknown:
        print(f"unknown tables {unknown}; valid: {sorted(TABLES)}", file=sys.stderr)
        return 2
    try:
        for table in tables:
            summaries = []
            for summary in run_table(table, args):
                if not all("self_collisions" in r["ours"] for r in summary["rows"]):
                    summary = _with_collision_kinds(summary)
                    write_summary(args.out, summary, stem=f"table_{table}_{summary['setup']}")
                summaries.append(summary)
            text = f"## Table {table}\n\n" + "\n".join(_table_text(s) for s in summaries)
            (args.out / f"table_{table}.md").write_text(text)
            (args.out / f"table_{table}.json").write_text(
                json.dumps({"table": table, "setups": summaries}, indent=1) + "\n"
            )
            _bars(table, summaries, args.out / f"table_{table}.png")
            print(text)
    except NehmoError as exc:
        print(f"evaluate_tables: error: {exc}", file=sys.stderr)
        return 2
    missing = [
        (s, r) for t in tables for s, rows in TABLES[t] for r in rows if paper_row(s, r) is None
    ]
    if missing:
        print(f"rows without paper numbers (extras): {missing}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
