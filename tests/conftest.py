"""Shared fixtures. Tests run single-threaded torch so the suite behaves the same on 2 cores."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

REPO = Path(__file__).resolve().parent.parent

torch.set_num_threads(1)


@pytest.fixture(scope="session")
def colcon_install(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``ros_ws/`` built with colcon into a temporary directory; its install space.

    The interface package (ament_cmake) finds ament, rosidl and the message packages where
    their wheels put them, under the environment's prefix: ``AMENT_PREFIX_PATH`` and
    ``CMAKE_PREFIX_PATH`` name it, and its ``bin/`` (cmake) comes first on PATH."""
    base = tmp_path_factory.mktemp("colcon")
    colcon = Path(sys.executable).parent / "colcon"
    argv = [str(colcon), "--log-base", str(base / "log"), "build"]
    argv += ["--build-base", str(base / "build"), "--install-base", str(base / "install")]
    env = dict(os.environ)
    for name, first in (
        ("AMENT_PREFIX_PATH", sys.prefix),
        ("CMAKE_PREFIX_PATH", sys.prefix),
        ("PATH", str(colcon.parent)),
    ):
        env[name] = os.pathsep.join(p for p in (first, env.get(name, "")) if p)
    proc = subprocess.run(
        argv,
        cwd=REPO / "ros_ws",
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return base / "install"
