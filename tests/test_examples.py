"""Every script under ``examples/`` runs with small arguments and produces what it says."""

from __future__ import annotations

import json
import re
import subprocess
import sys
from pathlib import Path

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"


def _run(script: str, *args: str, cwd: Path) -> str:
    out = subprocess.run(
        [sys.executable, str(EXAMPLES / script), *args],
        capture_output=True,
        text=True,
        cwd=cwd,
        timeout=900,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    return out.stdout


def test_every_example_is_tested() -> None:
    tested = {
        "01_value_slice.py",
        "02_batch_episode.py",
        "03_node_suite.py",
        "04_verify_model.py",
    }
    assert {p.name for p in EXAMPLES.glob("*.py")} == tested


def test_01_plots_a_value_slice(tmp_path: Path) -> None:
    png = tmp_path / "slice.png"
    stdout = _run("01_value_slice.py", "--resolution", "11", "--out", str(png), cwd=tmp_path)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert f"wrote {png}" in stdout
    assert "unsafe share" in stdout


def test_02_plans_one_batch_episode(tmp_path: Path) -> None:
    out = tmp_path / "batch"
    stdout = _run("02_batch_episode.py", "--time-limit", "0.4", "--out", str(out), cwd=tmp_path)
    assert "row nehmo: {'ur5_0': 'nehmo', 'ur5_1': 'nehmo'}" in stdout
    assert "outcome " in stdout and " ticks" in stdout
    assert "planning time" in stdout
    assert any(out.rglob("*.mcap"))


def test_03_runs_the_node_suite_on_a_custom_cell(tmp_path: Path) -> None:
    out = tmp_path / "suite"
    stdout = _run("03_node_suite.py", "--time-limit", "0.5", "--out", str(out), cwd=tmp_path)
    assert "cell cell.yaml: arms ['ur5_0', 'ur5_1']" in stdout
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["episodes"]) == 1
    assert summary["episodes"][0]["outcome"] in ("success", "collision", "stuck")


def test_04_certifies_a_shipped_model(tmp_path: Path) -> None:
    stdout = _run("04_verify_model.py", "--samples", "150", "--alpha", "0.1", cwd=tmp_path)
    assert "model ur5_ur5 (bc+sym), τ = 0.3 s, uniform states" in stdout
    rollouts = re.search(r"(\d+) of 150 rollouts in contact", stdout)
    bound = re.search(r"violation probability ≤ ([0-9.]+) at confidence 0.999", stdout)
    assert rollouts is not None and bound is not None, stdout
    assert float(bound.group(1)) > int(rollouts.group(1)) / 150  # a bound above the rate seen
