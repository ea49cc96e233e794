"""Episodes of the node suite: start the nodes, wait for the bridge, evaluate the bags.

For every episode the ``recorder`` starts first (and is waited for until it records), then one
``arm_planner`` per arm and the ``sim_bridge`` (simulated time on ``/clock``). The bridge starts
the episode once every planner is up and exits when it ends; then planners and recorder get
SIGINT. Every episode bag is evaluated with :mod:`nehmo_core.eval.metrics` (the batch runner's
metrics) and the aggregate goes to ``<out>/summary.json``.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import time
from collections.abc import Sequence
from contextlib import suppress
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nehmo_core.errors import NehmoError
from nehmo_core.eval.metrics import EpisodeResult, aggregate, evaluate_log
from nehmo_core.eval.report import json_safe
from nehmo_core.eval.setups import parse_row
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import load_scenario_set
from nehmo_ros.processes import (
    Process,
    child_env,
    isolated_domain,
    node_command,
    reported_rmw,
    started_processes,
)
from nehmo_ros.suite_settings import SuiteSettings

__all__ = ["EpisodeRun", "format_metrics", "run_episode", "run_suite"]


@dataclass(frozen=True)
class EpisodeRun:
    """One orchestrated episode: its log, its evaluation and how the processes ended."""

    index: int
    log: Path
    result: EpisodeResult | None
    exit_codes: dict[str, int | None]
    wall_seconds: float
    error: str = ""
    rmw: str = ""  # the middleware the nodes reported at start


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
            raise NehmoError(f"the recorder did not start:\n{recorder.output()[-2000:]}")
        for arm_id, kind in kinds.items():
            params = {"arm_id": arm_id, "cell": cell_ref, "planner": kind, "model": settings.model}
            launch(
                f"planner_{arm_id}",
                node_command(
                    "nehmo_ros.arm_planner",
                    {**params, **sim},
                    ["-r", f"__node:=arm_planner_{arm_id}", *settings.extra_planner_args],
                    settings.install_space,
                ),
            )
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
                },
                install_space=settings.install_space,
            ),
        )
        budget = settings.startup_timeout + settings.time_limit / settings.real_time_factor + 30
        with suppress(subprocess.TimeoutExpired):
            bridge.proc.wait(budget)
        codes["sim_bridge"] = bridge.stop(settings.stop_timeout)
        for p in procs:
            if p is not bridge:
                codes[p.name] = p.stop(settings.stop_timeout)
        failed = {n: c for n, c in codes.items() if c != 0}
    wall = time.monotonic() - start
    rmw = reported_rmw(bridge.output())
    if failed:
        detail = "; ".join(f"{n}: exit {c}" for n, c in failed.items())
        return EpisodeRun(episode, log_path, None, codes, wall, f"processes failed ({detail})", rmw)
    try:
        result = evaluate_log(log_path)
    except NehmoError as exc:
        return EpisodeRun(episode, log_path, None, codes, wall, str(exc), rmw)
    return EpisodeRun(episode, log_path, result, codes, wall, rmw=rmw)


def run_suite(
    scenario_file: Path, episodes: Sequence[int], out_dir: Path, settings: SuiteSettings
) -> dict[str, Any]:
    """Run ``episodes`` of a scenario set; write and return the summary."""
    runs = []
    for episode in episodes:
        run = run_episode(scenario_file, episode, out_dir, settings)
        outcome = run.result.outcome if run.result else f"error: {run.error}"
        print(f"episode {episode}: {outcome} ({run.wall_seconds:.1f} s wall) -> {run.log}")
        runs.append(run)
    results = [r.result for r in runs if r.result is not None]
    summary = {
        "scenarios": str(scenario_file),
        "planner": settings.planner,
        "model": settings.model,
        "rmw": next((r.rmw for r in runs if r.rmw), ""),
        "metrics": aggregate(results).to_dict() if results else None,
        "episodes": [
            {
                "episode": r.index,
                "log": str(r.log),
                "outcome": r.result.outcome if r.result else None,
                "end_time": r.result.end_time if r.result else None,
                "path_length": r.result.path_length if r.result else None,
                "exit_codes": r.exit_codes,
                "wall_seconds": r.wall_seconds,
                "error": r.error,
            }
            for r in runs
        ],
    }
    (out_dir / "summary.json").write_text(json.dumps(json_safe(summary), indent=1) + "\n")
    return summary


def format_metrics(metrics: dict[str, Any] | None) -> str:
    """One line of the paper's metrics."""
    if metrics is None:
        return "no episode could be evaluated"
    pt, mpl = metrics["plan_time_ms"], metrics["mpl"]
    return (
        f"SR {metrics['sr']:.0f} %  CR {metrics.get('cr_inter_arm', metrics['cr']):.0f} %"
        f"  self {metrics.get('self_collision_rate', 0.0):.0f} %"
        f"  stuck {metrics['stuck_rate']:.0f} %"
        f"  plan time {pt['mean']:.2f} ± {pt['std']:.2f} ms  MPL {mpl['mean']:.2f} rad"
        f"  ({metrics['episodes']} episodes)"
    )
