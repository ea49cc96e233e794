"""Episodes of the node suite: start the nodes, wait for the bridge, evaluate the bags.

For every episode the ``recorder`` starts first (and is waited for until it records), then one
``arm_planner`` per arm and the ``sim_bridge`` (simulated time on ``/clock``). The bridge starts
the episode once every planner is up and exits when it ends; then planners and recorder get
SIGINT. Every episode bag is evaluated with :mod:`nehmo_core.eval.metrics` (the batch runner's
metrics) and the aggregate goes to ``<out>/summary.json``.

Every episode that was started counts: one whose processes failed (a node that exits before the
episode ends, or not with status 0) or whose bag cannot be read is an ``error`` with its reason,
in the summary's metrics and on the terminal. A node that exits early (a configuration error at
start-up, a crash) stops the episode at once, and its own error line becomes the reason.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nehmo_core.eval.metrics import (
    EpisodeResult,
    aggregate,
    evaluate_or_error,
    format_metrics,
)
from nehmo_core.eval.report import json_safe
from nehmo_core.eval.setups import parse_row
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import load_scenario_set
from nehmo_ros.processes import (
    Process,
    child_env,
    isolated_domain,
    node_command,
    planner_node_name,
    reported_rmw,
    started_processes,
)
from nehmo_ros.suite_settings import SuiteSettings

__all__ = [
    "EpisodeRun",
    "error_line",
    "format_metrics",
    "planner_commands",
    "run_episode",
    "run_suite",
]

#: [s] between checks of the episode's processes
POLL = 0.1


@dataclass(frozen=True)
class EpisodeRun:
    """One orchestrated episode: its log, its evaluation (an ``error`` result when the
    processes failed or the bag cannot be read) and how the processes ended."""

    index: int
    log: Path
    result: EpisodeResult
    exit_codes: dict[str, int | None]
    wall_seconds: float
    rmw: str = ""  # the middleware the nodes reported at start

    @property
    def error(self) -> str:
        return self.result.error


def error_line(output: str) -> str:
    """A node's own reason for failing, from its output: its ``<node>: error: ...`` line, else
    the last line of a traceback, else its last line."""
    lines = [ln.strip() for ln in output.splitlines() if ln.strip()]
    for line in reversed(lines):
        if ": error: " in line:
            return line
    if any(ln.startswith("Traceback") for ln in lines):
        for line in reversed(lines):
            if not line.startswith(("File ", "^", "~")) and ":" in line:
                return line
    return lines[-1] if lines else "no output"


def _watch(procs: Sequence[Process], bridge: Process, budget: float) -> Process | None:
    """Wait until the bridge exits (the episode ended) or ``budget`` s pass; the first other
    process that exits before the bridge, if any (the episode is then over)."""
    end = time.monotonic() + budget
    while time.monotonic() < end and bridge.proc.poll() is None:
        for p in procs:
            if p is not bridge and p.proc.poll() is not None:
                return p
        time.sleep(POLL)
    return None


def planner_commands(
    kinds: dict[str, str], cell_ref: str, settings: SuiteSettings
) -> list[tuple[str, list[str]]]:
    """``(process name, argv)`` of the planner processes: one ``arm_planner`` per arm, or with
    ``planner_processes`` k the arms dealt in order to k ``arm_planners`` groups. Every node
    is named ``arm_planner_<id>`` and starts unconfigured (the lifecycle manager brings it up)."""
    common = {"cell": cell_ref, "model": settings.model, "use_sim_time": True, "autostart": False}
    extra = list(settings.extra_planner_args)
    ids = list(kinds)
    if not settings.planner_processes:
        return [
            (
                f"planner_{a}",
                node_command(
                    "nehmo_ros.arm_planner",
                    {"arm_id": a, "planner": kinds[a], **common},
                    ["-r", f"__node:={planner_node_name(a)}", *extra],
                    settings.install_space,
                ),
            )
            for a in ids
        ]
    k = min(settings.planner_processes, len(ids))
    size = -(-len(ids) // k)
    chunks = [ids[i : i + size] for i in range(0, len(ids), size)]
    return [
        (
            f"planners_{i}",
            node_command(
                "nehmo_ros.planner_group",
                {
                    "arm_ids": "[" + ",".join(chunk) + "]",
                    "planners": "/".join(kinds[a] for a in chunk),
                    **common,
                },
                extra,
                settings.install_space,
            ),
        )
        for i, chunk in enumerate(chunks)
    ]


def run_episode(
    scenario_file: Path,
    episode: int,
    out_dir: Path,
    settings: SuiteSettings,
) -> EpisodeRun:
    """Run one episode of ``scenario_file`` through the node suite; evaluate its log."""
    scenarios = load_scenario_set(scenario_file)
    cell = load_cell(scenarios.cell)
    cell_ref = scenarios.cell  # a shipped name or a cell YAML path: what every node loads
    kinds = parse_row(settings.planner, cell)
    domain_id = settings.domain_id if settings.domain_id is not None else isolated_domain()
    env = child_env(settings, domain_id)
    stem = f"episode_{episode:03d}"
    log_path = out_dir / stem
    logs = out_dir / "logs" / stem
    logs.mkdir(parents=True, exist_ok=True)
    if log_path.is_dir():
        shutil.rmtree(log_path)
    sim = {"use_sim_time": True}
    start = time.monotonic()
    codes: dict[str, int | None] = {}
    with started_processes() as procs:
        commands: dict[str, list[str]] = {}

        def launch(name: str, argv: list[str]) -> Process:
            commands[name] = argv
            (logs / "commands.json").write_text(json.dumps(commands, indent=1) + "\n")
            nice = settings.nice + (settings.recorder_nice if name == "recorder" else 0)
            procs.append(Process(name, argv, env, logs / f"{name}.log", nice))
            return procs[-1]

        recorder = launch(
            "recorder",
            node_command(
                "nehmo_ros.recorder",
                {"cell": cell_ref, "output": str(log_path), **sim},
                install_space=settings.install_space,
            ),
        )
        if not recorder.wait_for("recording", settings.startup_timeout):
            wall = time.monotonic() - start
            reason = f"the recorder did not start: {error_line(recorder.output())}"
            codes["recorder"] = recorder.stop(settings.stop_timeout)
            return EpisodeRun(episode, log_path, EpisodeResult.failed(reason, kinds), codes, wall)
        for name, argv in planner_commands(kinds, cell_ref, settings):
            launch(name, argv)
        # the planners start unconfigured; the lifecycle manager configures, then activates them
        manager_argv = node_command(
            "nehmo_ros.lifecycle_manager",
            {
                "node_names": [planner_node_name(a) for a in kinds],
                "timeout": settings.startup_timeout,
            },
            install_space=settings.install_space,
        )
        commands["lifecycle_manager"] = manager_argv
        manager = Process("lifecycle_manager", manager_argv, env, logs / "lifecycle_manager.log", 0)
        try:
            manager_code: int | None = manager.proc.wait(settings.startup_timeout * 2 + 30)
        except subprocess.TimeoutExpired:
            manager_code = manager.stop(settings.stop_timeout)
        if manager_code != 0:
            reason = f"the planners did not come up: {error_line(manager.output())}"
            for p in procs:  # the planner's own reason
                said = [ln for ln in p.output().splitlines() if "configure failed: " in ln]
                if said:
                    reason += f"; {p.name}: {said[-1].split('configure failed: ', 1)[1]}"
            for p in procs:
                codes[p.name] = p.stop(settings.stop_timeout)
            wall = time.monotonic() - start
            return EpisodeRun(episode, log_path, EpisodeResult.failed(reason, kinds), codes, wall)
        bridge = launch(
            "sim_bridge",
            node_command(
                "sim_bridge.bridge",
                {
                    "cell": cell_ref,
                    "scenarios": str(scenario_file),
                    "episode": episode,
                    "sim_time": True,
                    "exit_when_done": True,
                    "time_limit": settings.time_limit,
                    "physics_rate": settings.physics_rate,
                    "real_time_factor": settings.real_time_factor,
                    "start_timeout": settings.startup_timeout,
                    "planners": settings.planner,
                    "min_subscribers": len(kinds) + 1,  # every planner and the recorder
                    **dict(settings.bridge_params),
                },
                install_space=settings.install_space,
            ),
        )
        budget = settings.startup_timeout + settings.time_limit / settings.real_time_factor + 30
        early = _watch(procs, bridge, budget)
        reasons = []
        if early is not None:
            reasons.append(
                f"{early.name} exited with status {early.proc.returncode} before the episode "
                f"ended: {error_line(early.output())}"
            )
        elif bridge.proc.poll() is None:
            reasons.append(f"the episode did not end within {budget:.0f} s of wall time")
        codes["sim_bridge"] = bridge.stop(settings.stop_timeout)
        for p in procs:
            if p is not bridge:
                codes[p.name] = p.stop(settings.stop_timeout)
        for p in procs:
            if p is not early and codes[p.name] != 0:
                status = "killed" if codes[p.name] is None else f"exit {codes[p.name]}"
                reasons.append(f"{p.name}: {status}: {error_line(p.output())}")
    wall = time.monotonic() - start
    rmw = reported_rmw(bridge.output())
    if reasons:
        result = EpisodeResult.failed("; ".join(reasons), kinds)
    else:
        result = evaluate_or_error(log_path, kinds)
    return EpisodeRun(episode, log_path, result, codes, wall, rmw)


def run_suite(
    scenario_file: Path, episodes: Sequence[int], out_dir: Path, settings: SuiteSettings
) -> dict[str, Any]:
    """Run ``episodes`` of a scenario set; write and return the summary."""
    runs = []
    for episode in episodes:
        run = run_episode(scenario_file, episode, out_dir, settings)
        outcome = run.result.outcome
        if outcome == "error":
            outcome = f"error: {run.error}"
        ignored = run.result.malformed
        if ignored:
            listed = ", ".join(f"{t}: {n:,}" for t, n in ignored.items())
            outcome += f" (malformed messages ignored: {listed})"
        print(f"episode {episode}: {outcome} ({run.wall_seconds:.1f} s wall) -> {run.log}")
        runs.append(run)
    summary = {
        "scenarios": str(scenario_file),
        "planner": settings.planner,
        "model": settings.model,
        "rmw": next((r.rmw for r in runs if r.rmw), ""),
        "metrics": aggregate([r.result for r in runs]).to_dict(),
        "episodes": [
            {
                "episode": r.index,
                "log": str(r.log),
                "outcome": r.result.outcome,
                "end_time": r.result.end_time if r.result.outcome != "error" else None,
                "path_length": r.result.path_length if r.result.outcome != "error" else None,
                "exit_codes": r.exit_codes,
                "wall_seconds": r.wall_seconds,
                "error": r.error,
                "malformed_messages": r.result.malformed,
                "malformed_reasons": r.result.malformed_reasons,
            }
            for r in runs
        ],
    }
    (out_dir / "summary.json").write_text(json.dumps(json_safe(summary), indent=1) + "\n")
    return summary
