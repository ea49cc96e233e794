"""``ros_ws/`` builds with colcon from PyPI, and its install space runs the nodes as a ROS user
runs them: source ``install/setup.bash``, then ``install/<pkg>/lib/<pkg>/<executable>``."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
from _ros_testutil import child_env


def _in_install_space(install: Path, command: str) -> subprocess.CompletedProcess[str]:
    script = f'source "{install}/setup.bash" && {command}'
    return subprocess.run(
        ["bash", "-c", script], env=child_env(), capture_output=True, text=True, timeout=120
    )


@pytest.mark.parametrize(
    ("package", "executable"),
    [("nehmo_ros", "arm_planner"), ("nehmo_ros", "recorder"), ("sim_bridge", "sim_bridge")],
)
def test_the_install_space_has_each_node_executable(
    colcon_install: Path, package: str, executable: str
) -> None:
    path = colcon_install / package / "lib" / package / executable
    assert path.is_file()
    proc = _in_install_space(colcon_install, f'"{path}" --help')
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.startswith(f"`{executable}` node:"), proc.stdout[:200]


def test_sourced_setup_imports_the_installed_packages(colcon_install: Path) -> None:
    proc = _in_install_space(
        colcon_install, 'python -c "import nehmo_ros, sim_bridge; print(nehmo_ros.__file__)"'
    )
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip().startswith(str(colcon_install / "nehmo_ros")), proc.stdout


def test_an_installed_node_rejects_a_bad_parameter_with_one_line(colcon_install: Path) -> None:
    exe = colcon_install / "nehmo_ros" / "lib" / "nehmo_ros" / "arm_planner"
    proc = _in_install_space(
        colcon_install, f'"{exe}" --ros-args -p arm_id:=ur5_0 -p cell:=dual_ur5 -p rate:=0.0'
    )
    assert proc.returncode == 2
    lines = [x for x in proc.stderr.splitlines() if "pybullet build time" not in x]
    assert lines == ["arm_planner: error: `rate` must lie in [0.001, 1000]; got 0.0"], lines
