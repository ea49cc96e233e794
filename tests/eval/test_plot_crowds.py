"""bench/plot_crowds.py: Wilson intervals, one line per row of each summary, a PNG written, and a
summary that is not a task run rejected with its path."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _eval_helpers import bench_module


def _summary(path: Path, rows: dict[str, dict[int, tuple[int, int]]]) -> Path:
    data = {
        "rows": [
            {
                "row": row,
                "by_arms": {str(a): {"episodes": n, "successes": k} for a, (k, n) in cells.items()},
            }
            for row, cells in rows.items()
        ]
    }
    path.write_text(json.dumps(data))
    return path


def test_wilson_interval_matches_the_closed_form_and_contains_the_rate():
    plot_crowds = bench_module("plot_crowds")
    low, high = plot_crowds.wilson(10, 10)
    assert low == pytest.approx(72.25, abs=0.01)  # 10 of 10: n / (n + z²)
    assert high == pytest.approx(100.0)
    low, high = plot_crowds.wilson(55, 100)
    assert low < 55 < high
    assert low == pytest.approx(45.25, abs=0.02) and high == pytest.approx(64.4, abs=0.02)
    with pytest.raises(ValueError, match="n must be positive"):
        plot_crowds.wilson(0, 0)


def test_every_row_becomes_a_line_and_the_plot_is_written(tmp_path):
    plot_crowds = bench_module("plot_crowds")
    a = _summary(tmp_path / "a.json", {"nehmo": {3: (9, 10), 8: (5, 10)}, "naive": {3: (4, 10)}})
    b = _summary(tmp_path / "b.json", {"nehmo": {3: (10, 10)}})
    lines = plot_crowds.series([(None, a), (None, b)])
    assert [line["label"] for line in lines] == ["nehmo (a)", "naive", "nehmo (b)"]
    assert lines[0]["points"][8]["sr"] == pytest.approx(50.0)
    labelled = plot_crowds.series([("OMPL", b)])
    assert labelled[0]["label"] == "OMPL"
    out = tmp_path / "plot.png"
    plot_crowds.main(["--summary", str(a), "--summary", str(b), "--out", str(out)])
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_a_summary_without_arm_counts_is_rejected_by_name(tmp_path):
    plot_crowds = bench_module("plot_crowds")
    setup_run = tmp_path / "setup.json"
    setup_run.write_text(json.dumps({"rows": [{"row": "nehmo", "ours": {}}]}))
    with pytest.raises(SystemExit, match="no row has by_arms"):
        plot_crowds.series([(None, setup_run)])
    with pytest.raises(SystemExit):
        plot_crowds.main(
            ["--summary", str(setup_run), "--label", "a", "--label", "b", "--out", "x.png"]
        )
