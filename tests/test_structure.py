"""The shape of the source tree: a ROS-free core, no import cycle in planning, small modules."""

from __future__ import annotations

import ast
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CORE = ROOT / "nehmo_core" / "nehmo_core"
PLANNING = CORE / "planning"
PACKAGES = [CORE, ROOT / "nehmo_ros", ROOT / "sim_bridge"]
MAX_LINES = 450

_IMPORT_ALL_WITHOUT_ROS = textwrap.dedent(
    """
    import importlib, importlib.abc, pkgutil, sys

    BLOCKED = ("rclpy", "nehmo_ros", "sim_bridge", "rosidl", "rosbag2_py", "launch", "ament")

    class NoRos(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            top = name.split(".")[0]
            if top in BLOCKED or top.endswith("_msgs") or top.endswith("_interfaces"):
                raise ImportError(f"{name} is not installed (blocked: the core must not need ROS)")
            return None

    sys.meta_path.insert(0, NoRos())
    import nehmo_core

    names = [m.name for m in pkgutil.walk_packages(nehmo_core.__path__, "nehmo_core.")]
    for name in names:
        importlib.import_module(name)
    print(f"imported {len(names)} modules")
    """
)


def test_every_core_module_imports_without_ros() -> None:
    out = subprocess.run(
        [sys.executable, "-c", _IMPORT_ALL_WITHOUT_ROS],
        capture_output=True,
        text=True,
        timeout=600,
        check=False,
    )
    assert out.returncode == 0, out.stderr[-3000:]
    count = int(out.stdout.split()[1])
    assert count == len(list(CORE.rglob("*.py"))) - 1  # every module but the package itself


def _planning_module(path: Path) -> str:
    """``stages.exact_guard`` for ``planning/stages/exact_guard.py``."""
    return ".".join(path.relative_to(PLANNING).with_suffix("").parts)


def _planning_imports(path: Path) -> set[str]:
    """Planning modules that ``path`` imports (at any depth in the file)."""
    known = {_planning_module(p) for p in PLANNING.rglob("*.py")}
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
        elif isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        else:
            continue
        for name in names:
            parts = name.split(".")
            if parts[:2] == ["nehmo_core", "planning"] and ".".join(parts[2:]) in known:
                out.add(".".join(parts[2:]))
    return out - {_planning_module(path)}


def test_planning_modules_import_no_cycle() -> None:
    graph = {
        _planning_module(p): _planning_imports(p)
        for p in PLANNING.rglob("*.py")
        if p.stem != "__init__"
    }
    done: set[str] = set()

    def visit(module: str, stack: list[str]) -> None:
        assert module not in stack, f"import cycle: {' -> '.join([*stack, module])}"
        if module in done:
            return
        for child in sorted(graph.get(module, ())):
            visit(child, [*stack, module])
        done.add(module)

    for module in sorted(graph):
        visit(module, [])
    assert "numerics.qp" in graph and graph["numerics.qp"] == set()


def _sources() -> list[Path]:
    return sorted(p for root in PACKAGES for p in root.rglob("*.py") if "build" not in p.parts)


def test_source_files_are_short_and_say_what_they_hold() -> None:
    long = {
        str(p.relative_to(ROOT)): n
        for p in _sources()
        if (n := len(p.read_text().splitlines())) > MAX_LINES
    }
    assert not long, f"files over {MAX_LINES} lines: {long}"
    for path in _sources():
        doc = ast.get_docstring(ast.parse(path.read_text()))
        assert doc and doc.strip(), f"{path.relative_to(ROOT)} has no module docstring"


def test_readme_layout_names_every_package_and_subpackage() -> None:
    layout = (ROOT / "README.md").read_text().split("## Layout", 1)[1].split("\n## ", 1)[0]
    packages = sorted(
        str(init.parent.relative_to(ROOT))
        for package in PACKAGES
        for init in package.rglob("__init__.py")
        if ".venv" not in init.parts
    )
    named = {
        line.split("`")[1].rstrip("/") for line in layout.splitlines() if line.startswith("| `")
    }
    # a project's own package directory (nehmo_ros/nehmo_ros) is named by the project's row
    inner = {
        p for p in packages if p.split("/")[-1] == p.split("/")[0] and p.split("/")[0] in named
    }
    missing = [p for p in packages if p not in named and p not in inner]
    assert not missing, f"README Layout lacks {missing}"


def test_readme_limitations_are_short() -> None:
    text = (ROOT / "README.md").read_text().split("## Limitations", 1)[1].split("\n## ", 1)[0]
    lines = [line for line in text.strip().splitlines() if line.strip()]
    assert 0 < len(lines) <= 25, f"README Limitations has {len(lines)} lines (at most 25)"


def test_ros_nodes_use_planners_through_their_interface() -> None:
    """No ``hasattr``/``getattr``/``cast`` on a planner in nehmo_ros: the ``Planner`` protocol
    says what every planner answers."""
    found = []
    for path in sorted((ROOT / "nehmo_ros" / "nehmo_ros").glob("*.py")):
        for node in ast.walk(ast.parse(path.read_text())):
            if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Name)):
                continue
            if node.func.id not in ("hasattr", "getattr", "cast") or not node.args:
                continue
            subject = ast.unparse(node.args[1 if node.func.id == "cast" else 0])
            if node.func.id == "hasattr" or "planner" in subject:  # _PLANNER: settings
                found.append(f"{path.name}:{node.lineno}: {ast.unparse(node)}")
    assert not found, found


PLANNING_MAX_LINES = 300
#: planning's layers, bottom first: a module may import its own layer's package and those below
PLANNING_LAYERS = {
    "settings": 0,
    "numerics": 0,
    "models": 1,
    "opt": 2,
    "solvers": 3,
    "stages": 3,
    "baselines": 3,
    "nehmo": 4,
    "factory": 4,
}


def test_planning_modules_are_short_and_layered() -> None:
    long = {
        _planning_module(p): n
        for p in PLANNING.rglob("*.py")
        if (n := len(p.read_text().splitlines())) > PLANNING_MAX_LINES
    }
    assert not long, f"planning modules over {PLANNING_MAX_LINES} lines: {long}"
    upward = []
    for path in PLANNING.rglob("*.py"):
        me = _planning_module(path).split(".")[0]
        if me == "__init__":
            continue
        for other in _planning_imports(path):
            top = other.split(".")[0]
            if top == me or top == "__init__":
                continue
            if PLANNING_LAYERS[top] > PLANNING_LAYERS[me] or (
                PLANNING_LAYERS[top] == PLANNING_LAYERS[me] and PLANNING_LAYERS[me] < 4
            ):
                upward.append(f"{_planning_module(path)} imports {other}")
    assert not upward, upward


TEST_MAX_LINES = 500


def test_test_files_mirror_the_packages_and_are_short() -> None:
    tests = ROOT / "tests"
    long = {
        str(p.relative_to(ROOT)): n
        for p in tests.rglob("*.py")
        if (n := len(p.read_text().splitlines())) > TEST_MAX_LINES
    }
    assert not long, f"test files over {TEST_MAX_LINES} lines: {long}"
    folders = {p.name for p in tests.iterdir() if p.is_dir() and p.name != "data"}
    packages = {p.name for p in CORE.iterdir() if (p / "__init__.py").exists()} | {"ros"}
    assert folders <= packages, f"test folders without a package: {sorted(folders - packages)}"


#: numbers at module level in the stages and Opt that are not tunables: a meaning, a tolerance
NOT_TUNABLE = {
    "opt/peer_bounds.py": {"FULL_SPEED"},  # the announcement of an arm that promises nothing
    "stages/self_clearance.py": {"MIN_GRADIENT"},  # a numerical floor of a row's gradient
    "opt/tick.py": {"NO_PEERS"},  # the (empty) peer values of a tick without constrained peers
}


def test_tunable_numbers_live_in_settings_groups() -> None:
    """A number a user might tune sits in a settings group (with its unit and rule), not as a
    module constant of a stage or of Opt."""
    found = []
    for sub in ("stages", "opt"):
        for path in sorted((PLANNING / sub).glob("*.py")):
            rel = f"{sub}/{path.name}"
            for node in ast.parse(path.read_text()).body:
                target = node.targets[0] if isinstance(node, ast.Assign) else None
                if isinstance(node, ast.AnnAssign):
                    target = node.target
                value = getattr(node, "value", None)
                if not isinstance(target, ast.Name) or value is None:
                    continue
                numbers = [n for n in ast.walk(value) if isinstance(n, ast.Constant)]
                numeric = numbers and all(
                    isinstance(n.value, int | float) and not isinstance(n.value, bool)
                    for n in numbers
                )
                if numeric and target.id not in NOT_TUNABLE.get(rel, set()):
                    found.append(f"{rel}:{node.lineno} {target.id}")
    assert not found, f"module constants that belong in a settings group: {found}"
