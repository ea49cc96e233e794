"""Summaries of evaluation runs: JSON, a markdown table with the paper's numbers beside ours."""

from __future__ import annotations

import json
import math
import platform
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from nehmo_core.eval.batch import RowRun
from nehmo_core.eval.paper import PAPER_NOTES, paper_row

__all__ = [
    "error_notes",
    "json_safe",
    "markdown_table",
    "row_summary",
    "setup_summary",
    "write_summary",
]


def json_safe(x: Any) -> Any:
    """JSON-safe: NaN and inf become None."""
    if isinstance(x, float) and not math.isfinite(x):
        return None
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    return x


def row_summary(setup: str, run: RowRun) -> dict[str, Any]:
    """One row: our metrics, the paper's, per-episode outcomes and the log check."""
    paper = paper_row(setup, run.row)
    return {
        "row": run.row,
        "planners": run.kinds,
        "ours": run.metrics.to_dict(),
        "paper": None
        if paper is None
        else {
            "label": paper.label,
            "sr": paper.sr,
            "cr": paper.cr,
            "time_ms": paper.time_ms,
            "mpl": paper.mpl,
            "note": PAPER_NOTES.get((setup, run.row)),
        },
        "wall_seconds": run.wall_seconds,
        "episode_seconds_mean": sum(run.episode_seconds) / max(len(run.episode_seconds), 1),
        "log_check": "ok" if not run.mismatches else f"mismatch at positions {run.mismatches}",
        "value_models": run.value_models,
        "unmodelled_peers": run.unmodelled_peers,
        "epsilon": run.epsilon,
        "episodes": [
            {
                "scenario": r.metadata.get("scenario_set", {}).get("index"),
                "outcome": r.outcome,
                "collision": r.collision_kind,
                "end_time": r.end_time,
                "path_length": r.path_length,
                "log": str(path),
                "error": r.error,
            }
            for r, path in zip(run.results, run.logs, strict=True)
        ],
    }


def setup_summary(
    setup: str, runs: Sequence[RowRun], extra: Mapping[str, Any] | None = None
) -> dict[str, Any]:
    return json_safe(
        {
            "setup": setup,
            "machine": {"python": platform.python_version(), "platform": platform.platform()},
            **(extra or {}),
            "rows": [row_summary(setup, r) for r in runs],
        }
    )


def _pm(pair: Any, digits: int = 1) -> str:
    if pair is None:
        return "–"
    mean, std = (pair["mean"], pair["std"]) if isinstance(pair, dict) else pair
    if mean is None or (isinstance(mean, float) and math.isnan(mean)):
        return "–"
    return f"{mean:.{digits}f} ± {std:.{digits}f}"


def _pct(x: Any) -> str:
    return "–" if x is None else f"{x:.0f}"


def markdown_table(summary: Mapping[str, Any]) -> str:
    """Our SR/CR/stuck/time/MPL beside the paper's (in parentheses) for every row."""
    lines = [
        f"### {summary['setup']}",
        "",
        "| planners | episodes | SR % (paper) | CR % (paper) | self % | stuck % "
        "| time ms (paper) | MPL rad (paper) | fail-safe | log check |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in summary["rows"]:
        ours, paper = row["ours"], row["paper"] or {}
        sr = f"{_pct(ours['sr'])} ({_pct(paper.get('sr'))})"
        # the paper's CR counts collisions between arms; self-collisions have their own column
        cr = f"{_pct(ours.get('cr_inter_arm', ours['cr']))} ({_pct(paper.get('cr'))})"
        own = _pct(ours.get("self_collision_rate"))
        digits = 0 if (ours["plan_time_ms"]["mean"] or 0) >= 100 else 1
        time_ms = f"{_pm(ours['plan_time_ms'], digits)} ({_pm(paper.get('time_ms'), digits)})"
        mpl = f"{_pm(ours['mpl'])} ({_pm(paper.get('mpl'))})"
        fs = ours["fail_safe_rate"]
        errors = ours.get("errors") or 0
        episodes = f"{ours['episodes']}" + (f" ({errors} errors)" if errors else "")
        lines.append(
            f"| {row['row']} | {episodes} | {sr} | {cr} | {own} "
            f"| {_pct(ours['stuck_rate'])} "
            f"| {time_ms} | {mpl} | {'–' if fs is None else f'{100 * fs:.0f}%'} "
            f"| {row['log_check']} |"
        )
    lines += [
        "",
        "CR: episodes ending in a collision between arms (the paper's definition); self: episodes "
        "ending in an arm's collision with itself (the authors' code counts these as collisions "
        "too). Either ends the episode.",
    ]
    lines += error_notes(summary["rows"])
    notes = [r["paper"]["note"] for r in summary["rows"] if r["paper"] and r["paper"]["note"]]
    if notes:
        lines += ["", *(f"Paper: {n}." for n in notes)]
    for row in summary["rows"]:
        if row.get("unmodelled_peers"):
            pairs = "; ".join(f"{a}: {', '.join(p)}" for a, p in row["unmodelled_peers"].items())
            lines += ["", f"{row['row']}: peers not constrained (no pair model fits): {pairs}."]
    return "\n".join(lines) + "\n"


def error_notes(rows: Sequence[Mapping[str, Any]]) -> list[str]:
    """Lines naming each row's error episodes and malformed messages (nothing when none)."""
    lines = []
    for row in rows:
        ours = row["ours"]
        if ours.get("errors"):
            reasons = "; ".join(dict.fromkeys(ours.get("error_reasons") or []))
            lines += [
                "",
                f"{row['row']}: {ours['errors']} of {ours['episodes']} episodes could not be "
                f"evaluated (counted as failures): {reasons}.",
            ]
        if ours.get("malformed_messages"):
            listed = ", ".join(f"{t}: {n:,}" for t, n in ours["malformed_messages"].items())
            lines += ["", f"{row['row']}: malformed messages ignored: {listed}."]
    return lines


def write_summary(out_dir: str | Path, summary: Mapping[str, Any], stem: str = "summary") -> Path:
    """Write ``<stem>.json`` and ``<stem>.md`` into ``out_dir``; return the JSON path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{stem}.json"
    path.write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
    (out / f"{stem}.md").write_text(markdown_table(summary))
    return path
