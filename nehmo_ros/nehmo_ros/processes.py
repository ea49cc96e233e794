"""The node processes of one episode: command lines, environment, start and stop.

Each node runs as its own rclpy process in a DDS domain of its own (``ROS_DOMAIN_ID``) kept on
this machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``); :class:`Process` stops one with
SIGINT, then SIGKILL after a bounded wait.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

from nehmo_ros.suite_settings import SuiteSettings

__all__ = [
    "Process",
    "child_env",
    "isolated_domain",
    "node_command",
    "planner_node_name",
    "reported_rmw",
    "started_processes",
]


def isolated_domain() -> int:
    """A DDS domain id for this run (100..219, from the process id)."""
    return 100 + os.getpid() % 120


def child_env(settings: SuiteSettings, domain_id: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(
        {
            "ROS_DOMAIN_ID": str(domain_id),
            "PYTHONUNBUFFERED": "1",
            "OMP_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1",
        }
    )
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # this machine only, unless overridden
    env.pop("ROS_STATIC_PEERS", None)
    # UDP only: with Fast DDS's shared-memory transport a SIGKILLed node stalled the surviving
    # ones (bridge steps up to 5 s apart) until its port was given up.
    env.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")
    env.update(settings.env)
    return env


class Process:
    """A child node process with its output in a file; stopped with SIGINT, then SIGKILL."""

    def __init__(self, name: str, argv: list[str], env: dict[str, str], log: Path, nice: int):
        self.name = name
        self.log = log
        self._out: IO[bytes] = open(log, "wb")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen(
            argv,
            env=env,
            stdout=self._out,
            stderr=subprocess.STDOUT,
            preexec_fn=(lambda: os.nice(nice)) if nice else None,
        )

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def wait_for(self, marker: str, timeout: float) -> bool:
        """True once ``marker`` appears in the output; False on exit or timeout."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if marker in self.output():
                return True
            if self.proc.poll() is not None:
                return False
            time.sleep(0.1)
        return False

    def stop(self, timeout: float) -> int | None:
        """SIGINT, wait up to ``timeout`` s, then SIGKILL; the exit status (None if killed)."""
        killed = False
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
                killed = True
        self._out.close()
        return None if killed else self.proc.returncode


def planner_node_name(arm_id: str) -> str:
    """The node name of arm ``arm_id``'s planner, alone in its process or in a group (the
    lifecycle manager brings it up by this name)."""
    return f"arm_planner_{arm_id}"


#: The console script of each node module: (package, executable).
EXECUTABLES: dict[str, tuple[str, str]] = {
    "nehmo_ros.arm_planner": ("nehmo_ros", "arm_planner"),
    "nehmo_ros.planner_group": ("nehmo_ros", "arm_planners"),
    "nehmo_ros.command_watchdog": ("nehmo_ros", "command_watchdog"),
    "nehmo_ros.lifecycle_manager": ("nehmo_ros", "lifecycle_manager"),
    "nehmo_ros.recorder": ("nehmo_ros", "recorder"),
    "sim_bridge.bridge": ("sim_bridge", "sim_bridge"),
}


def node_command(
    module: str, params: dict[str, Any], extra: Sequence[str] = (), install_space: str = ""
) -> list[str]:
    """``python -m <module> --ros-args -p k:=v ...``; with ``install_space``, the same node as
    ``<install>/<pkg>/lib/<pkg>/<exe> --ros-args ...`` after sourcing ``<install>/setup.bash``."""
    args = ["--ros-args"]
    for key, value in params.items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        args += ["-p", f"{key}:={text}"]
    args += list(extra)
    if not install_space:
        return [sys.executable, "-m", module, *args]
    package, executable = EXECUTABLES[module]
    install = Path(install_space).resolve()
    exe = install / package / "lib" / package / executable
    script = f'source "{install}/setup.bash" && exec "{exe}" "$@"'
    return ["bash", "-c", script, executable, *args]


@contextmanager
def started_processes() -> Iterator[list[Process]]:
    """The processes an episode starts (appended by the caller), all stopped on exit."""
    procs: list[Process] = []
    try:
        yield procs
    finally:
        for p in procs:  # normally already stopped; on errors and Ctrl-C: stop them all
            p.stop(2.0)


def reported_rmw(output: str) -> str:
    """The middleware a node named in its start-up line (``... rmw <name>``), or ''."""
    for line in output.splitlines():
        if ", rmw " in line:
            return line.rsplit(", rmw ", 1)[1].split()[0].strip(")")
    return ""
