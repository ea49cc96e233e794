"""Bad input at every door the user opens: one clear line each, no traceback, no pickles run.

Node parameters, cell YAML, scenario files and model files reach the nodes as parameters; the
command-line tools take log files. Every case runs the real entry point as a process (all of
them at once, to keep the wall time down) and expects exit status 2 (1 for ``recover``), one
line on stderr naming the parameter or file, the rule and the value, and no traceback.
(``tests/ros/test_nodes_params.py`` holds the plain parameter-value cases.)
"""

from __future__ import annotations

import json
import math
import os
import pickle
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from _ros_testutil import REPO, child_env

from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import save_scenario_set
from nehmo_core.sim.scenarios import generate_scenario_set

MODELS = REPO / "nehmo_core" / "nehmo_core" / "models"
MARKER = "pickle_code_ran"


class _Payload:
    """Unpickling this creates the marker file: proof that pickled code ran."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self) -> tuple[object, tuple[str, ...]]:
        return (os.system, (f"touch {self.marker}",))


def _model_dir(root: Path, name: str, pair: str = "ur5_ur5") -> Path:
    d = root / name
    d.mkdir()
    shutil.copy(MODELS / f"value_{pair}_bc_sym.safetensors", d / "model.safetensors")
    shutil.copy(MODELS / f"value_{pair}_bc_sym.json", d / "model.json")
    return d


def _sidecar(d: Path, **changes: object) -> None:
    meta = json.loads((d / "model.json").read_text())
    for key, value in changes.items():
        if value is None:
            del meta[key]
        else:
            meta[key] = value
    (d / "model.json").write_text(json.dumps(meta))


def _files(root: Path) -> None:
    """The bad files of every case under ``root``."""
    marker = root / MARKER
    (root / "broken.yaml").write_text("name: x\narms: [\n")
    (root / "weights.pt").write_bytes(pickle.dumps(_Payload(marker)))
    disguised = _model_dir(root, "disguised")
    (disguised / "model.safetensors").write_bytes(pickle.dumps(_Payload(marker)))
    _sidecar(_model_dir(root, "future"), format_version=99)
    _sidecar(_model_dir(root, "no_card"), system=None)
    _model_dir(root, "other_pair", "ur5_kinova")
    (root / "garbage.mcap").write_bytes(b"not an MCAP file" + bytes(range(200)))
    (root / "exists.mcap").write_bytes(b"keep me")
    save_scenario_set(generate_scenario_set(load_cell("triple_ur5"), 0, 1), root / "triple.json")
    dual = save_scenario_set(generate_scenario_set(load_cell("dual_ur5"), 0, 1), root / "dual.json")
    data = json.loads(dual.read_text())
    data["scenarios"][0]["goal"]["ur5_0"][2] = 7.0  # elbow limit ±π
    (root / "beyond.json").write_text(json.dumps(data))


@pytest.fixture(scope="module")
def root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("bad_input")
    _files(path)
    return path


# ------------------------------------------------------------ entry points, as processes
def _commands(root: Path) -> dict[str, tuple[list[str], str]]:
    """name → (argv after the interpreter, text the one error line must hold)."""
    planner = ["-m", "nehmo_ros.arm_planner", "--ros-args", "-p", "arm_id:=ur5_0"]
    recorder = ["-m", "nehmo_ros.recorder", "--ros-args", "-p", "cell:=dual_ur5"]
    return {
        "cell_yaml": ([*planner, "-p", f"cell:={root / 'broken.yaml'}"], "not valid YAML"),
        "pickle_model": (
            [*planner, "-p", "cell:=dual_ur5", "-p", f"model:={root / 'weights.pt'}"],
            "parameter `model`",
        ),
        "recorder_output": (
            [*recorder, "-p", "output:=/proc/no/such_bag"],
            "`output` must be a writable directory path",
        ),
        "evaluate_log": (
            ["-m", "nehmo_ros.orchestrate", "evaluate", str(root / "garbage.mcap")],
            "garbage.mcap: not a readable MCAP log",
        ),
        "recover_garbage": (
            ["-m", "nehmo_core.logs.recover", str(root / "garbage.mcap"), str(root / "o.mcap")],
            "holds no readable MCAP header",
        ),
        "recover_overwrite": (
            ["-m", "nehmo_core.logs.recover", str(root / "dual.json"), str(root / "exists.mcap")],
            "does not overwrite",
        ),
    }


@pytest.fixture(scope="module")
def results(root: Path) -> dict[str, tuple[int, str, str]]:
    commands = _commands(root)
    procs = {
        name: subprocess.Popen(
            [sys.executable, *argv],
            env=child_env(),
            cwd=root,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        for name, (argv, _) in commands.items()
    }
    out = {}
    for name, proc in procs.items():
        _, stderr = proc.communicate(timeout=300)
        out[name] = (proc.returncode, stderr, commands[name][1])
    return out


@pytest.mark.parametrize(
    "name",
    [
        "cell_yaml",
        "pickle_model",
        "recorder_output",
        "evaluate_log",
        "recover_garbage",
        "recover_overwrite",
    ],
)
def test_entry_points_print_one_clear_line(results: dict, name: str) -> None:
    code, stderr, expected = results[name]
    noise = ("pybullet build time", "RuntimeWarning: 'nehmo_core.logs.recover' found in")
    lines = [line for line in stderr.splitlines() if not any(n in line for n in noise)]
    assert code == (1 if name.startswith("recover") else 2), stderr
    assert len(lines) == 1, stderr
    assert "error:" in lines[0] and expected in lines[0], lines[0]
    assert "Traceback" not in stderr


# ------------------------------------------------ the same checks, in-process (the nodes
# print what these raise through node_support.run_main, tested above and in test_nodes_params)
@pytest.mark.parametrize(
    ("model", "expected"),
    [
        ("disguised", "cannot read weights file"),
        ("future", "format_version 99"),
        ("no_card", "malformed model file (KeyError: 'system')"),
        ("other_pair", "covers no pair of arm 'ur5_0'"),
    ],
    ids=["pickle_named_safetensors", "other_version", "malformed_card", "other_pair"],
)
def test_bad_model_files_name_the_model_parameter(root: Path, model: str, expected: str) -> None:
    from nehmo_core.errors import NehmoError
    from nehmo_core.planning.settings import PlannerSettings
    from nehmo_ros.planners import build_planner

    cell = load_cell("dual_ur5")
    with pytest.raises(NehmoError) as info:
        build_planner("nehmo", cell, "ur5_0", str(root / model), PlannerSettings())
    assert "`model`" in str(info.value) and expected in str(info.value)


@pytest.mark.parametrize(
    ("params", "expected"),
    [
        ({"scenarios": "triple.json"}, "`scenarios` must be a scenario set of cell 'dual_ur5'"),
        ({"scenarios": "beyond.json"}, "must respect joint limits"),
        ({"scenarios": "dual.json", "episode": 3}, "`episode` must lie in [0, 0]"),
    ],
    ids=["other_cell", "goal_beyond_limits", "episode"],
)
def test_bad_scenario_files_stop_the_bridge_with_the_reason(
    root: Path, params: dict, expected: str
) -> None:
    from nehmo_core.errors import NehmoError
    from sim_bridge.settings import DEFAULTS, load_episode

    p = {**DEFAULTS, **params, "scenarios": str(root / params["scenarios"])}
    with pytest.raises(NehmoError) as info:
        load_episode(load_cell("dual_ur5"), p)
    assert expected in str(info.value)


@pytest.mark.parametrize(
    ("changes", "expected"),
    [
        ({"jump_margin": -1.0}, "`jump_margin` must be > 0"),
        ({"opt": {"d_max": math.nan}}, "`opt.d_max` must be a number"),
        ({"opt": {"u_max": math.inf}}, "`opt.u_max` must lie in (0, inf)"),
    ],
)
def test_new_control_parameters_are_checked(changes: dict, expected: str) -> None:
    from nehmo_core.errors import InvalidValueError
    from nehmo_core.planning.settings import OptSettings
    from nehmo_ros.control import ControlSettings

    with pytest.raises(InvalidValueError) as info:
        if "opt" in changes:  # the speed bounds are the planner's: checked by its settings
            ControlSettings(opt=OptSettings(**changes["opt"]))
        else:
            ControlSettings(**changes)
    assert expected in str(info.value)


def test_loading_a_model_never_runs_pickled_code(root: Path, results: dict) -> None:
    from nehmo_core.errors import NehmoError
    from nehmo_core.planning.settings import PlannerSettings
    from nehmo_ros.planners import build_planner

    assert results["pickle_model"][0] == 2  # the node, given a pickle
    refusals = {  # the loader, given one under either name
        "disguised": "cannot read weights file",
        "weights.pt": "expected a run directory or a .safetensors file",
    }
    for model, refusal in refusals.items():
        with pytest.raises(NehmoError, match=refusal):
            build_planner(
                "nehmo", load_cell("dual_ur5"), "ur5_0", str(root / model), PlannerSettings()
            )
    assert not (root / MARKER).exists()


def test_recover_leaves_an_existing_output_alone(root: Path, results: dict) -> None:
    assert results["recover_overwrite"][0] == 1
    assert (root / "exists.mcap").read_bytes() == b"keep me"


def test_recorder_never_overwrites_a_log(tmp_path: Path) -> None:
    from nehmo_ros.recorder import free_path

    bag = tmp_path / "run"
    assert free_path(bag) == bag
    bag.mkdir()
    assert free_path(bag) == tmp_path / "run_1"
    (tmp_path / "run_1").mkdir()
    assert free_path(bag) == tmp_path / "run_2"
