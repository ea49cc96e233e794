"""Evaluation: the episode runner's stops and latency, metrics from logs, scenario files."""

from __future__ import annotations

import functools
import json
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pytest

from nehmo_core.errors import InvalidValueError, ModelFileError, NehmoError, UnknownNameError
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.episode_log import read_episode_log
from nehmo_core.eval.metrics import EpisodeResult, aggregate, evaluate_log, planning_times
from nehmo_core.eval.report import markdown_table
from nehmo_core.eval.scenario_sets import naive_collides, scenario_set_for
from nehmo_core.eval.setups import get_setup, parse_row
from nehmo_core.geometry.pybullet_world import CellWorld, Collision
from nehmo_core.hjr.networks import NetworkSettings
from nehmo_core.planning.baselines.naive import NaivePlanner
from nehmo_core.planning.models.registry import parse_value_models
from nehmo_core.planning.models.synthetic import random_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.interface import PlanResult, Telemetry, WithoutValues
from nehmo_core.robots import load_cell
from nehmo_core.robots.loader import CELLS_DIR
from nehmo_core.sim.cell_sim import CellSimulator
from nehmo_core.sim.scenario_files import ScenarioFileError, load_scenario_set, save_scenario_set
from nehmo_core.sim.scenarios import Scenario, generate_scenario_set, sample_scenario, scenario_rng

DUAL = load_cell("dual_ur5")
DT = 0.04


def _naive(cell=DUAL):
    return {a: NaivePlanner(cell, a) for a in cell.arm_ids}


@functools.cache
def _scenario_where_naive(outcome: str, time_limit: float = 20.0, limit: int = 40) -> Scenario:
    settings = EpisodeSettings(time_limit=time_limit)
    with CellSimulator(DUAL, settings.substeps) as sim:
        for i in range(limit):
            sc = sample_scenario(DUAL, scenario_rng(0, i), sim.world)
            if run_episode(DUAL, sc, _naive(), settings, simulator=sim).outcome == outcome:
                return sc
    raise AssertionError(f"no naive {outcome} in {limit} scenarios")


class _Recording(WithoutValues):
    """Commands joint 0 at 0.01·(call number + 1) rad/s and records what it observed."""

    def __init__(self, arm_id: str) -> None:
        self.arm_id = arm_id
        self.seen: list[np.ndarray] = []

    def reset(self) -> None:
        self.seen = []

    def plan(self, q_self, peers: Mapping[str, np.ndarray], q_goal, peer_bounds=None) -> PlanResult:
        self.seen.append(np.array(q_self))
        u = np.zeros(6)
        u[0] = 0.01 * len(self.seen)
        return PlanResult(u, Telemetry(1e-4 * len(self.seen), "recording"))


def test_stops_at_success_within_tolerance() -> None:
    with CellWorld(DUAL) as world:
        sc = sample_scenario(DUAL, scenario_rng(0, 1), world)
    goal = {a: q + np.array([0.3, 0, 0, 0, 0, 0]) for a, q in sc.start.items()}
    result = run_episode(DUAL, Scenario(sc.start, goal), _naive())
    assert result.outcome == "success"
    # 1 tick of latency, then 0.2 rad at 0.5 rad/s (0.02 rad per tick) to be within 0.1 rad
    assert result.ticks == 1 + 10
    assert all(e < 0.1 for e in result.final_errors.values())


def test_stops_at_the_first_colliding_tick(tmp_path: Path) -> None:
    sc = _scenario_where_naive("collision")
    result = run_episode(DUAL, sc, _naive(), log_path=tmp_path / "c")
    assert result.outcome == "collision" and result.collisions
    log = read_episode_log(tmp_path / "c")
    assert log.stamps[-1] == result.end_ns and len(log.collisions) == 1
    with CellWorld(DUAL) as world:  # the tick before was free: the runner did not stop late
        world.set_configuration({a: log.positions[a][-2] for a in DUAL.arm_ids})
        assert not world.in_collision()


def test_collision_rate_splits_inter_arm_from_self_collisions() -> None:
    """The paper's CR counts collisions between arms; an episode that ends with an arm in
    itself is counted apart (and in the total, as the authors' code does)."""

    def episode(outcome: str, *hits: tuple[str, str]) -> EpisodeResult:
        collisions = tuple(Collision(a, "wrist_3_link", b, "base_link", -1e-3) for a, b in hits)
        return EpisodeResult(
            outcome,
            10**9,
            25,
            {"ur5_0": 1.0},
            {"ur5_0": "naive"},
            ("ur5_0",),
            {"ur5_0": (1e-4,)},
            {"ur5_0": {}},
            {"ur5_0": 0},
            collisions,
            {"ur5_0": 0.0},
        )

    results = [
        episode("success"),
        episode("collision", ("ur5_0", "ur5_1")),
        episode("collision", ("ur5_0", "ur5_0")),
        episode("collision", ("ur5_1", "ur5_1"), ("ur5_0", "ur5_1")),  # both kinds: between arms
    ]
    assert [r.collision_kind for r in results] == [None, "inter-arm", "self", "inter-arm"]
    m = aggregate(results)
    assert (m.collisions, m.self_collisions) == (3, 1)
    assert (m.cr, m.cr_inter_arm, m.self_collision_rate) == (75.0, 50.0, 25.0)
    summary = {
        "setup": "dual_ur5",
        "rows": [{"row": "naive", "ours": m.to_dict(), "paper": None, "log_check": "ok"}],
    }
    assert "| naive | 4 | 25 (–) | 50 (–) | 25 | 0 |" in markdown_table(summary)


def test_planning_time_leaves_out_holds_and_missed_deadlines() -> None:
    """A node's hold (no planning ran) and a missed deadline (NaN: no solve finished) are not
    planning times; every status where plan() ran is, the fail-safe ones included."""
    records = [
        Telemetry(0.002, "optimal"),
        Telemetry(0.001, "naive"),
        Telemetry(0.003, "infeasible", fail_safe=True),
        Telemetry(math.nan, "deadline_missed", fail_safe=True),
        Telemetry(2e-6, "stale_peer"),
        Telemetry(1e-6, "waiting_for_peers"),
        Telemetry(0.004, "failed", fail_safe=True),
    ]
    assert planning_times(records) == (0.002, 0.001, 0.003, 0.004)


def test_stops_at_the_time_limit() -> None:
    sc = _scenario_where_naive("success")
    hold = {a: _Recording(a) for a in DUAL.arm_ids}
    for p in hold.values():
        p.plan = lambda q, peers, goal, bounds=None: PlanResult(np.zeros(6), Telemetry(0.0, "hold"))  # type: ignore[method-assign]
    result = run_episode(DUAL, sc, hold, EpisodeSettings(time_limit=0.4))
    assert result.outcome == "stuck" and result.ticks == 10 and result.end_time == 0.4
    assert result.path_length == 0.0


def test_command_of_tick_k_was_planned_from_tick_k_minus_1(tmp_path: Path) -> None:
    sc = _scenario_where_naive("success")
    planners = {a: _Recording(a) for a in DUAL.arm_ids}
    result = run_episode(
        DUAL, sc, planners, EpisodeSettings(time_limit=0.4), log_path=tmp_path / "l"
    )
    log = read_episode_log(tmp_path / "l")
    q = log.positions["ur5_0"]
    # the planner saw the state of its tick
    np.testing.assert_array_equal(np.array(planners["ur5_0"].seen), q[:-1])
    # tick 0 holds still; during tick k the arm moves by the command of call k (1-based) = k − 1
    moved = np.diff(q[:, 0])
    assert moved[0] == 0.0
    np.testing.assert_allclose(moved[1:], 0.01 * np.arange(1, 10) * DT, atol=1e-12)
    # logged: the command taking effect at t_{k+1}, planned from observations at t_k
    for t_ns, record in log.statuses["ur5_0"]:
        assert t_ns - record.observation_ns == round(DT * 1e9)
    assert result.plan_times["ur5_0"] == tuple(1e-4 * np.arange(1, 11))


def _small_nehmo_planners() -> dict:
    vf = random_value_function("ur5_ur5", "bc+sym", NetworkSettings(width=16, hidden_layers=1))
    model = PairValueModel.from_value_function(vf, "test_eval_bcsym", backend="vm")
    return {
        "ur5_0": NehmoPlanner(DUAL, "ur5_0", [model]),
        "ur5_1": NaivePlanner(DUAL, "ur5_1"),
    }


def test_metrics_from_logs_equal_the_runner_results(tmp_path: Path) -> None:
    scenarios = [_scenario_where_naive("collision", 6.0), _scenario_where_naive("success", 6.0)]
    kinds = {"ur5_0": "nehmo", "ur5_1": "naive"}
    settings = EpisodeSettings(time_limit=6.0)
    memory, logged = [], []
    naive_kinds = dict.fromkeys(DUAL.arm_ids, "naive")
    runs = [(scenarios[0], _naive(), naive_kinds), (scenarios[1], _naive(), naive_kinds)]
    runs.append((scenarios[0], _small_nehmo_planners(), kinds))
    for i, (sc, planners, k) in enumerate(runs):
        path = tmp_path / f"episode_{i}"
        memory.append(run_episode(DUAL, sc, planners, settings, kinds=k, log_path=path))
        logged.append(evaluate_log(path))
    assert {r.outcome for r in memory} >= {"collision", "success"}
    for m, g in zip(memory, logged, strict=True):
        assert m == g  # every field: outcome, times, path lengths, plan times, statuses, ...
    assert aggregate(memory) == aggregate(logged)
    assert any(sum(r.plan_times["ur5_0"]) > 0 for r in logged)


def test_scenario_files_round_trip(tmp_path: Path) -> None:
    made = generate_scenario_set(DUAL, seed=3, count=2, meta={"setup": "dual_ur5"})
    path = save_scenario_set(made, tmp_path / "s.json")
    back = load_scenario_set(path)
    assert back.indices == (0, 1) and back.seed == 3 and back.meta == {"setup": "dual_ur5"}
    for a, b in zip(made.scenarios, back.scenarios, strict=True):
        for arm in DUAL.arm_ids:
            np.testing.assert_array_equal(a.start[arm], b.start[arm])
            np.testing.assert_array_equal(a.goal[arm], b.goal[arm])
    # scenario i is reproducible on its own
    again = sample_scenario(DUAL, scenario_rng(3, 1))
    np.testing.assert_array_equal(again.goal["ur5_1"], back.scenarios[1].goal["ur5_1"])


@pytest.mark.parametrize(
    ("edit", "message"),
    [
        (lambda d: d.update(format="other"), "format must be 'nehmo-scenarios'"),
        (lambda d: d.update(version=9), "version 9 is not supported"),
        (lambda d: d.update(cell="nowhere"), "unknown cell 'nowhere'"),
        (lambda d: d.pop("seed"), "missing key 'seed'"),
        (lambda d: d["scenarios"][0]["start"].pop("ur5_1"), r"scenarios\[0\].start: arms"),
        (lambda d: d["scenarios"][1]["goal"]["ur5_0"].pop(), r"scenarios\[1\].goal.ur5_0"),
        (lambda d: d["scenarios"][0]["goal"]["ur5_0"].__setitem__(1, 9.0), "joint limits"),
        (lambda d: d["scenarios"][0].update(index="a"), "expected int"),
        (lambda d: d.update(scenarios=[]), "the set is empty"),
    ],
)
def test_bad_scenario_files_raise_naming_the_field(tmp_path: Path, edit, message) -> None:
    made = generate_scenario_set(DUAL, seed=3, count=2)
    path = save_scenario_set(made, tmp_path / "s.json")
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    with pytest.raises(ScenarioFileError, match=message):
        load_scenario_set(path)


def test_unreadable_scenario_files(tmp_path: Path) -> None:
    with pytest.raises(ScenarioFileError, match="not found"):
        load_scenario_set(tmp_path / "missing.json")
    (tmp_path / "bad.json").write_text("{not json")
    with pytest.raises(ScenarioFileError, match="not valid JSON"):
        load_scenario_set(tmp_path / "bad.json")


def test_challenging_set_keeps_exactly_the_naive_collisions(tmp_path: Path) -> None:
    setup = get_setup("ur5_kinova_challenging")
    chosen = scenario_set_for(setup, seed=0, count=2, directory=tmp_path)
    assert (tmp_path / "ur5_kinova_challenging_seed0.json").exists()
    cell = load_cell("ur5_kinova")
    settings = EpisodeSettings.for_setup(setup)
    with CellSimulator(cell, settings.substeps) as sim:
        collides = naive_collides(cell, settings, sim)
        for index in range(chosen.candidates):
            sc = sample_scenario(cell, scenario_rng(0, index), sim.world)
            assert collides(sc) == (index in chosen.indices)
    again = scenario_set_for(setup, seed=0, count=1, directory=tmp_path)  # read back, cut
    assert again.indices == chosen.indices[:1]


def test_rows_and_value_model_sources_are_checked() -> None:
    kinova = load_cell("ur5_kinova")
    assert parse_row("nehmo/reckless", kinova) == {"ur5_0": "nehmo", "kinova_0": "reckless"}
    assert parse_row("chomp", DUAL) == {"ur5_0": "chomp", "ur5_1": "chomp"}
    with pytest.raises(UnknownNameError, match="nehmo"):
        parse_row("rrt", DUAL)
    with pytest.raises(InvalidValueError, match="one per arm"):
        parse_row("nehmo/naive/naive", DUAL)
    with pytest.raises(InvalidValueError, match="cannot be mixed"):
        parse_row("chomp/naive", DUAL)
    with pytest.raises(UnknownNameError, match="setup"):
        get_setup("quad_ur5")


def test_a_cell_file_is_a_setup_of_its_own(tmp_path: Path) -> None:
    """``--setup my_cell.yaml``: the user's cell, named by its file's ``name``, with the paper's
    two-arm rules; a missing file is one clear error."""
    text = (
        (CELLS_DIR / "dual_panda.yaml").read_text().replace("name: dual_panda", "name: my_pandas")
    )
    (tmp_path / "mine.yaml").write_text(text)
    setup = get_setup(str(tmp_path / "mine.yaml"))
    assert (setup.name, setup.time_limit, setup.success_tolerance) == ("my_pandas", 20.0, 0.1)
    assert setup.load_cell().arm_ids == ("panda_0", "panda_1")
    with pytest.raises(ModelFileError, match="cell file not found"):
        get_setup(str(tmp_path / "missing.yaml"))
    specs = parse_value_models(["synthetic", "nehmo_no_sym=/runs/bc"])
    assert [(s.kind, s.source) for s in specs] == [
        (None, "synthetic"),
        ("nehmo_no_sym", "/runs/bc"),
    ]
    with pytest.raises(InvalidValueError, match="KIND"):
        parse_value_models(["nemo=x"])


def test_episode_settings_are_checked() -> None:
    with pytest.raises(InvalidValueError, match="`rate`"):
        EpisodeSettings(rate=0)
    with pytest.raises(UnknownNameError, match="l2"):
        EpisodeSettings(success_norm="l1")
    five = EpisodeSettings.for_setup(get_setup("five_ur5"))
    assert (five.time_limit, five.success_norm, five.success_tolerance) == (30.0, "max", 0.03)
    assert five.max_ticks == 750 and five.period_ns == 40_000_000
    with pytest.raises(NehmoError, match="planner"):
        run_episode(DUAL, _scenario_where_naive("success"), {"ur5_0": _naive()["ur5_0"]})


def test_renders_from_a_log(tmp_path: Path) -> None:
    from PIL import Image

    from nehmo_core.eval.render import plot_distances, render_gif

    sc = _scenario_where_naive("collision")
    run_episode(DUAL, sc, _naive(), EpisodeSettings(time_limit=1.0), log_path=tmp_path / "e")
    log = read_episode_log(tmp_path / "e")
    gif = render_gif(log, tmp_path / "e.gif", fps=5, size=(96, 72))
    with Image.open(gif) as im:
        assert im.n_frames >= 2 and im.size == (96, 72)
    png = plot_distances(log, tmp_path / "d.png", stride=5)
    assert png.stat().st_size > 1000


def test_evaluate_command_writes_logs_summary_and_table(tmp_path: Path) -> None:
    import argparse

    from nehmo_core.eval import cli

    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    argv = ["--setup", "dual_ur5", "--planners", "naive", "--episodes", "2", "--no-progress"]
    args = parser.parse_args([*argv, "--out", str(tmp_path)])
    assert cli.run(args) == 0
    summary = json.loads((tmp_path / "summary.json").read_text())
    row = summary["rows"][0]
    assert row["log_check"] == "ok" and row["ours"]["episodes"] == 2
    assert row["paper"]["sr"] == 66
    logs = sorted(p for p in (tmp_path / "logs" / "naive").iterdir() if p.is_dir())
    assert [p.name for p in logs] == ["episode_0000", "episode_0001"]  # a bag per episode
    records = sorted(p.name for p in (tmp_path / "logs" / "naive").glob("*.done.json"))
    assert records == ["episode_0000.done.json", "episode_0001.done.json"]  # for --resume
    assert [e["log"] for e in row["episodes"]] == [str(p) for p in logs]
    assert sorted(p.name for p in logs[0].iterdir()) == ["episode_0000_0.mcap", "metadata.yaml"]
    assert cli.run(args) == 0  # a second run replaces the bags of the first
    again = json.loads((tmp_path / "summary.json").read_text())["rows"][0]
    assert again["log_check"] == "ok" and again["episodes"] == row["episodes"]
    assert "| naive | 2 |" in (tmp_path / "summary.md").read_text()
    assert load_scenario_set(tmp_path / "scenarios" / "dual_ur5_seed0.json").indices == (0, 1)
    out = tmp_path / "bad"
    bad = parser.parse_args(["--setup", "dual_ur5", "--planners", "nehmo/x", "--out", str(out)])
    with pytest.raises(UnknownNameError, match="planner"):
        cli.run(bad)
    assert not out.exists()


def test_value_model_snapshots_freeze_a_training_run(tmp_path: Path) -> None:
    from nehmo_core.planning.models.registry import snapshot_value_models

    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoint.safetensors").write_bytes(b"weights-1")
    (run / "checkpoint.json").write_text("{}")
    sources = parse_value_models(["synthetic", f"nehmo={run}"])
    snap = snapshot_value_models(sources, tmp_path / "snap")
    assert snap[0] == sources[0] and snap[1].kind == "nehmo"
    copied = Path(snap[1].source)
    assert copied.read_bytes() == b"weights-1" and copied.with_suffix(".json").exists()
    (run / "checkpoint.safetensors").write_bytes(b"weights-2")  # training moves on
    assert copied.read_bytes() == b"weights-1"
    with pytest.raises(NehmoError, match="no weights file"):
        snapshot_value_models(parse_value_models([str(tmp_path / "none")]), tmp_path / "snap")


def test_episode_title_reads_batch_and_ros_metadata() -> None:
    from types import SimpleNamespace

    from nehmo_core.eval.render import episode_title

    cell = SimpleNamespace(name="dual_ur5")
    batch = SimpleNamespace(
        cell=cell,
        metadata={"setup": "dual_ur5", "row": "nehmo", "scenario_set": {"seed": 0, "index": 7}},
    )
    assert episode_title(batch) == "dual_ur5 · nehmo · scenario seed 0 #7"  # type: ignore[arg-type]
    ros = SimpleNamespace(
        cell=cell,
        metadata={
            "source": "ros",
            "scenario": {"file": "s.json", "episode": 0, "seed": 3, "index": 12},
            "planners": {"ur5_0": "nehmo", "ur5_1": "naive"},
        },
    )
    assert episode_title(ros) == "dual_ur5 (ROS) · nehmo/naive · scenario seed 3 #12"  # type: ignore[arg-type]


def test_nehmo_wrap_kind_wraps_the_goal_and_uses_the_bc_sym_model() -> None:
    from nehmo_core.eval.setups import OPT_KINDS
    from nehmo_core.planning.factory import make_planner

    cell = load_cell("dual_ur5")
    model = PairValueModel.from_value_function(
        random_value_function("ur5_ur5", "bc+sym", NetworkSettings(width=16, hidden_layers=1)),
        "tiny",
    )
    plain = make_planner("nehmo", cell, "ur5_0", [model])
    wrapped = make_planner("nehmo_wrap", cell, "ur5_0", [model])
    assert isinstance(wrapped, NehmoPlanner) and isinstance(plain, NehmoPlanner)
    assert wrapped.settings.opt.wrap_goal and not plain.settings.opt.wrap_goal
    assert OPT_KINDS["nehmo_wrap"] == OPT_KINDS["nehmo"] == "bc+sym"
    # a goal 2π − 0.2 away on the base joint: the wrapped cost turns the short way
    q = np.zeros(6)
    goal = q.copy()
    goal[0] = np.pi - 0.1
    q[0] = -np.pi + 0.1
    far = {"ur5_1": np.array([3.0, -1.6, 1.5, -1.6, -1.5, 0.0])}
    assert wrapped.plan(q, far, goal).velocity[0] < 0 < plain.plan(q, far, goal).velocity[0]


def test_one_line_summaries_give_the_papers_cr_and_self_collisions_apart() -> None:
    from types import SimpleNamespace

    from nehmo_core.eval.batch import _postfix
    from nehmo_core.eval.metrics import format_metrics

    episodes = [
        SimpleNamespace(outcome="collision", collision_kind="self"),
        SimpleNamespace(outcome="success", collision_kind=None),
    ]
    assert _postfix(episodes) == "SR 50% CR 0% self 50%"
    metrics = {
        "sr": 50.0,
        "successes": 1,
        "cr": 50.0,  # every collision, as the authors' code counts
        "cr_inter_arm": 0.0,
        "self_collision_rate": 50.0,
        "stuck_rate": 0.0,
        "plan_time_ms": {"mean": 1.0, "std": 0.5},
        "mpl": {"mean": 2.0, "std": 0.0},
        "episodes": 2,
    }
    assert format_metrics(metrics).startswith("SR 50 % (1 of 2)  CR 0 %  self 50 %  stuck 0 %")
    assert "error" not in format_metrics(metrics)


def test_evaluate_with_out_naming_a_file_is_one_clear_error(tmp_path: Path) -> None:
    from nehmo_core.eval.cli import main as evaluate_main

    a_file = tmp_path / "results"
    a_file.write_text("")
    args = ["--setup", "dual_ur5", "--planners", "naive", "--episodes", "1", "--out", str(a_file)]
    assert evaluate_main(args) == 2
    assert a_file.read_text() == ""


def test_time_limit_option_sets_the_episode_length_and_is_checked(tmp_path: Path) -> None:
    """``--time-limit`` replaces the setup's episode length (recorded in the summary; no
    episode runs past it) and a length that is not positive is one clear error."""
    import argparse

    from nehmo_core.eval import cli

    parser = argparse.ArgumentParser()
    cli.add_arguments(parser)
    argv = ["--setup", "dual_ur5", "--planners", "naive", "--episodes", "2", "--no-progress"]
    args = parser.parse_args([*argv, "--out", str(tmp_path / "a"), "--time-limit", "0.6"])
    assert cli.run(args) == 0
    summary = json.loads((tmp_path / "a" / "summary.json").read_text())
    assert summary["episode_settings"]["time_limit"] == 0.6
    episodes = summary["rows"][0]["episodes"]
    assert all(e["end_time"] <= 0.6 + 1e-9 for e in episodes)
    assert any(e["outcome"] == "stuck" and e["end_time"] == pytest.approx(0.6) for e in episodes)
    for bad in ("0", "-5", "nan"):
        out = tmp_path / f"bad{bad}"
        args = parser.parse_args([*argv, "--out", str(out), "--time-limit", bad])
        with pytest.raises(InvalidValueError, match="--time-limit"):
            cli.run(args)
        assert not out.exists()
