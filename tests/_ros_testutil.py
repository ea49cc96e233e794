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
