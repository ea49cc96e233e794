"""How the node suite runs: :class:`SuiteSettings`, checked before any process starts."""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from nehmo_core.errors import InvalidValueError, UnknownNameError

__all__ = ["SuiteSettings", "check_row_and_model", "layout_hint"]


@dataclass(frozen=True)
class SuiteSettings:
    """How the suite is run (times [s], rates [Hz])."""

    planner: str = "nehmo"  # a row: one kind, or one per arm joined by '/'
    model: str = "shipped"
    time_limit: float = 20.0
    physics_rate: float = 100.0
    real_time_factor: float = 1.0
    domain_id: int | None = None
    startup_timeout: float = 60.0  # [s] for the recorder and the planners to come up
    stop_timeout: float = 10.0  # [s] after SIGINT before SIGKILL
    nice: int = 0  # added niceness of the children
    #: Added niceness of the recorder on top of ``nice``: the planners and the bridge come first
    #: when the CPUs are busy; the recorder's deep reader history absorbs its delays.
    recorder_nice: int = 10
    extra_planner_args: tuple[str, ...] = ()
    #: ``sim_bridge`` parameters set on top of the suite's (e.g. ``command_validity``).
    bridge_params: tuple[tuple[str, object], ...] = ()
    #: Processes the planners run in: 0, one ``arm_planner`` per arm; k > 0, the arms dealt in
    #: order to at most k ``arm_planners`` processes (several nodes per process, composition).
    planner_processes: int = 0
    env: dict[str, str] = field(default_factory=dict)
    #: A colcon install space (``ros_ws/install``): the nodes then run as its executables after
    #: sourcing its ``setup.bash``, as a ROS user runs them; '' runs ``python -m <module>``.
    install_space: str = ""

    def __post_init__(self) -> None:
        if not 0 <= self.recorder_nice <= 19:
            raise InvalidValueError("recorder_nice", "must lie in [0, 19]", self.recorder_nice)
        for name in ("time_limit", "physics_rate", "real_time_factor", "startup_timeout"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        if self.planner_processes < 0:
            rule = "must be >= 0 (0: one process per arm)"
            raise InvalidValueError("planner_processes", rule, self.planner_processes)
        if self.domain_id is not None and not 0 <= self.domain_id <= 232:
            raise InvalidValueError("domain_id", "must lie in [0, 232]", self.domain_id)
        check_row_and_model(self.planner, self.model)
        from sim_bridge.settings import PARAMS as BRIDGE_PARAMS

        unknown = sorted({k for k, _ in self.bridge_params} - set(BRIDGE_PARAMS))
        if unknown:
            rule = f"must name sim_bridge parameters {sorted(BRIDGE_PARAMS)}"
            raise InvalidValueError("bridge_params", rule, unknown)
        # ROS reads `50` as an integer, which a float parameter refuses: 50.0 is meant
        floats = {k for k, p in BRIDGE_PARAMS.items() if isinstance(p.default, float)}
        params = tuple(
            (k, float(v) if k in floats and type(v) is int else v) for k, v in self.bridge_params
        )
        object.__setattr__(self, "bridge_params", params)
        if self.install_space and not (Path(self.install_space) / "setup.bash").is_file():
            raise InvalidValueError(
                "install_space",
                "must be a colcon install space (with setup.bash)",
                self.install_space,
            )


def check_row_and_model(planner: str, model: str) -> None:
    """What every ``arm_planner`` would reject, checked before any process starts: each kind
    of the row (one, or one per arm joined by '/') and each source of ``model``."""
    from nehmo_core.hjr.model_files import SHIPPED_VALUE_FUNCTIONS
    from nehmo_core.planning.factory import DECENTRALIZED
    from nehmo_core.planning.models.registry import SYNTHETIC, model_sources

    for kind in planner.split("/"):
        if kind not in DECENTRALIZED:
            raise UnknownNameError("planner", kind, DECENTRALIZED)
    for source in model_sources(model):
        known = source.source in SHIPPED_VALUE_FUNCTIONS or source.source == SYNTHETIC
        if not known and not Path(source.source).exists():
            raise InvalidValueError(
                "model",
                "must be 'shipped', 'synthetic', a shipped pair "
                f"{sorted(SHIPPED_VALUE_FUNCTIONS)} or an existing path, per [KIND=]SOURCE item",
                str(source),
            )


def layout_hint(arms: int, settings: SuiteSettings, cores: int | None = None) -> str:
    """A note for a run whose layout was measured to miss many 25 Hz periods at real time, ''
    otherwise: more than three arms per core, planned in more processes than cores or with the
    bridge stepping faster than 50 Hz (eight arms on 2 cores: ``docs/ros2.md``, several planners
    in one process)."""
    cores = cores or os.cpu_count() or 1
    processes = arms if settings.planner_processes == 0 else min(settings.planner_processes, arms)
    if arms <= 3 * cores or (processes <= cores and settings.physics_rate <= 50):
        return ""
    return (
        f"{arms} arms in {processes} planner process{'es' if processes > 1 else ''} with "
        f"{settings.physics_rate:g} Hz physics on {cores} core{'s' if cores > 1 else ''} miss "
        f"many 25 Hz periods at real time; --planner-processes {cores} --physics-rate 50 keeps "
        "most (docs/ros2.md, several planners in one process)"
    )
