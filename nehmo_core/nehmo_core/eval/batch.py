"""Batches of episodes over a process pool or a Ray cluster (:mod:`nehmo_core.cluster`): one
episode per task, one bag (log) per episode.

Each worker process keeps its simulators, value models (compiled once, cached on disk) and
decentralized planners between episodes; centralized planners plan each scenario anew. The
metrics of a row are computed from its logs (:func:`nehmo_core.eval.metrics.evaluate_log`) and
checked against the runner's in-memory results. An episode that raises, or whose log cannot be
read, stays in the row as an ``error`` with its reason (the traceback goes to stderr); the row
goes on.

Every finished episode leaves a record beside its bag (:mod:`nehmo_core.eval.records`). With
``resume=True`` an episode whose record matches this run (same setup, row, scenario, planner
settings and value models) and whose bag reads back is not run again; its result comes from
its bag as any other's.
"""

from __future__ import annotations

import dataclasses
import os
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from nehmo_core.cluster import ClusterSpec, make_executor, pack_folder, unpack_folder
from nehmo_core.eval import records
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.metrics import (
    EpisodeResult,
    RowMetrics,
    aggregate,
    evaluate_logs,
    failed_episode,
)
from nehmo_core.eval.planners import build_planners, unmodelled_peers
from nehmo_core.eval.setups import OPT_KINDS, get_setup, is_centralized, parse_row, row_slug
from nehmo_core.logs import remove_bag
from nehmo_core.planning.models.registry import ModelRegistry, ValueModelSource
from nehmo_core.planning.opt.interface import Planner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.sim.cell_sim import CellSimulator
from nehmo_core.sim.scenarios import Scenario, ScenarioSet

__all__ = ["BatchConfig", "RowRun", "init_worker", "run_rows"]


@dataclass(frozen=True)
class BatchConfig:
    """What every episode of a batch shares."""

    setup: str
    out_dir: Path
    value_models: tuple[ValueModelSource, ...] = ()
    backend: str = "auto"
    planner_settings: PlannerSettings = field(default_factory=PlannerSettings)
    episode_overrides: tuple[tuple[str, Any], ...] = ()  # EpisodeSettings fields to override

    def episode_settings(self) -> EpisodeSettings:
        return EpisodeSettings.for_setup(get_setup(self.setup), **dict(self.episode_overrides))


@dataclass(frozen=True)
class _Job:
    row: str
    position: int  # in the scenario set
    index: int  # the scenario's number (its seed)
    set_seed: int
    scenario: Scenario
    log_path: Path  # the episode's bag directory


@dataclass
class RowRun:
    """One row's episodes: results from the logs, the in-memory check and the wall time."""

    row: str
    kinds: dict[str, str]
    results: list[EpisodeResult]  # from the logs, in scenario order
    logs: list[Path]  # bag directories, in scenario order
    metrics: RowMetrics
    mismatches: list[int]  # positions whose log result differs from the in-memory one
    wall_seconds: float
    episode_seconds: list[float]
    value_models: dict[str, Any]
    unmodelled_peers: dict[str, list[str]]  # per Opt arm: peers in reach it does not constrain
    epsilon: dict[str, str] = field(default_factory=dict)  # per Opt arm: its ε and whence


# -- worker side ---------------------------------------------------------------------------------
_STATE: dict[str, Any] = {}


def init_worker() -> None:
    """A pool worker's start: one torch/OpenMP thread (the pool runs one worker per core)."""
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import torch

    torch.set_num_threads(1)


def _registry(config: BatchConfig) -> ModelRegistry:
    key = (config.value_models, config.backend)
    if _STATE.get("registry_key") != key:
        _STATE["registry_key"] = key
        _STATE["registry"] = ModelRegistry(config.value_models, config.backend)
        _STATE["planners"] = {}
    registry: ModelRegistry = _STATE["registry"]
    return registry


def _simulator(cell_name: str, settings: EpisodeSettings) -> CellSimulator:
    sims: dict[tuple[str, int, bool, str], CellSimulator] = _STATE.setdefault("sims", {})
    key = (cell_name, settings.substeps, settings.self_collision, settings.actuators)
    if key not in sims:
        sims[key] = CellSimulator(
            load_cell(cell_name), settings.substeps, settings.self_collision, settings.actuators
        )
    return sims[key]


def _run_job(config: BatchConfig, job: _Job) -> tuple[int, EpisodeResult, float, dict[str, Any]]:
    """One episode in a worker; an exception becomes an ``error`` result with its reason."""
    start = time.perf_counter()
    try:
        return _episode(config, job, start)
    except Exception as exc:
        failed = failed_episode(f"episode {job.index} of row {job.row!r}", exc)
        used: dict[str, Any] = {"value_models": {}, "unmodelled_peers": {}, "epsilon": {}}
        return job.position, failed, time.perf_counter() - start, used


def _episode(
    config: BatchConfig, job: _Job, start: float
) -> tuple[int, EpisodeResult, float, dict[str, Any]]:
    setup = get_setup(config.setup)
    cell = load_cell(setup.cell)
    settings = config.episode_settings()
    kinds = parse_row(job.row, cell)
    registry = _registry(config)
    cache: dict[str, Planner] = _STATE["planners"].setdefault((setup.name, job.row), {})
    planners = build_planners(
        cell,
        kinds,
        job.scenario,
        1.0 / settings.rate,
        registry,
        config.planner_settings,
        None if is_centralized(kinds) else cache,
        allow_unmodelled=setup.unmodelled_peers_ok,
    )
    models = {k: registry.described.get(k, []) for k in set(kinds.values()) if k in OPT_KINDS}
    unmodelled = unmodelled_peers(planners)
    epsilon = {a: p.epsilon_source for a, p in planners.items() if p.epsilon_source}
    metadata = {
        "setup": setup.name,
        "row": job.row,
        "scenario_set": {"seed": job.set_seed, "index": job.index, "position": job.position},
        "value_models": models,
        "unmodelled_peers": unmodelled,
        "epsilon": epsilon,
        "planner_settings": config.planner_settings.to_dict(),
    }
    remove_bag(job.log_path)  # an earlier run's bag of this episode
    result = run_episode(
        cell,
        job.scenario,
        planners,
        settings,
        kinds=kinds,
        timed_arms=setup.timed_arms or cell.arm_ids,
        simulator=_simulator(setup.cell, settings),
        log_path=job.log_path,
        metadata=metadata,
    )
    used = {"value_models": models, "unmodelled_peers": unmodelled, "epsilon": epsilon}
    return job.position, result, time.perf_counter() - start, used


def _run_job_shipped(
    config: BatchConfig, job: _Job
) -> tuple[int, EpisodeResult, float, dict[str, Any], dict[str, bytes]]:
    """:func:`_run_job` on a cluster node: the bag is written to a folder of the node's own and
    returned with the result, so the node needs no access to the driver's output folder."""
    with tempfile.TemporaryDirectory(prefix="nehmo-episode-") as tmp:
        local = dataclasses.replace(job, log_path=Path(tmp) / job.log_path.name)
        position, result, wall, used = _run_job(config, local)
        return position, result, wall, used, pack_folder(local.log_path)


# -- driver side ---------------------------------------------------------------------------------
def _fingerprint(config: BatchConfig, job: _Job) -> str:
    """What makes an episode the same episode: a resumed run reuses a bag only on a match."""
    return records.fingerprint(
        setup=config.setup,
        row=job.row,
        set_seed=job.set_seed,
        index=job.index,
        scenario=repr(job.scenario),
        planner_settings=config.planner_settings.to_dict(),
        value_models=[str(v) for v in config.value_models],
        backend=config.backend,
        episode=config.episode_settings().to_dict(),
    )


def _finished(
    config: BatchConfig, job: _Job
) -> tuple[int, EpisodeResult, float, dict[str, Any]] | None:
    """A finished episode of an earlier run of this very job (record and readable bag)."""
    found = records.read_finished(job.log_path, _fingerprint(config, job))
    return None if found is None else (job.position, *found)


def _jobs(config: BatchConfig, row: str, scenarios: ScenarioSet) -> list[_Job]:
    logs = config.out_dir / "logs" / row_slug(row)
    return [
        _Job(row, k, index, scenarios.seed, sc, logs / f"episode_{index:04d}")
        for k, (index, sc) in enumerate(zip(scenarios.indices, scenarios.scenarios, strict=True))
    ]


def run_rows(
    config: BatchConfig,
    rows: Sequence[str],
    scenarios: ScenarioSet,
    workers: int = 1,
    progress: bool = True,
    on_row: Callable[[RowRun], None] | None = None,
    cluster: ClusterSpec | None = None,
    resume: bool = False,
) -> list[RowRun]:
    """Run every row on every scenario; rows one after the other, episodes in parallel (over
    ``workers`` local processes, or as Ray tasks when ``cluster`` is Ray). With ``resume``,
    episodes an earlier run of the same jobs finished are read from their bags, not rerun."""
    from tqdm import tqdm

    cell = load_cell(get_setup(config.setup).cell)
    kinds_of = {row: parse_row(row, cell) for row in rows}  # fail early on a bad row
    cluster = cluster or ClusterSpec("local")
    executor = make_executor(workers, cluster, init_worker)
    runs = []
    try:
        for row in rows:
            jobs = _jobs(config, row, scenarios)
            start = time.perf_counter()
            memory: dict[int, EpisodeResult] = {}
            seconds: dict[int, float] = {}
            models: dict[str, Any] = {}
            unmodelled: dict[str, list[str]] = {}
            epsilon: dict[str, str] = {}
            done = [_finished(config, job) if resume else None for job in jobs]
            todo = [job for job, d in zip(jobs, done, strict=True) if d is None]
            for job in todo:  # an earlier record must not vouch for a bag being rewritten
                records.forget(job.log_path)
            with tqdm(total=len(jobs), desc=f"{config.setup} {row}", disable=not progress) as bar:
                earlier = [d for d in done if d is not None]  # finished by an earlier run
                fresh = _outputs(config, todo, executor, cluster)
                for is_new, (position, result, wall, used) in _chain(earlier, fresh):
                    if is_new and result.outcome != "error":
                        job = jobs[position]
                        records.write_record(job.log_path, _fingerprint(config, job), wall, used)
                    memory[position], seconds[position] = result, wall
                    models.update(used["value_models"])
                    unmodelled.update(used["unmodelled_peers"])
                    epsilon.update(used["epsilon"])
                    bar.update(1)
                    bar.set_postfix_str(_postfix(memory.values()))
            logs = [job.log_path for job in jobs]
            # every result is read back from its bag (on the workers when they are local)
            known = [memory[k] for k in range(len(logs))]
            from_logs = evaluate_logs(logs, kinds_of[row], executor, known)
            mismatches = [
                k
                for k, r in enumerate(from_logs)
                if r != memory[k] and memory[k].outcome != "error"
            ]
            run = RowRun(
                row=row,
                kinds=kinds_of[row],
                results=from_logs,
                logs=logs,
                metrics=aggregate(from_logs),
                mismatches=mismatches,
                wall_seconds=time.perf_counter() - start,
                episode_seconds=[seconds[k] for k in range(len(jobs))],
                value_models=models,
                unmodelled_peers=unmodelled,
                epsilon=epsilon,
            )
            runs.append(run)
            if on_row is not None:
                on_row(run)
    finally:
        if executor is not None:
            executor.shutdown(cancel_futures=True)
    return runs


def _chain(earlier: list[Any], fresh: Any) -> Any:
    """``(False, output)`` for each earlier run's output, then ``(True, output)`` as new ones
    come."""
    for output in earlier:
        yield False, output
    for output in fresh:
        yield True, output


def _outputs(config: BatchConfig, jobs: Sequence[_Job], executor: Any, cluster: ClusterSpec) -> Any:
    """``(position, result, wall, used)`` of each job as it finishes; on a cluster the bag
    comes back with the result and is written here, where a local run writes it."""
    if executor is None:
        yield from (_run_job(config, job) for job in jobs)
        return
    if not cluster.is_ray:
        futures = [executor.submit(_run_job, config, job) for job in jobs]
        yield from (f.result() for f in as_completed(futures))
        return
    shipped = {executor.submit(_run_job_shipped, config, job): job for job in jobs}
    for future in as_completed(shipped):
        position, result, wall, used, files = future.result()
        unpack_folder(files, shipped[future].log_path)
        yield position, result, wall, used


def _postfix(results: Any) -> str:
    """SR, the paper's CR (between arms) and self-collisions so far."""
    outcomes = [r.outcome for r in results]
    kinds = [r.collision_kind for r in results]
    n = len(outcomes) or 1
    return (
        f"SR {100 * outcomes.count('success') / n:.0f}% "
        f"CR {100 * kinds.count('inter-arm') / n:.0f}% self {100 * kinds.count('self') / n:.0f}%"
    )
