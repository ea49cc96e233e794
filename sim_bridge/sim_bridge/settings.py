"""The bridge's parameters (names, defaults, checks) and the episode they select."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from nehmo_core.errors import InvalidValueError, UnknownNameError
from nehmo_core.eval.setups import SUCCESS_NORMS
from nehmo_core.robots.loader import load_cell
from nehmo_core.robots.model import Cell
from nehmo_core.sim.actuators import ACTUATOR_MODELS
from nehmo_core.sim.scenario_files import load_scenario_set
from nehmo_core.sim.scenarios import Scenario, sample_scenario, scenario_rng
from nehmo_ros.node_support import Param

__all__ = ["DEFAULTS", "PARAMS", "BridgeSettings", "load_episode"]

PARAMS: dict[str, Param] = {
    "cell": Param("", "shipped cell name (dual_ur5, ...) or a cell YAML path"),
    "scenarios": Param("", "scenario set JSON file ('' = draw from seed/index)"),
    "episode": Param(0, "episode of the scenario set file"),
    "seed": Param(0, "seed of the drawn scenario set"),
    "index": Param(0, "scenario index within the seeded set"),
    "physics_rate": Param(100.0, "[Hz] simulation step rate"),
    "control_rate": Param(25.0, "[Hz] the planners' command rate (episode metadata)"),
    "sim_time": Param(False, "publish simulated time on /clock"),
    "real_time_factor": Param(1.0, "simulated seconds per wall second (with sim_time)"),
    "command_timeout": Param(0.2, "[s] watchdog: an arm with an older command holds still"),
    "command_validity": Param(
        0.06,
        "[s] a command drives its arm at most this long after it came (the planner checked it "
        "for one 40 ms period); then the arm holds still until the next one",
    ),
    "time_limit": Param(20.0, "[s] episode length"),
    "success_norm": Param("l2", "l2 | linf: the goal distance norm"),
    "success_tolerance": Param(0.1, "[rad] goal distance that counts as reached"),
    "stop_on_collision": Param(True, "end the episode at the first collision"),
    "stop_on_success": Param(True, "end the episode when every arm is at its goal"),
    "self_collision": Param(True, "check each arm's self-collision too"),
    "actuators": Param(
        "ideal",
        "ideal (q' = u) | realistic (acceleration limits, command latency, joint-state noise)",
    ),
    "wait_for_planners": Param(True, "start when every arm's command topic has a publisher"),
    "start_timeout": Param(60.0, "[s] longest wait for the planners"),
    "start_delay": Param(0.5, "[s] extra wait after the planners appear (discovery settles)"),
    "min_subscribers": Param(
        0, "with wait_for_planners: also wait until each joint-state topic has this many readers"
    ),
    "exit_when_done": Param(False, "exit 0.5 s after the episode ends"),
    "planners": Param(
        "", "row of planner kinds for the metadata, e.g. nehmo or ur5_0=nehmo,ur5_1=naive"
    ),
}
#: The parameters' defaults.
DEFAULTS: dict[str, Any] = {name: p.default for name, p in PARAMS.items()}


@dataclass(frozen=True)
class BridgeSettings:
    """Validated parameters of the bridge (times [s], rates [Hz], tolerance [rad])."""

    physics_rate: float
    control_rate: float
    sim_time: bool
    real_time_factor: float
    command_timeout: float
    time_limit: float
    success_norm: str
    success_tolerance: float
    stop_on_collision: bool
    stop_on_success: bool
    self_collision: bool
    wait_for_planners: bool
    start_timeout: float
    start_delay: float
    min_subscribers: int
    exit_when_done: bool
    actuators: str = "ideal"
    command_validity: float = math.inf

    def __post_init__(self) -> None:
        for name in ("physics_rate", "control_rate", "real_time_factor", "command_timeout"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise InvalidValueError(name, "must be a finite number > 0", value)
        if not self.command_validity > 0:
            raise InvalidValueError("command_validity", "must be > 0 [s]", self.command_validity)
        if not self.sim_time and self.real_time_factor != 1.0:
            raise InvalidValueError(
                "real_time_factor",
                "must be 1 without sim_time (the stamps are wall time; set sim_time:=true to run "
                "faster or slower than real time)",
                self.real_time_factor,
            )
        if self.physics_rate > 2000:
            raise InvalidValueError("physics_rate", "must be <= 2000 Hz", self.physics_rate)
        for name in ("time_limit", "success_tolerance", "start_timeout"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        if not self.start_delay >= 0:
            raise InvalidValueError("start_delay", "must be >= 0 [s]", self.start_delay)
        if self.min_subscribers < 0:
            raise InvalidValueError("min_subscribers", "must be >= 0", self.min_subscribers)
        if self.success_norm not in SUCCESS_NORMS:
            raise UnknownNameError("success_norm", self.success_norm, SUCCESS_NORMS)
        if self.actuators not in ACTUATOR_MODELS:
            raise UnknownNameError("actuators", self.actuators, ACTUATOR_MODELS)

    @property
    def dt_ns(self) -> int:
        """Simulated time of one physics step [ns]."""
        return round(1e9 / self.physics_rate)

    @property
    def substeps_per_tick(self) -> int:
        return max(1, round(self.physics_rate / self.control_rate))


def load_episode(cell: Cell, p: dict[str, Any]) -> tuple[Scenario, dict[str, Any]]:
    """The episode to run (from the scenario file, or drawn from ``seed``/``index``)."""
    if p["scenarios"]:
        scenario_set = load_scenario_set(p["scenarios"])
        # the set names its cell by shipped name or by YAML path: compare the cells themselves
        if load_cell(scenario_set.cell).name != cell.name:
            raise InvalidValueError(
                "scenarios", f"must be a scenario set of cell {cell.name!r}", scenario_set.cell
            )
        episode = int(p["episode"])
        if not 0 <= episode < len(scenario_set):
            raise InvalidValueError(
                "episode", f"must lie in [0, {len(scenario_set) - 1}] for {p['scenarios']}", episode
            )
        source = {
            "file": p["scenarios"],
            "episode": episode,
            "seed": scenario_set.seed,
            "index": scenario_set.indices[episode],
        }
        return scenario_set.scenarios[episode], source
    seed, index = int(p["seed"]), int(p["index"])
    if index < 0:
        raise InvalidValueError("index", "must be >= 0", index)
    scenario = sample_scenario(cell, scenario_rng(seed, index))
    return scenario, {"seed": seed, "index": index}
