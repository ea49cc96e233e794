"""Helpers of the ROS tests: a DDS domain per test run, bounded subprocesses, nodes spun in
the test's own process (rclpy)."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
PROC = Path(__file__).resolve().parent / "_ros_proc.py"

#: One DDS domain per pytest process, so parallel runs on one machine do not see each other.
DOMAIN_ID = 100 + os.getpid() % 120


def child_env(**extra: str) -> dict[str, str]:
    """Environment of a child process: this run's domain, discovery on this machine only."""
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(DOMAIN_ID)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_STATIC_PEERS", None)
    env.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")  # as orchestrate runs the nodes
    paths = [str(REPO / "nehmo_core"), str(REPO / "nehmo_ros"), env.get("PYTHONPATH", "")]
    env["PYTHONPATH"] = os.pathsep.join(p for p in paths if p)
    env.update(extra)
    return env


def start(*args: str, **extra_env: str) -> subprocess.Popen[str]:
    """Start ``tests/_ros_proc.py <args>`` with piped text output."""
    return subprocess.Popen(
        [sys.executable, str(PROC), *args],
        env=child_env(**extra_env),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def finish(proc: subprocess.Popen[str], timeout: float = 20.0) -> tuple[int, str, str]:
    """Wait for `proc` (killing it after `timeout` seconds); (returncode, stdout, stderr)."""
    try:
        out, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        out, err = proc.communicate()
    return proc.returncode, out, err


class Spinner:
    """One executor for the nodes a test runs in its own process."""

    def __init__(self) -> None:
        from rclpy.executors import SingleThreadedExecutor

        self.executor = SingleThreadedExecutor()
        self.nodes: list[Any] = []

    def add(self, node: Any) -> None:
        self.executor.add_node(node)
        self.nodes.append(node)

    def spin(self, seconds: float, until: Callable[[], bool] | None = None) -> bool:
        """Spin for ``seconds``, or until ``until()`` holds; returns ``until()``'s last value
        (True without ``until``), so a caller asserts that what it waited for happened."""
        return spin_until(self.executor, seconds, until)

    def close(self) -> None:
        for node in self.nodes:
            self.executor.remove_node(node)
            node.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)


def spin_until(executor: Any, seconds: float, until: Callable[[], bool] | None = None) -> bool:
    """Spin ``executor`` until ``until()`` holds (True) or ``seconds`` pass (False; True
    without ``until``)."""
    end = time.monotonic() + seconds
    while True:
        if until is not None and until():
            return True
        if time.monotonic() >= end:
            return until is None
        executor.spin_once(timeout_sec=0.01)


@contextmanager
def in_process(executable: str, params: Sequence[str]) -> Iterator[Spinner]:
    """The ROS context of one in-process test: ``executable --ros-args -p …`` in this test
    run's domain; the spinner's nodes are destroyed and the context shut down at the end."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    rclpy.init(
        args=[executable, "--ros-args", *[a for p in params for a in ("-p", p)]],
        domain_id=DOMAIN_ID,
        signal_handler_options=SignalHandlerOptions.NO,
    )
    try:
        spinner = Spinner()
        yield spinner
        spinner.close()
    finally:
        rclpy.try_shutdown()


class CellProbe:
    """A plain rclpy node in the test process standing in for a cell's drivers: it publishes
    every arm's joint state every ``period`` s (positions from ``positions()``, called at each
    publication), optionally a latched goal for one arm, and records what reaches
    ``command_topic`` as ``(monotonic time, data)`` in :attr:`commands`."""

    def __init__(
        self,
        name: str,
        joint_names: dict[str, list[str]],
        positions: Callable[[], dict[str, Sequence[float]]],
        command_topic: str,
        goal: tuple[str, Sequence[float]] | None = None,
        period: float = 0.02,
    ) -> None:
        import rclpy
        from rclpy.executors import SingleThreadedExecutor
        from rclpy.node import Node
        from rclpy.qos import DurabilityPolicy, QoSProfile, qos_profile_sensor_data
        from sensor_msgs.msg import JointState
        from std_msgs.msg import Float64MultiArray

        self.rclpy, self.JointState = rclpy, JointState
        self.joint_names, self.positions = joint_names, positions
        self.commands: list[tuple[float, list[float]]] = []
        rclpy.init(args=[], domain_id=DOMAIN_ID)
        self.node = Node(name)
        self.states = {
            a: self.node.create_publisher(JointState, f"/{a}/joint_states", qos_profile_sensor_data)
            for a in joint_names
        }
        if goal is not None:
            latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
            arm_id, position = goal
            pub = self.node.create_publisher(JointState, f"/{arm_id}/goal", latched)
            pub.publish(JointState(name=joint_names[arm_id], position=list(position)))
        self.node.create_subscription(Float64MultiArray, command_topic, self._on_command, 50)
        self.node.create_timer(period, self._publish_states)
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)

    def _on_command(self, msg: Any) -> None:
        self.commands.append((time.monotonic(), list(msg.data)))

    def _publish_states(self) -> None:
        stamp = self.node.get_clock().now().to_msg()
        for arm_id, q in self.positions().items():
            msg = self.JointState(name=self.joint_names[arm_id], position=[float(v) for v in q])
            msg.header.stamp = stamp
            self.states[arm_id].publish(msg)

    def spin(self, seconds: float, until: Callable[[], bool] | None = None) -> bool:
        """Spin until ``until()`` holds (True) or ``seconds`` pass."""
        return spin_until(self.executor, seconds, until)

    def call(self, srv_type: Any, name: str, request: Any, seconds: float = 60.0) -> Any:
        """Call a service once it is offered; its response (an assertion error if it is not
        offered or does not answer within ``seconds``)."""
        client = self.node.create_client(srv_type, name)
        try:
            assert self.spin(seconds, client.service_is_ready), f"{name} not offered"
            future = client.call_async(request)
            assert self.spin(seconds, future.done), f"{name} did not answer"
            return future.result()
        finally:
            self.node.destroy_client(client)

    def close(self) -> None:
        self.executor.remove_node(self.node)
        self.node.destroy_node()
        self.executor.shutdown(timeout_sec=1.0)
        self.rclpy.try_shutdown()


#: The suite tests' end-to-end episode: dual UR5, scenario 11 of seed 0, where the naive planner
#: collides 2.2 s in, so the arms must coordinate.
E2E_CELL, E2E_SEED, E2E_INDEX = "dual_ur5", 0, 11


def e2e_scenarios(directory: Path) -> Path:
    """The end-to-end episode's scenario set, written to ``directory/scenarios.json``."""
    from nehmo_core.robots import load_cell
    from nehmo_core.sim.scenario_files import save_scenario_set
    from nehmo_core.sim.scenarios import generate_scenario_set

    scenarios = generate_scenario_set(load_cell(E2E_CELL), E2E_SEED, E2E_INDEX + 1)
    return save_scenario_set(scenarios, directory / "scenarios.json")


def e2e_batch_reference(scenario_file: Path) -> Any:
    """The batch runner's run of the end-to-end episode with the synthetic models and no solve
    cut short by load: what an orchestrated run of it is compared with."""
    from nehmo_core.eval.episode import EpisodeSettings, run_episode
    from nehmo_core.eval.planners import build_planners
    from nehmo_core.planning.models.registry import ModelRegistry, parse_value_models
    from nehmo_core.planning.settings import PlannerSettings
    from nehmo_core.robots import load_cell
    from nehmo_core.sim.scenario_files import load_scenario_set

    cell = load_cell(E2E_CELL)
    scenario = load_scenario_set(scenario_file).scenarios[E2E_INDEX]
    registry = ModelRegistry(parse_value_models(["synthetic"]))
    kinds = dict.fromkeys(cell.arm_ids, "nehmo")
    unhurried = PlannerSettings().override({"opt.deadline": 3600.0})
    planners = build_planners(cell, kinds, scenario, 0.04, registry, unhurried)
    return run_episode(cell, scenario, planners, EpisodeSettings(), kinds=kinds)
