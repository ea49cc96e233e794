"""Bad input during orchestrated runs: a flood of garbage on a cell's topics, and a node that
fails at start-up.

The flood comes from a plain rclpy node (``_ros_proc.py flood``, no nehmo code) on the run's
DDS domain: malformed JointState on ``/ur5_1/joint_states`` (NaN, inf, 1e9 positions, three
joints, unknown names) and malformed commands on ``/ur5_1/velocity_controller/commands``, at
100 Hz for the whole run. The nodes must stay up and safe, and the evaluation must count every
episode, with the malformed messages it ignored per topic. The count is checked against an
independent recount of the bag with the MCAP library.

The start-up failure: three UR5s 0.6 m apart whose bases climb 0.15 m per arm: in reach of
each other, and no shipped value model covers bases at different heights. Their planners fail
their configure transition; the run must stop the episode then (before the simulation starts)
and name the planner's own error line.
"""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from _ros_testutil import DOMAIN_ID, REPO, child_env, finish, start

from nehmo_core.eval.metrics import OUTCOMES
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import save_scenario_set
from nehmo_core.sim.scenarios import generate_scenario_set
from nehmo_ros.suite import run_suite
from nehmo_ros.suite_settings import SuiteSettings

CELL = load_cell("dual_ur5")
EPISODES = 2
JOINT_STATES = "/ur5_1/joint_states"
COMMANDS = "/ur5_1/velocity_controller/commands"


@pytest.fixture(scope="module")
def flooded(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path, str]:
    """The summary of two orchestrated episodes under the flood, their directory, and what the
    flooding node reported."""
    out = tmp_path_factory.mktemp("flood")
    scenarios = save_scenario_set(generate_scenario_set(CELL, 5, EPISODES), out / "sc.json")
    flood = start("flood", "900", "ur5_1")
    try:
        settings = SuiteSettings(
            planner="nehmo",
            model="synthetic",
            time_limit=6.0,
            domain_id=DOMAIN_ID,
            startup_timeout=240.0,
        )
        summary = run_suite(scenarios, list(range(EPISODES)), out, settings)
    finally:
        flood.terminate()
        _, flood_out, _ = finish(flood, timeout=20)
    return summary, out, flood_out


def _recount(bag: Path) -> dict[str, int]:
    """Malformed messages of the flood's kinds in ``bag``, counted with the MCAP library."""
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    names = list(CELL.arm("ur5_1").robot.joint_names)
    counts = {JOINT_STATES: 0, COMMANDS: 0}
    (mcap_file,) = sorted(bag.glob("*.mcap"))
    with mcap_file.open("rb") as stream:
        for schema, channel, message in make_reader(stream).iter_messages(
            topics=[JOINT_STATES, COMMANDS]
        ):
            assert schema is not None
            msg = typestore.deserialize_cdr(message.data, schema.name)
            if channel.topic == JOINT_STATES:
                ok = list(msg.name) == names and all(math.isfinite(v) for v in msg.position)
            else:
                ok = len(msg.data) == 6 and all(abs(v) <= 3.15 for v in msg.data)
            counts[channel.topic] += not ok
    return counts


def test_every_process_exits_cleanly_and_nothing_collides(flooded: Any) -> None:
    summary, _, flood_out = flooded
    assert '"states"' in flood_out, flood_out  # the flooding node ran to its end
    for episode in summary["episodes"]:
        assert all(code == 0 for code in episode["exit_codes"].values()), episode
        assert episode["outcome"] in OUTCOMES and episode["outcome"] not in ("error",), episode
        assert episode["outcome"] != "collision", episode


def test_the_summary_counts_every_episode(flooded: Any) -> None:
    _, out, _ = flooded
    written = json.loads((out / "summary.json").read_text())
    assert written["metrics"]["episodes"] == EPISODES == len(written["episodes"])
    assert all(e["outcome"] for e in written["episodes"])
    m = written["metrics"]
    assert m["successes"] + m["collisions"] + m["stuck"] + m["errors"] == EPISODES
    assert m["errors"] == 0, m["error_reasons"]


def test_malformed_messages_are_counted_per_topic(flooded: Any) -> None:
    summary, _, _ = flooded
    total: dict[str, int] = {}
    for episode in summary["episodes"]:
        counted = episode["malformed_messages"]
        recount = _recount(Path(episode["log"]))
        assert recount[JOINT_STATES] > 0 and recount[COMMANDS] > 0, recount
        # the reader also drops well-formed 1e9 states that disagree with the bridge's state
        # at one time; every garbage message of the flood is counted
        assert counted[COMMANDS] == recount[COMMANDS], (counted, recount)
        assert counted[JOINT_STATES] >= recount[JOINT_STATES], (counted, recount)
        for topic, n in counted.items():
            total[topic] = total.get(topic, 0) + n
    assert summary["metrics"]["malformed_messages"] == dict(sorted(total.items()))


def test_a_node_failing_at_start_up_stops_the_episode_with_its_reason(tmp_path: Path) -> None:
    cell = tmp_path / "line.yaml"
    # the bases climb 0.15 m per arm: each pair is in reach, and no shipped model covers
    # bases at different heights
    cell.write_text(
        "name: line_three_ur5\narms:\n"
        + "".join(
            f"  - {{id: ur5_{i}, robot: ur5, base: {{xyz: [{x}, 0.0, {z}]}}}}\n"
            for i, (x, z) in enumerate([(0.0, 0.0), (0.6, 0.15), (1.2, 0.3)])
        )
    )
    out = tmp_path / "demo"
    proc = subprocess.run(
        [sys.executable, "-m", "nehmo_ros.demo", "--cell", str(cell), "--out", str(out)],
        env=child_env(),
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr
    # the planner's own error line reaches the terminal
    assert "covers no pair of arm 'ur5_0'" in proc.stdout, proc.stdout
    # started unconfigured, the planner fails its configure transition and says why
    assert "the planners did not come up" in proc.stdout, proc.stdout
    assert "arm_planner_ur5_0: configure failed" in proc.stdout, proc.stdout
    assert "1 error: " in proc.stdout, proc.stdout
    summary = json.loads((out / "summary.json").read_text())
    (episode,) = summary["episodes"]
    assert episode["outcome"] == "error" and summary["metrics"]["errors"] == 1
    # stopped before the simulation started: the episode never ran without its planners
    assert not (out / "logs" / "episode_000" / "sim_bridge.log").exists()
