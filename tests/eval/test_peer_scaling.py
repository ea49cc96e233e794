"""bench/peer_scaling.py --tasks: every arm of a task timed in closed loop, grouped by the peers
it constrains, and the results page written under the given name."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from _eval_helpers import bench_module

TASKS = Path(__file__).resolve().parents[1] / "data" / "ha_tasks"


def test_tasks_mode_times_every_arm_by_constrained_peers(tmp_path, monkeypatch) -> None:
    bench = bench_module("peer_scaling")
    tasks = tmp_path / "tasks"
    tasks.mkdir()
    for name in ("135011.json", "135003.json"):  # two arms; one arm alone
        shutil.copy(TASKS / name, tasks / name)
    rows, names = bench.run_tasks(tasks, 6)
    assert sorted(names) == ["135003", "135011"]
    by_peers = {r["peers"]: r for r in rows}
    assert set(by_peers) == {0, 1}  # the lone arm has no peer; each of the pair has one
    assert by_peers[0]["steps"] == 6 and by_peers[1]["steps"] == 2 * 6
    for r in rows:
        assert 0 < r["median_ms"] <= r["p95_ms"] <= r["max_ms"]
        assert 0 <= r["constrained_share"] <= 1 and 0 <= r["fail_safe_share"] <= 1
    monkeypatch.setattr(bench, "RESULTS", tmp_path / "results")
    meta = {"tasks": names, "tasks_source": "tasks", "steps": 6, "cpu": "x", "torch": "y"}
    bench.write(rows, meta, "crowd_cost")
    saved = json.loads((tmp_path / "results" / "crowd_cost.json").read_text())
    assert saved["rows"] == rows
    page = (tmp_path / "results" / "crowd_cost.md").read_text()
    assert "--tasks DIR --out crowd_cost" in page and "| 1 | 12 |" in page
