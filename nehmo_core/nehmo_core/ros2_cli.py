"""``ros2`` where no ROS 2 installation provides one: ``ros2 run`` and ``ros2 pkg executables``.

The ROS 2 command line (``ros2cli``) is not on PyPI, so on a pip install (``./run``) this
stand-in offers the two verbs a user needs to start the nodes of a sourced colcon workspace::

    source ros_ws/install/setup.bash
    ros2 run nehmo_ros arm_planner --ros-args -p arm_id:=ur5_0 -p cell:=dual_ur5
    ros2 pkg executables nehmo_ros

It resolves executables through the ament index of the sourced workspaces
(``AMENT_PREFIX_PATH``, as ``ros2run`` does: ``<prefix>/lib/<package>/<executable>``) and
replaces itself with the executable, so signals reach the node directly. Any other verb gets
one line saying what this is. Where a real ``ros2`` is on ``PATH`` (a ROS 2 installation), it
hands every call to that one, whatever the order of ``PATH``: it never shadows it.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path

__all__ = ["main"]

PROGRAM = "ros2"
MARKER = "nehmo_core.ros2_cli"  # in the console script pip writes for this entry point
USAGE = """usage: ros2 run <package> <executable> [argv ...]
       ros2 pkg executables [<package>]

NeHMO's stand-in for the ROS 2 command line on a pip install (a real ros2 on PATH is used
instead). It runs the executables of the workspaces sourced with install/setup.bash."""


def _is_stand_in(path: Path) -> bool:
    try:
        head = path.read_bytes()[:1024]
    except OSError:
        return False
    return MARKER.encode() in head or path.resolve() == Path(sys.argv[0]).resolve()


def real_ros2() -> Path | None:
    """The first ``ros2`` on ``PATH`` that is not this stand-in, or None."""
    for folder in os.environ.get("PATH", "").split(os.pathsep):
        candidate = Path(folder or ".") / PROGRAM
        if candidate.is_file() and os.access(candidate, os.X_OK) and not _is_stand_in(candidate):
            return candidate
    return None


def _fail(message: str, code: int = 1) -> int:
    print(f"{PROGRAM}: {message}", file=sys.stderr)
    return code


class _NoIndex(Exception):
    """No ament index to read: nothing sourced, or ament_index_python missing."""


def _index() -> dict[str, str]:
    """Package name → install prefix of every package in the sourced workspaces."""
    if not os.environ.get("AMENT_PREFIX_PATH"):
        raise _NoIndex(
            "no workspace is sourced (AMENT_PREFIX_PATH is empty): source install/setup.bash "
            "of a colcon workspace, e.g. ros_ws/install/setup.bash"
        )
    try:
        from ament_index_python.packages import get_packages_with_prefixes
    except ImportError as exc:
        raise _NoIndex(f"cannot read the ament index ({exc}); ./run installs it") from None
    return dict(get_packages_with_prefixes())


def _executables(package: str, prefix: str) -> list[str]:
    folder = Path(prefix) / "lib" / package
    if not folder.is_dir():
        return []
    return sorted(p.name for p in folder.iterdir() if p.is_file() and os.access(p, os.X_OK))


def _run(args: Sequence[str]) -> int:
    if len(args) < 2:
        return _fail("usage: ros2 run <package> <executable> [argv ...]", 2)
    package, executable, rest = args[0], args[1], list(args[2:])
    prefix = _index().get(package)
    if prefix is None:
        return _fail(
            f"package {package!r} not found in the sourced workspaces (AMENT_PREFIX_PATH); "
            "source its install/setup.bash"
        )
    found = _executables(package, prefix)
    if executable not in found:
        return _fail(f"no executable {executable!r} in package {package!r} (it has {found})")
    path = Path(prefix) / "lib" / package / executable
    os.execv(path, [str(path), *rest])  # the node replaces this process: signals reach it
    return 0  # not reached


def _pkg(args: Sequence[str]) -> int:
    if not args or args[0] != "executables" or len(args) > 2:
        return _fail("this stand-in knows only 'ros2 pkg executables [<package>]'", 2)
    index = _index()
    if len(args) == 2 and args[1] not in index:
        return _fail(f"package {args[1]!r} not found in the sourced workspaces")
    for package in [args[1]] if len(args) == 2 else sorted(index):
        for executable in _executables(package, index[package]):
            print(f"{package} {executable}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = list(sys.argv[1:] if argv is None else argv)
    real = real_ros2()
    if real is not None:
        os.execv(real, [str(real), *args])
    if not args or args[0] in ("-h", "--help"):
        print(USAGE)
        return 0
    try:
        if args[0] == "run":
            return _run(args[1:])
        if args[0] == "pkg":
            return _pkg(args[1:])
    except _NoIndex as exc:
        return _fail(str(exc))
    return _fail(
        f"'{args[0]}' needs the ROS 2 command line, which is not on PyPI: this is NeHMO's "
        "stand-in with 'run' and 'pkg executables' only (a full ROS 2: the docker/ image)",
        2,
    )


if __name__ == "__main__":
    raise SystemExit(main())
