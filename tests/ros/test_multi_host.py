"""The node suite spread over separate hosts: bridge and recorder on one, each planner on its own.

The "hosts" are Linux network namespaces made by this test: a hub namespace holds a bridge
device ``br0``; every host namespace is joined to it by a veth pair and has an address of
10.231.0.0/24. Each node runs under ``ip netns exec`` with discovery over the subnet plus the
other hosts as static peers, and FastDDS restricted to UDPv4, so all DDS traffic between hosts
(clock, states, goals, commands, diagnostics) has to cross the veths instead of shared memory.
The episode (dual-UR5 scenario 11 of seed 0, synthetic value models, as in
``test_e2e_suite``) must end as the same episode run on one host through ``orchestrate`` does:
equal outcome, success within the time limit (the processes run asynchronously). The
namespaces are removed after the run, also when it fails.

Needs root and ``ip netns``; skipped otherwise, with the reason, except where the test must run:
with ``CI`` set (CI runs as root with ``ip netns``) or ``NEHMO_REQUIRE_NETNS=1`` every test of
the module fails instead (``tests/_netns.py``), so a CI machine without namespaces cannot lose
it to one ``-ra`` line.
"""

from __future__ import annotations

import os
import subprocess
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from _netns import Host, hosts, own_namespaces, require_netns
from _ros_testutil import DOMAIN_ID, E2E_CELL, E2E_INDEX, child_env, e2e_scenarios

from nehmo_core.eval.metrics import EpisodeResult, evaluate_log
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import load_scenario_set
from nehmo_core.sim.scenarios import Scenario, goal_error
from nehmo_ros.processes import Process, node_command
from nehmo_ros.suite import EpisodeRun, run_episode
from nehmo_ros.suite_settings import SuiteSettings


@pytest.fixture(scope="module", autouse=True)
def _network_namespaces() -> None:
    """Skip the module (or fail it where it must run) before any episode starts."""
    require_netns("multi-host test")


CELL = load_cell(E2E_CELL)
INDEX = E2E_INDEX
TIME_LIMIT = 20.0  # [s] simulated
STARTUP_TIMEOUT = 240.0  # [s] generous: a loaded CI machine starts processes slowly
STOP_TIMEOUT = 10.0  # [s] after SIGINT before SIGKILL
PREFIX = f"nehmo-mh-{os.getpid()}-"  # every namespace of this test run starts with it
SUBNET = "10.231.0"
MIN_RX_BYTES = 100_000  # every host receives more than this (an episode moves about 1 MB)


@dataclass(frozen=True)
class MultiHostRun:
    exit_codes: dict[str, int | None]
    outputs: dict[str, str]  # the tail of each process's output
    bag: Path
    result: EpisodeResult | None
    error: str
    rx_bytes: dict[str, int]  # received on each host's veth during the run
    namespaces_during_run: list[str]


def host_env(own: Host, all_hosts: dict[str, Host]) -> dict[str, str]:
    peers = ";".join(h.address for h in all_hosts.values() if h is not own)
    return child_env(
        ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET",
        ROS_STATIC_PEERS=peers,
        FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
        PYTHONUNBUFFERED="1",
        OMP_NUM_THREADS="1",
        MKL_NUM_THREADS="1",
    )


def run_on_hosts(scenario_file: Path, out_dir: Path) -> MultiHostRun:
    """The episode with bridge and recorder on one host and every planner on a host of its
    own; the namespaces are gone when this returns (or raises)."""
    bag = out_dir / f"episode_{INDEX:03d}"
    logs = out_dir / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    sim = {"use_sim_time": True}
    procs: list[Process] = []
    codes: dict[str, int | None] = {}
    with hosts(PREFIX, SUBNET, ["sim", *CELL.arm_ids]) as net:
        namespaces = own_namespaces(PREFIX)
        rx_before = {role: h.rx_bytes() for role, h in net.items()}
        try:

            def launch(name: str, host: Host, argv: list[str]) -> Process:
                wrapped = ["ip", "netns", "exec", host.netns, *argv]
                procs.append(Process(name, wrapped, host_env(host, net), logs / f"{name}.log", 0))
                return procs[-1]

            recorder = launch(
                "recorder",
                net["sim"],
                node_command("nehmo_ros.recorder", {"cell": CELL.name, "output": str(bag), **sim}),
            )
            assert recorder.wait_for("recording", STARTUP_TIMEOUT), recorder.output()[-2000:]
            for arm_id in CELL.arm_ids:
                params = {"arm_id": arm_id, "cell": CELL.name, "planner": "nehmo"}
                launch(
                    f"planner_{arm_id}",
                    net[arm_id],
                    node_command(
                        "nehmo_ros.arm_planner",
                        {**params, "model": "synthetic", **sim},
                        ["-r", f"__node:=arm_planner_{arm_id}"],
                    ),
                )
            bridge = launch(
                "sim_bridge",
                net["sim"],
                node_command(
                    "sim_bridge.bridge",
                    {
                        "cell": CELL.name,
                        "scenarios": str(scenario_file),
                        "episode": INDEX,
                        "sim_time": True,
                        "exit_when_done": True,
                        "time_limit": TIME_LIMIT,
                        "start_timeout": STARTUP_TIMEOUT,
                        "planners": "nehmo",
                        "min_subscribers": 3,  # both planners and the recorder
                    },
                ),
            )
            with suppress(subprocess.TimeoutExpired):
                bridge.proc.wait(STARTUP_TIMEOUT + TIME_LIMIT + 30)
            codes["sim_bridge"] = bridge.stop(STOP_TIMEOUT)
            for p in procs:
                if p is not bridge:
                    codes[p.name] = p.stop(STOP_TIMEOUT)
            rx = {role: h.rx_bytes() - rx_before[role] for role, h in net.items()}
        finally:
            for p in procs:  # already stopped unless the run failed part way
                p.stop(2.0)
    outputs = {p.name: p.output()[-3000:] for p in procs}
    result, error = None, ""
    try:
        result = evaluate_log(bag)
    except Exception as exc:  # reported by the tests that need the result
        error = f"{type(exc).__name__}: {exc}"
    return MultiHostRun(codes, outputs, bag, result, error, rx, namespaces)


@pytest.fixture(scope="module")
def scenario_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return e2e_scenarios(tmp_path_factory.mktemp("multi_host"))


@pytest.fixture(scope="module")
def single_host(scenario_file: Path) -> EpisodeRun:
    settings = SuiteSettings(
        planner="nehmo",
        model="synthetic",
        time_limit=TIME_LIMIT,
        domain_id=DOMAIN_ID,
        startup_timeout=STARTUP_TIMEOUT,
        stop_timeout=STOP_TIMEOUT,
    )
    return run_episode(scenario_file, INDEX, scenario_file.parent / "single_host", settings)


@pytest.fixture(scope="module")
def multi_host(scenario_file: Path, single_host: EpisodeRun) -> MultiHostRun:
    # depends on single_host only to run after it: the two episodes never share the CPUs
    return run_on_hosts(scenario_file, scenario_file.parent / "multi_host")


def test_every_process_exits_cleanly(multi_host: MultiHostRun) -> None:
    expected = {"recorder", "sim_bridge", *(f"planner_{a}" for a in CELL.arm_ids)}
    assert set(multi_host.exit_codes) == expected
    failed = {n: c for n, c in multi_host.exit_codes.items() if c != 0}
    assert not failed, (failed, {n: multi_host.outputs[n] for n in failed})


def test_the_episode_succeeds_without_collision(multi_host: MultiHostRun) -> None:
    result = multi_host.result
    assert result is not None, (multi_host.error, multi_host.outputs)
    assert result.outcome == "success", (result.outcome, multi_host.outputs)
    assert not result.collisions
    assert set(result.plan_times) == set(CELL.arm_ids)


def test_the_bag_holds_states_and_commands_of_both_arms(multi_host: MultiHostRun) -> None:
    from mcap.reader import make_reader

    (mcap_file,) = sorted(multi_host.bag.glob("*.mcap"))
    with mcap_file.open("rb") as stream:
        summary = make_reader(stream).get_summary()
    assert summary is not None and summary.statistics is not None
    counts = {
        ch.topic: summary.statistics.channel_message_counts.get(ch_id, 0)
        for ch_id, ch in summary.channels.items()
    }
    for arm_id in CELL.arm_ids:
        for topic in (f"/{arm_id}/joint_states", f"/{arm_id}/velocity_controller/commands"):
            assert counts.get(topic, 0) > 50, (topic, counts)


def _assert_travelled(result: EpisodeResult, scenario: Scenario) -> None:
    """What success does not imply: every arm's path is at least as long as the way it made to
    its goal, no arm covered it faster than ``u_max`` per joint allows, and the episode took at
    least as long as the farthest joint needs at that speed."""
    u_max = PlannerSettings().opt.u_max
    assert result.metadata["success"]["norm"] == "l2"  # final_errors are L2 distances
    soonest = 0.0
    for a in CELL.arm_ids:
        way = goal_error(scenario.start[a], scenario.goal[a], CELL.arm(a).robot)
        made = float(np.linalg.norm(way)) - result.final_errors[a]  # triangle inequality
        length = result.path_lengths[a]
        assert made > 0.5 and made - 1e-9 <= length, (a, made, length)
        assert length <= u_max * np.sqrt(len(way)) * result.end_time, (a, length, result.end_time)
        soonest = max(soonest, (float(np.abs(way).max()) - result.final_errors[a]) / u_max)
    assert result.end_time >= 0.9 * soonest, (result.end_time, soonest)


def test_the_outcome_equals_a_single_host_run(
    multi_host: MultiHostRun, single_host: EpisodeRun, scenario_file: Path
) -> None:
    assert single_host.error == "", single_host.error
    one, many = single_host.result, multi_host.result
    assert one is not None and many is not None, multi_host.error
    assert many.outcome == one.outcome == "success"
    # Both end in success, so within the episode's time limit; how soon depends on how often a
    # starved process misses a solve deadline, so the times are not compared with each other,
    # only with what the scenario takes at least.
    scenario = load_scenario_set(scenario_file).scenarios[INDEX]
    for result in (one, many):
        _assert_travelled(result, scenario)


def test_the_traffic_crossed_the_veths(multi_host: MultiHostRun) -> None:
    rx = multi_host.rx_bytes
    for arm_id in CELL.arm_ids:  # clock, states and goals from the sim host
        assert rx[arm_id] > MIN_RX_BYTES, rx
    assert rx["sim"] > MIN_RX_BYTES, rx  # commands and diagnostics from the planners


def test_no_namespace_of_the_test_remains(request: pytest.FixtureRequest) -> None:
    run = None
    # the run's own failure (a process that did not start, an ``ip`` command or a process wait
    # that failed) is reported by the tests that use it; a failed run must have cleaned up as
    # well, which is what this test checks. Any other error (in the test's own code, say) fails.
    with suppress(AssertionError, RuntimeError, subprocess.SubprocessError):
        run = request.getfixturevalue("multi_host")
    assert own_namespaces(PREFIX) == []
    if run is not None:
        assert len(run.namespaces_during_run) == 2 + len(CELL.arm_ids)  # hub, sim, planners
