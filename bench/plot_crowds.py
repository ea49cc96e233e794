"""Success rate against the number of arms, one line per planner, from ``nehmo evaluate --tasks``
summaries, beside DG-MAP's published averages.

    ./run python bench/plot_crowds.py --summary crowds/generated_ik_s133.json \\
        --summary crowds/generated_ik_s133_naive.json --out crowds/generated_ik_s133.png

Each ``--summary`` is a ``summary.json`` of a task run (a path, or one relative to
``bench/results/``); every row of it with ``by_arms`` becomes one line, labelled by its row and,
when several summaries share a row name, by its file (``--label`` names them instead, one per
summary, in order). Error bars are Wilson 95 % intervals of each count's episodes, so a row run
on 10 tasks per count shows how little it says. DG-MAP's averages (Parimi & Williams, CoRL 2025,
Tables 1–2) are drawn as published; they are not rerun here, and their success rule differs
(end effectors within 0.02 m and 0.1 rad; ours every arm within 0.1 rad of its goal in joint
space, all at once, within 20 s).
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

RESULTS = Path(__file__).resolve().parent / "results"
DGMAP = {3: 97.5, 4: 96.8, 5: 94.5, 6: 92.8, 7: 92.6, 8: 92.4}
"""DG-MAP's average success [%] by arm count (its Tables 1–2)."""
Z95 = 1.959964


def wilson(successes: int, n: int) -> tuple[float, float]:
    """The Wilson 95 % interval of a success rate, in percent."""
    if n <= 0:
        raise ValueError(f"wilson: n must be positive, got {n}")
    p = successes / n
    centre = (p + Z95**2 / (2 * n)) / (1 + Z95**2 / n)
    half = Z95 * math.sqrt(p * (1 - p) / n + Z95**2 / (4 * n * n)) / (1 + Z95**2 / n)
    return 100 * max(0.0, centre - half), 100 * min(1.0, centre + half)


def _resolve(name: str) -> Path:
    path = Path(name)
    if not path.exists() and (RESULTS / name).exists():
        path = RESULTS / name
    if not path.exists():
        raise SystemExit(f"--summary: no file {name} (nor bench/results/{name})")
    return path


def series(summaries: list[tuple[str | None, Path]]) -> list[dict[str, Any]]:
    """One entry per row with ``by_arms``: its label and, per arm count, episodes, successes,
    SR and the Wilson interval."""
    loaded = [(label, path, json.loads(path.read_text())) for label, path in summaries]
    names = [row["row"] for _, _, data in loaded for row in data.get("rows", [])]
    out = []
    for label, path, data in loaded:
        rows = [row for row in data.get("rows", []) if row.get("by_arms")]
        if not rows:
            raise SystemExit(f"--summary {path}: no row has by_arms (not a --tasks run?)")
        for row in rows:
            if label is not None:
                name = label if len(rows) == 1 else f"{label}: {row['row']}"
            elif names.count(row["row"]) > 1:
                name = f"{row['row']} ({path.stem})"
            else:
                name = row["row"]
            points: dict[int, dict[str, Any]] = {}
            for arms, cell in sorted(row["by_arms"].items(), key=lambda kv: int(kv[0])):
                n, k = int(cell["episodes"]), int(cell["successes"])
                points[int(arms)] = {
                    "episodes": n,
                    "successes": k,
                    "sr": 100 * k / n,
                    "interval": wilson(k, n),
                }
            out.append({"label": name, "points": points})
    return out


def plot(lines: list[dict[str, Any]], path: Path, title: str) -> None:
    """SR by arm count with Wilson intervals, DG-MAP dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(
        list(DGMAP),
        list(DGMAP.values()),
        "k--",
        marker="s",
        markersize=4,
        label="DG-MAP (published averages)",
    )
    count = max(len(lines), 1)
    for i, line in enumerate(lines):
        arms = sorted(line["points"])
        shift = (i - (count - 1) / 2) * 0.06  # keep the error bars apart
        sr = [line["points"][a]["sr"] for a in arms]
        # max(0, ·): at 0 or 100 % one end of the interval is the rate itself, up to rounding
        low = [max(0.0, sr[j] - line["points"][a]["interval"][0]) for j, a in enumerate(arms)]
        high = [max(0.0, line["points"][a]["interval"][1] - sr[j]) for j, a in enumerate(arms)]
        n = sorted({line["points"][a]["episodes"] for a in arms})
        per = f"{n[0]}" if len(n) == 1 else f"{n[0]}-{n[-1]}"
        ax.errorbar(
            [a + shift for a in arms],
            sr,
            yerr=[low, high],
            marker="o",
            markersize=4,
            capsize=3,
            label=f"{line['label']} ({per} per count)",
        )
    ax.set_xlabel("arms")
    ax.set_ylabel("success rate [%]")
    ax.set_ylim(0, 101)
    ax.set_xticks(sorted({a for line in lines for a in line["points"]} | set(DGMAP)))
    ax.grid(alpha=0.3)
    ax.set_title(title, fontsize=10)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--summary",
        action="append",
        required=True,
        help="a summary.json of `nehmo evaluate --tasks` (repeatable)",
    )
    parser.add_argument(
        "--label", action="append", default=None, help="a label per --summary, in order"
    )
    parser.add_argument(
        "--out", required=True, help="the PNG to write (relative: under bench/results/)"
    )
    parser.add_argument("--title", default="Success by number of arms (Wilson 95 % intervals)")
    args = parser.parse_args(argv)
    labels: list[str | None] = list(args.label) if args.label else [None] * len(args.summary)
    if len(labels) != len(args.summary):
        parser.error(
            f"--label: give one per --summary ({len(args.summary)}), got {len(args.label)}"
        )
    out = Path(args.out)
    if not out.is_absolute():
        out = RESULTS / out
    if out.suffix != ".png":
        parser.error(f"--out must end in .png, got {args.out}")
    lines = series([(lab, _resolve(s)) for lab, s in zip(labels, args.summary, strict=True)])
    plot(lines, out, args.title)
    for line in lines:
        cells = ", ".join(
            f"{a}: {p['successes']}/{p['episodes']}" for a, p in sorted(line["points"].items())
        )
        print(f"{line['label']}: {cells}")
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
