"""Ha et al.'s task files: loading, the joint-convention check, and ``nehmo evaluate --tasks``."""

from __future__ import annotations

import gc
import json
import shutil
from pathlib import Path

import numpy as np
import pybullet as pb
import pytest
from _eval_helpers import record_calls

from nehmo_core.errors import InvalidValueError, ModelFileError
from nehmo_core.eval.cli import main as evaluate_main
from nehmo_core.eval.ha_tasks import (
    TOOL_OFFSET,
    check_joint_convention,
    load_task,
    load_tasks,
    pair_distances,
)
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.geometry.world_pool import WORLDS

TASKS = Path(__file__).parents[1] / "data" / "ha_tasks"


def test_tasks_load_as_cells_with_their_base_poses() -> None:
    tasks = {t.task_id: t for t in load_tasks(TASKS)}
    assert {t.arm_count for t in tasks.values()} == {1, 2, 3, 4}
    four = next(t for t in tasks.values() if t.arm_count == 4)
    raw = json.loads(four.path.read_text())
    for arm, (xyz, quat) in zip(four.cell.arms, raw["base_poses"], strict=True):
        assert arm.base.xyz == pytest.approx(xyz)
        yaw = 2 * np.arctan2(quat[2], quat[3])
        assert np.cos(arm.base.yaw - yaw) == pytest.approx(1.0)
    assert all(0.3 < d < 1.61 for d in pair_distances(four.cell))
    obstacles = [t for t in tasks.values() if t.obstacles]
    assert len(obstacles) == 1 and obstacles[0].arm_count == 3


def test_their_joint_values_put_our_end_effector_on_their_targets() -> None:
    for task in load_tasks(TASKS):
        assert check_joint_convention(task) < 1e-3


def test_a_wrong_joint_order_fails_the_convention_check(tmp_path: Path) -> None:
    data = json.loads((TASKS / "135011.json").read_text())
    data["goal_config"] = [q[::-1] for q in data["goal_config"]]  # wrist first: wrong order
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps(data))
    with pytest.raises(InvalidValueError, match=r"goal_config.*ee_link"):
        check_joint_convention(load_task(bad))
    assert TOOL_OFFSET > 0


def test_bad_task_files_are_rejected_with_the_file_and_entry(tmp_path: Path) -> None:
    data = json.loads((TASKS / "135011.json").read_text())
    missing = dict(data)
    del missing["start_config"]
    (tmp_path / "missing.json").write_text(json.dumps(missing))
    with pytest.raises(ModelFileError, match=r"missing\.json.*start_config"):
        load_task(tmp_path / "missing.json")
    short = dict(data, start_config=[[0.0] * 5, [0.0] * 6])
    (tmp_path / "short.json").write_text(json.dumps(short))
    with pytest.raises(InvalidValueError, match="start_config"):
        load_task(tmp_path / "short.json")
    with pytest.raises(InvalidValueError, match="--tasks"):
        load_tasks(tmp_path / "nowhere")


def test_starts_and_goals_are_collision_free_for_our_geometry() -> None:
    for task in load_tasks(TASKS):
        with CellWorld(task.cell) as world:
            for q in (task.scenario.start, task.scenario.goal):
                world.set_configuration(q)
                assert not world.in_collision(), task.task_id


def _pybullet_clients() -> set[int]:
    """Connected PyBullet clients once unreachable planners are collected (the worlds their
    stages share close with the last of them)."""
    gc.collect()
    return {i for i in range(256) if pb.isConnected(physicsClientId=i)}


def test_evaluate_tasks_writes_rows_per_arm_count(tmp_path: Path) -> None:
    tasks = tmp_path / "tasks"
    tasks.mkdir()
    for name in ("135003.json", "135011.json", "135000.json"):  # 1 arm, 2 arms, obstacles
        shutil.copy(TASKS / name, tasks / name)
    out = tmp_path / "out"
    before, worlds = _pybullet_clients(), len(WORLDS)
    code = evaluate_main(
        ["--tasks", str(tasks), "--planners", "naive,nehmo", "--out", str(out), "--no-progress"]
    )
    assert code == 0
    # every task's simulator and planners let their PyBullet clients go (a task run once kept
    # ~120 MB per four-arm task until the worker ended), the shared worlds of the stages too
    assert _pybullet_clients() == before
    assert len(WORLDS) == worlds
    summary = json.loads((out / "summary.json").read_text())
    assert summary["skipped"] == [{"task": "135000", "arms": 3, "reason": "obstacles"}]
    rows = {r["row"]: r for r in summary["rows"]}
    assert set(rows) == {"naive", "nehmo"}
    for row in rows.values():
        assert row["ours"]["episodes"] == 2
        assert set(row["by_arms"]) == {"1", "2"}
        assert row["by_arms"]["2"]["episodes"] == 1
        for key in ("sr", "cr", "stuck_rate", "episodes"):
            assert key in row["ours"]
    assert rows["nehmo"]["ours"]["collisions"] == 0
    assert rows["nehmo"]["by_arms"]["1"]["sr"] == 100.0
    assert "Ha et al." in (out / "summary.md").read_text()


def test_the_summary_names_generated_tasks_as_such() -> None:
    """Published figures on Ha et al.'s 48 tasks are not cited as if on generated ones."""
    from nehmo_core.eval.task_runner import PUBLISHED, markdown

    row = {"row": "nehmo", "ours": {"episodes": 0, "sr": 0, "cr_inter_arm": 0, "stuck_rate": 0}}
    summary = {"rows": [{**row, "by_arms": {}}], "skipped": [], "success_rule": "r"}
    summary["published"] = PUBLISHED
    shared = markdown({**summary, "tasks": 1, "task_ids": ["135003"]})
    generated = markdown({**summary, "tasks": 1, "task_ids": ["gen_8arm_s80_000"]})
    assert shared.startswith("### Ha et al.'s tasks") and "Published on Ha et al.'s tasks" in shared
    assert generated.startswith("### Generated tasks (Ha et al.'s protocol)")
    assert "Published on other tasks of Ha et al.'s protocol" in generated


def _two_arm_task(tmp_path: Path, planner: str, *options: str) -> dict:
    """``nehmo evaluate --tasks`` on Ha et al.'s two-arm task 135011 with ``options``: the
    summary it writes."""
    tasks = tmp_path / "tasks"
    tasks.mkdir()
    shutil.copy(TASKS / "135011.json", tasks / "135011.json")
    out = tmp_path / "out"
    args = ["--tasks", str(tasks), "--planners", planner, "--out", str(out), "--no-progress"]
    assert evaluate_main([*args, *options]) == 0
    return json.loads((out / "summary.json").read_text())


def test_tasks_run_under_an_actuator_model(tmp_path: Path) -> None:
    """``--actuators realistic`` reaches the task runner's simulator (it once failed every task:
    the simulator was built ideal), and the episodes record the model."""
    summary = _two_arm_task(tmp_path, "nehmo", "--actuators", "realistic")
    assert summary["episode_settings"]["actuators"] == "realistic"
    row = summary["rows"][0]
    assert row["ours"]["episodes"] == 1 and not any(e["error"] for e in row["episodes"])


def test_a_task_with_a_pair_no_model_covers_is_skipped_with_its_reason(tmp_path: Path) -> None:
    """Two UR5s 1 m apart, one mounted 0.3 m higher, are within reach of each other, and no
    shipped model covers bases at different heights: the task is skipped by every row with that
    reason (never a success), and the other tasks still run."""
    tasks = tmp_path / "tasks"
    tasks.mkdir()
    shutil.copy(TASKS / "135003.json", tasks / "135003.json")
    far = json.loads((TASKS / "135011.json").read_text())
    (x, y, z), _ = far["base_poses"][0]
    old, new = far["base_poses"][1][0], [x, y + 1.0, z + 0.3]
    far["base_poses"][1][0] = new
    target = far["target_eff_poses"][1]  # the arm's goal pose moves with its base
    target[0] = [t + n - o for t, n, o in zip(target[0], new, old, strict=True)]
    far["id"] = "far"
    (tasks / "far.json").write_text(json.dumps(far))
    out = tmp_path / "out"
    code = evaluate_main(
        ["--tasks", str(tasks), "--planners", "naive,nehmo", "--out", str(out), "--no-progress"]
    )
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    [skipped] = summary["skipped"]
    assert skipped["task"] == "far" and skipped["arms"] == 2
    assert (
        "no nehmo value model covers the pair ur5_0-ur5_1 (bases 1.04 m apart" in skipped["reason"]
    )
    for row in summary["rows"]:
        assert row["ours"]["episodes"] == 1  # the one-arm task ran; the skipped one is not counted
    assert "far (no nehmo value model" in (out / "summary.md").read_text()


def test_a_resumed_task_run_runs_only_the_unfinished_tasks(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from nehmo_core.eval import task_runner

    tasks = tmp_path / "tasks"
    tasks.mkdir()
    for name in ("135003.json", "135011.json"):
        shutil.copy(TASKS / name, tasks / name)
    out = tmp_path / "out"
    argv = ["--tasks", str(tasks), "--planners", "naive", "--out", str(out), "--no-progress"]
    assert evaluate_main(argv) == 0
    first = json.loads((out / "summary.json").read_text())["rows"][0]["episodes"]
    (out / "logs" / "naive" / "task_135011.done.json").unlink()  # as if stopped during it
    ran = record_calls(monkeypatch, task_runner, "_episode", lambda config, row, t: t.task_id)
    assert evaluate_main([*argv, "--resume"]) == 0
    assert ran == ["135011"]
    again = json.loads((out / "summary.json").read_text())["rows"][0]["episodes"]
    assert [(e["task"], e["outcome"], e["end_time"]) for e in again] == [
        (e["task"], e["outcome"], e["end_time"]) for e in first
    ]


_FINGERPRINTS = """
import sys
from pathlib import Path
import numpy as np
from nehmo_core.eval import batch, task_runner
from nehmo_core.eval.ha_tasks import load_task
from nehmo_core.sim.scenarios import Scenario
task = load_task(Path(sys.argv[1]))
print(task_runner._fingerprint(task_runner.TaskConfig(out_dir=Path("out")), "nehmo", task))
scenario = Scenario({"ur5_0": np.zeros(6)}, {"ur5_0": np.ones(6)})
job = batch._Job("nehmo", 0, 3, 0, scenario, Path("out/logs/nehmo/episode_0003"))
print(batch._fingerprint(batch.BatchConfig("dual_ur5", Path("out")), job))
"""


def test_resume_fingerprints_are_the_same_in_every_process(tmp_path: Path) -> None:
    """``--resume`` keeps an episode only when its fingerprint matches the earlier run's, and
    that run was another process: string hashing is salted per process, so a fingerprint built
    from a set's order (the cell's ``repr``) never matched. Two processes with different salts
    must agree, for task runs and for setup runs."""
    import os
    import subprocess
    import sys

    prints = []
    for salt in ("1", "2"):
        env = {**os.environ, "PYTHONHASHSEED": salt}
        done = subprocess.run(
            [sys.executable, "-c", _FINGERPRINTS, str(TASKS / "135003.json")],
            env=env,
            capture_output=True,
            text=True,
            check=True,
        )
        prints.append(done.stdout.split())
    assert len(prints[0]) == 2 and all(len(p) == 64 for p in prints[0])
    assert prints[0] == prints[1]


def test_tasks_run_for_the_time_limit_given(tmp_path: Path) -> None:
    """``--time-limit`` reaches the task runner: no episode runs past it, and the summary's
    success rule states it."""
    summary = _two_arm_task(tmp_path, "naive", "--time-limit", "0.5")
    assert summary["episode_settings"]["time_limit"] == 0.5
    assert "within 0.5 s" in summary["success_rule"]
    assert all(e["end_time"] <= 0.5 + 1e-9 for e in summary["rows"][0]["episodes"])
