"""The paper's metrics from a small log written by hand, malformed messages in a log, and
episodes that cannot be evaluated: every started episode stays in the denominators.

The expected numbers below are worked out by hand from the log the test writes (not through
:func:`~nehmo_core.eval.metrics.aggregate`), so a change in how MPL, planning time or the
fail-safe rate is computed shows up here.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from nehmo_core.eval import batch as batch_module
from nehmo_core.eval.batch import BatchConfig, run_rows
from nehmo_core.eval.episode_log import EpisodeLogWriter
from nehmo_core.eval.metrics import (
    EpisodeResult,
    aggregate,
    evaluate_log,
    evaluate_logs,
    evaluate_or_error,
    format_metrics,
)
from nehmo_core.eval.telemetry import collisions_message, status_message
from nehmo_core.geometry.pybullet_world import Collision
from nehmo_core.logs import (
    DiagnosticStatus,
    Float64MultiArray,
    Header,
    JointState,
    KeyValue,
    String,
    command_topic,
    goal_topic,
    joint_states_topic,
    status_topic,
)
from nehmo_core.logs.topics import COLLISIONS_TOPIC, SCENARIO_TOPIC
from nehmo_core.planning.opt.interface import Telemetry
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import generate_scenario_set

CELL = load_cell("dual_ur5")
PERIOD = 40_000_000  # [ns] 25 Hz
MS = 1_000_000
JOINTS = list(CELL.arm("ur5_1").robot.joint_names)


def _q(j: int = 0, value: float = 0.0) -> np.ndarray:
    q = np.zeros(6)
    q[j] = value
    return q


#: ur5_0 moves along joint 0 (0 → 0.1 → 0.3), ur5_1 along joint 1 (0 → 0 → 0.4); both are at
#: their goals at t = 80 ms, so the episode succeeds there: path 0.1 + 0.2 + 0.4 = 0.7 rad.
TRAJECTORY = {
    "ur5_0": [_q(0, 0.0), _q(0, 0.1), _q(0, 0.3), _q(0, 0.3)],
    "ur5_1": [_q(1, 0.0), _q(1, 0.0), _q(1, 0.4), _q(1, 0.4)],
}
GOALS = {"ur5_0": _q(0, 0.3), "ur5_1": _q(1, 0.4)}
#: (arm, observation [ns], solve time [s], status, fail-safe)
STATUSES = [
    ("ur5_0", 0, 0.001, "optimal", False),
    ("ur5_0", 40 * MS, 0.003, "infeasible", True),
    ("ur5_0", 80 * MS, 0.500, "optimal", False),  # observed at the end: not in the episode
    ("ur5_1", 0, 0.002, "optimal", False),
    ("ur5_1", 40 * MS, math.nan, "stale_peer", False),  # a hold: no planning ran
]


def _write_log(path: Path, garbage: bool = False) -> Path:
    with EpisodeLogWriter(path, CELL) as log:
        if garbage:  # another publisher's scenario messages, before the episode's own
            log._log.write(SCENARIO_TOPIC, String(data="not json {"), 0)
            log._log.write(SCENARIO_TOPIC, String(data='{"format": "other"}'), 0)
        log.scenario(
            {
                "cell": {
                    "name": CELL.name,
                    "arms": [
                        {"id": a.arm_id, "robot": a.robot.name, "base": {"xyz": list(a.base.xyz)}}
                        for a in CELL.arms
                    ],
                },
                "planners": dict.fromkeys(CELL.arm_ids, "nehmo"),
                "timed_arms": list(CELL.arm_ids),
                "control": {"period_ns": PERIOD, "max_ticks": 10},
                "success": {"norm": "l2", "tolerance": 0.1},
                "goal": {a: q.tolist() for a, q in GOALS.items()},
            }
        )
        if garbage:  # a well-formed goal from another publisher first: the metadata decides
            log._log.write(goal_topic("ur5_1"), _state(JOINTS, [2.0] * 6, 0), 0)
        log.goals(GOALS)
        for k in range(4):
            q = {a: TRAJECTORY[a][k] for a in CELL.arm_ids}
            log.tick(k * PERIOD, q, {a: np.zeros(6) for a in CELL.arm_ids})
        for arm, obs, solve, status, fail in STATUSES:
            telemetry = Telemetry(solve, status, fail_safe=fail)
            log.plan(arm, obs + PERIOD, np.zeros(6), status_message(arm, "nehmo", telemetry, obs))
        if garbage:
            _write_garbage(log)
    return path


def _state(names: list[str], position: list[float], t_ns: int) -> JointState:
    return JointState(
        header=Header(stamp=_stamp(t_ns), frame_id=""),
        name=names,
        position=np.asarray(position, dtype=np.float64),
        velocity=np.zeros(0),
    )


def _stamp(t_ns: int):  # type: ignore[no-untyped-def]
    from nehmo_core.eval.telemetry import stamp

    return stamp(t_ns)


def _write_garbage(log: EpisodeLogWriter) -> None:
    """What a foreign node on the same topics leaves in a recording."""
    raw = log._log  # the bag writer underneath
    topic = joint_states_topic("ur5_1")
    bad_states = [
        _state(JOINTS, [math.nan] * 6, 40 * MS),
        _state(JOINTS, [math.inf] * 6, 120 * MS),
        _state(JOINTS[:3], [0.1] * 3, 40 * MS),
        _state([f"unknown_{i}" for i in range(6)], [0.1] * 6, 40 * MS),
        _state(JOINTS, [1e9] * 6, 40 * MS),  # well formed, but disagrees with the bridge's
    ]
    for msg in bad_states:
        raw.write(topic, msg, int(msg.header.stamp.sec * 1e9 + msg.header.stamp.nanosec))
    raw.write_raw(topic, b"\x00\x01\x00\x00garbage", 60 * MS, msgtype="sensor_msgs/msg/JointState")
    commands = command_topic("ur5_1")
    for data in ([math.nan] * 6, [0.1] * 5, [1e6] * 6):
        raw.write(commands, Float64MultiArray(data=np.asarray(data, dtype=np.float64)), 60 * MS)
    bare = DiagnosticStatus(
        level=0,
        name="x",
        message="optimal",
        hardware_id="ur5_1",
        values=[KeyValue(key="planner", value="nehmo")],
    )
    raw.write(status_topic("ur5_1"), bare, 60 * MS)
    negative = status_message("ur5_1", "nehmo", Telemetry(-1.0, "optimal"), 40 * MS)
    raw.write(status_topic("ur5_1"), negative, 60 * MS)
    ghost = collisions_message([Collision("ur5_0", "wrist", "ghost_arm", "base", -0.1)], 60 * MS)
    raw.write(COLLISIONS_TOPIC, ghost, 60 * MS)


def test_metrics_of_a_small_log_equal_the_values_worked_out_by_hand(tmp_path: Path) -> None:
    result = evaluate_log(_write_log(tmp_path / "clean"))
    assert result.outcome == "success"
    assert result.end_ns == 80 * MS
    assert result.path_lengths == pytest.approx({"ur5_0": 0.3, "ur5_1": 0.4})
    assert sorted(result.plan_time_samples()) == pytest.approx([0.001, 0.002, 0.003])
    assert result.fail_safe == {"ur5_0": 1, "ur5_1": 0}
    assert result.malformed == {}
    m = aggregate([result])
    assert m.plan_time_samples == 3
    assert m.plan_time_ms[0] == pytest.approx(2.0)  # (1 + 3 + 2) / 3 ms
    assert m.plan_time_ms[1] == pytest.approx(math.sqrt(2.0 / 3.0))  # population std
    assert m.mpl == pytest.approx((0.7, 0.0))
    assert m.fail_safe_rate == pytest.approx(1.0 / 3.0)  # one of three planned commands
    assert m.statuses == {"optimal": 2, "infeasible": 1, "stale_peer": 1}


def test_malformed_messages_are_ignored_and_counted_per_topic(tmp_path: Path) -> None:
    clean = evaluate_log(_write_log(tmp_path / "clean"))
    dirty = evaluate_log(_write_log(tmp_path / "dirty", garbage=True))
    # the valid stream decides: same outcome, time, path (the 40 ms instant, where the 1e9
    # state disagrees with the real one, is dropped; the arms move along straight lines, so
    # the path length is the same without it)
    assert dirty.outcome == clean.outcome == "success"
    assert dirty.end_ns == clean.end_ns
    assert dirty.path_length == pytest.approx(clean.path_length)
    assert dirty.plan_time_samples() == clean.plan_time_samples()
    assert dirty.collisions == ()  # the collision naming an arm not in the cell is ignored
    assert dirty.malformed == {
        COLLISIONS_TOPIC: 1,
        # NaN, inf, three joints, unknown names, undecodable bytes; the 1e9 state and the
        # bridge's state it disagrees with at 40 ms
        joint_states_topic("ur5_1"): 7,
        status_topic("ur5_1"): 2,  # one lacks its fields, one has a negative solve time
        command_topic("ur5_1"): 3,
        SCENARIO_TOPIC: 2,
    }
    assert "finite" in dirty.malformed_reasons[joint_states_topic("ur5_1")]
    m = aggregate([clean, dirty])
    assert m.malformed == dirty.malformed
    assert m.to_dict()["malformed_messages"][command_topic("ur5_1")] == 3
    assert f"{joint_states_topic('ur5_1')}: 7" in format_metrics(m.to_dict())


def test_errors_stay_in_every_denominator(tmp_path: Path) -> None:
    good = evaluate_log(_write_log(tmp_path / "clean"))
    unfinished = _write_log(tmp_path / "unfinished")
    (unfinished / "metadata.yaml").unlink()  # as after a SIGKILLed recorder
    errors = [
        evaluate_or_error(unfinished),
        evaluate_or_error(tmp_path / "never_written"),
        EpisodeResult.failed("planner_ur5_0: exit 2: bad model"),
    ]
    assert [e.outcome for e in errors] == ["error"] * 3
    assert "not closed" in errors[0].error and "does not exist" in errors[1].error
    m = aggregate([good, *errors])
    assert (m.episodes, m.successes, m.errors) == (4, 1, 3)
    assert m.sr == 25.0 and m.error_rate == 75.0 and m.stuck_rate == 0.0
    assert m.mpl == pytest.approx((0.7, 0.0))  # errors add no path and no planning time
    assert m.plan_time_samples == 3
    line = format_metrics(m.to_dict())
    assert line.startswith("SR 25 % (1 of 4)")
    assert "3 errors: " in line and "bad model" in line and "not closed" in line
    with pytest.raises(ValueError, match="outcomes must be among"):
        aggregate([EpisodeResult.failed("x").__class__(**{**vars(good), "outcome": "lost"})])


def test_bags_read_on_a_process_pool_come_back_in_order(tmp_path: Path) -> None:
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    paths = [_write_log(tmp_path / "a"), tmp_path / "never_written", _write_log(tmp_path / "b")]
    serial = evaluate_logs(paths)
    spawn = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(2, spawn) as pool:
        pooled = evaluate_logs(paths, None, pool)
    assert [r.outcome for r in pooled] == ["success", "error", "success"]
    assert pooled == serial


def test_a_batch_row_keeps_an_episode_that_raised(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    original = batch_module._episode

    def flaky(config, job, start):  # type: ignore[no-untyped-def]
        if job.position == 1:
            raise RuntimeError("planner blew up")
        return original(config, job, start)

    monkeypatch.setattr(batch_module, "_episode", flaky)
    scenarios = generate_scenario_set(CELL, 3, 3)
    config = BatchConfig(setup="dual_ur5", out_dir=tmp_path)
    (run,) = run_rows(config, ["naive"], scenarios, workers=1, progress=False)
    assert [r.outcome == "error" for r in run.results] == [False, True, False]
    assert "RuntimeError: planner blew up" in run.results[1].error
    assert run.metrics.episodes == 3 and run.metrics.errors == 1
    assert run.mismatches == []  # the two that ran agree with their logs
    assert run.metrics.successes + run.metrics.collisions + run.metrics.stuck == 2
