"""The node suite end to end: bridge, two planners and the recorder as separate processes.

One dual-UR5 episode (scenario 11 of seed 0: the naive planner collides 2.2 s in, so the arms
must coordinate) runs through ``orchestrate`` on rclpy as a ROS user runs the nodes: ``ros_ws``
built with colcon, ``install/setup.bash`` sourced, the install space's executables started. It
runs in this test run's own DDS domain, with
the synthetic pair value models (fast to compile; what this test checks is the suite, not the
models). Meanwhile a plain rclpy node (no nehmo code) listens to the bridge's joint states,
a planner's commands and ``/diagnostics``. Tolerance against the batch
runner (same scenario, same models): the outcome is equal; the time to success and the path
length within generous bounds, because the processes run asynchronously and
may be starved of CPU (solves that overrun their deadline become fail-safe commands, which
the lock-step batch run never sees).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _ros_testutil import (
    DOMAIN_ID,
    E2E_CELL,
    E2E_INDEX,
    e2e_batch_reference,
    e2e_scenarios,
    finish,
    start,
)

from nehmo_core.eval.metrics import EpisodeResult
from nehmo_core.robots import load_cell
from nehmo_ros.suite import EpisodeRun
from nehmo_ros.suite import run_episode as run_ros_episode
from nehmo_ros.suite_settings import SuiteSettings

CELL = load_cell(E2E_CELL)
INDEX = E2E_INDEX


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return e2e_scenarios(tmp_path_factory.mktemp("e2e"))


@pytest.fixture(scope="module")
def suite(scenario_file: Path, colcon_install: Path) -> tuple[EpisodeRun, list[dict[str, Any]]]:
    """The orchestrated episode, and what the plain rclpy listener received."""
    topics = [
        "/ur5_0/joint_states",
        "/ur5_0/velocity_controller/commands",
        "/ur5_0/planner/speed_bound",
        "/diagnostics",
    ]
    heard = scenario_file.parent / "listener.jsonl"
    reader = start("listen", "300", str(heard), *topics)
    try:
        settings = SuiteSettings(
            planner="nehmo",
            model="synthetic",
            time_limit=20.0,
            domain_id=DOMAIN_ID,
            startup_timeout=240.0,  # generous: a loaded CI machine starts processes slowly
            install_space=str(colcon_install),
        )
        run = run_ros_episode(scenario_file, INDEX, scenario_file.parent, settings)
    finally:
        reader.terminate()
        finish(reader, timeout=10)
    lines = heard.read_text().splitlines() if heard.exists() else []
    received = [json.loads(line) for line in lines if line.startswith("{")]
    return run, received


def test_the_nodes_ran_from_the_install_space(suite: Any, colcon_install: Path) -> None:
    run, _ = suite
    assert run.rmw == "rmw_fastrtps_cpp"
    logs = run.log.parent / "logs" / run.log.name
    commands = json.loads((logs / "commands.json").read_text())
    expected = {"recorder", "planner_ur5_0", "planner_ur5_1", "lifecycle_manager", "sim_bridge"}
    assert set(commands) == expected
    for name, argv in commands.items():
        assert argv[0] == "bash" and f'source "{colcon_install}/setup.bash"' in argv[2], name
        package = "sim_bridge" if name == "sim_bridge" else "nehmo_ros"
        assert f"{colcon_install}/{package}/lib/{package}/" in argv[2], name
    assert "episode started" in (logs / "sim_bridge.log").read_text()
    # the planners started unconfigured and were brought up by the lifecycle manager
    assert all("autostart:=false" in commands[f"planner_{a}"] for a in ("ur5_0", "ur5_1"))
    managed = (logs / "lifecycle_manager.log").read_text()
    for arm_id in ("ur5_0", "ur5_1"):
        assert f"arm_planner_{arm_id}: configured" in managed
        assert f"arm_planner_{arm_id}: activated" in managed


@pytest.fixture(scope="module")
def batch(scenario_file: Path) -> EpisodeResult:
    return e2e_batch_reference(scenario_file)


def test_both_arms_reach_their_goals_without_collision(suite: Any) -> None:
    run, _ = suite
    assert run.error == "", run.error
    assert all(code == 0 for code in run.exit_codes.values()), run.exit_codes
    result = run.result
    assert result is not None
    assert result.outcome == "success"
    assert not result.collisions
    assert all(err < 0.1 for err in result.final_errors.values()), result.final_errors
    assert set(result.plan_times) == set(CELL.arm_ids)
    assert all(len(t) > 50 for t in result.plan_times.values())  # every arm kept planning


def test_log_opens_with_the_mcap_and_rosbags_readers(suite: Any) -> None:
    from mcap.reader import make_reader
    from rosbags.highlevel import AnyReader

    run, _ = suite
    (mcap_file,) = sorted(run.log.glob("*.mcap"))
    assert (run.log / "metadata.yaml").is_file()
    with mcap_file.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    topics = {ch.topic for ch in summary.channels.values()}
    assert {"/ur5_0/joint_states", "/ur5_1/velocity_controller/commands", "/clock"} <= topics
    with AnyReader([run.log]) as reader:
        assert reader.message_count == summary.statistics.message_count
        states = [c for c in reader.connections if c.topic == "/ur5_1/joint_states"]
        first = next(iter(reader.messages(states)))
        msg = reader.deserialize(first[2], states[0].msgtype)
        assert list(msg.name) == list(CELL.arm("ur5_1").robot.joint_names)  # type: ignore[attr-defined]


def test_metrics_equal_the_batch_runner_within_tolerance(suite: Any, batch: EpisodeResult) -> None:
    run, _ = suite
    ros = run.result
    assert ros is not None
    assert batch.outcome == ros.outcome == "success"
    # Simulated time, but real-time processes: how soon the arms arrive depends on how often a
    # starved solve becomes fail-safe steps, so only the time limit bounds it.
    assert max(ros.path_lengths.values()) <= 0.5 * 6**0.5 * ros.end_time  # no joint faster than ū
    # Real-time runs can miss a solve deadline near contact; the fail-safe steps that follow
    # lengthen the path by a bounded share of fail-safe steps, never shorten it much.
    assert 0.65 * batch.path_length <= ros.path_length <= 2.0 * batch.path_length


def test_a_plain_rclpy_node_receives_states_commands_and_diagnostics(suite: Any) -> None:
    _, received = suite
    by_topic: dict[str, list[dict[str, Any]]] = {}
    for item in received:
        if "topic" in item:
            by_topic.setdefault(item["topic"], []).append(item)
    states = by_topic.get("/ur5_0/joint_states", [])
    assert states, f"the plain rclpy node received no joint states: {list(by_topic)}"
    assert states[0]["name"] == list(CELL.arm("ur5_0").robot.joint_names)
    assert len(states[0]["position"]) == 6
    commands = by_topic.get("/ur5_0/velocity_controller/commands", [])
    assert len(commands) > 10 and all(len(c["data"]) == 6 for c in commands)
    assert any(any(v != 0.0 for v in c["data"]) for c in commands)  # the arm was moved
    diagnostics = by_topic.get("/diagnostics", [])
    assert {"ur5_0/planner", "ur5_1/planner"} <= {n for d in diagnostics for n in d["status"]}
    bounds = [b["data"] for b in by_topic.get("/ur5_0/planner/speed_bound", [])]
    assert len(bounds) > 10 and all(0.0 <= b <= 1.0 for b in bounds)


def test_the_bag_holds_each_planners_markers(suite: Any) -> None:
    from nehmo_core.logs.reader import read_log

    run, _ = suite
    for arm_id in ("ur5_0", "ur5_1"):
        records = read_log(run.log, topics=[f"/{arm_id}/planner/markers"])
        assert len(records) >= 5, arm_id  # about 5 Hz over the episode
        lines = 0
        for record in records:
            markers = record.message.markers
            assert [(m.ns, m.id) for m in markers] == [(f"nehmo/{arm_id}", k) for k in range(3)]
            assert all(m.header.frame_id == "world" for m in markers)
            line, goal, text = markers
            assert text.text.startswith(f"{arm_id}: ")
            assert goal.type == 2 and goal.action == 0  # a sphere at the goal's tip
            if line.action == 0:  # the critical pair's closest link origins, coloured by V
                lines += 1
                assert line.type == 5 and len(line.points) == 2
                assert (line.color.r, line.color.g) != (0.0, 0.0)
        assert lines >= 1, arm_id  # the peer is in reach: the line is drawn
        values = read_log(run.log, topics=[f"/{arm_id}/planner/min_value"])
        assert len(values) >= 5 and any(math.isfinite(r.message.data) for r in values)


def test_statuses_carry_each_ticks_simulated_time(suite: Any) -> None:
    """``tick_ns`` is the planner's node clock at the tick: simulated time (the bridge's /clock,
    100 Hz steps), one timer period (40 ms) apart whenever no tick was skipped. When the simulated
    clock jumps by more than a period (the bridge's first steps), the timer runs the ticks it owes
    at once, so consecutive ticks may read the same clock; they never read it going backwards."""
    from nehmo_core.logs.reader import read_log

    run, _ = suite
    for arm_id in ("ur5_0", "ur5_1"):
        records = read_log(run.log, topics=[f"/{arm_id}/planner/status"])
        ticks = [
            int(next(kv.value for kv in r.message.values if kv.key == "tick_ns")) for r in records
        ]
        assert len(ticks) > 50, arm_id
        assert (np.diff(ticks) >= 0).all(), arm_id  # the clock never runs backwards
        assert all(t % 10_000_000 == 0 for t in ticks), arm_id  # on the simulated clock's steps
        periods = np.diff(ticks)
        assert int(np.median(periods)) == 40_000_000, arm_id
        assert ticks[-1] <= run.result.end_time * 1e9 + 1e8, arm_id  # simulated, not wall time
