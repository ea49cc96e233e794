"""Run planner rows on a directory of Ha et al.'s task files (``nehmo evaluate --tasks DIR``).

Every task is its own cell (random base poses and yaws, one to four UR5s), so each episode
builds its planners for that cell; value models are loaded once per worker (the registry caches
them, and the UR5 pairs at any base distance use the pose-conditioned ``ur5_ur5_any``). Success
follows our rule (every arm within 0.1 rad, joint-space L2 norm, of its goal at once, within the
time limit, no collision); the episodes last :data:`TIME_LIMIT` s like theirs. Tasks with
obstacles, and tasks with a pair of arms in reach of each other that no loaded value model
covers (for any Opt row asked for), are listed with the reason and skipped by every row: they
count in no row's denominator and never as a success, and the other tasks run.

A task whose episode raises or whose log cannot be read stays in its row as an ``error``
(a failure with its reason); the row goes on. ``OUT/summary.json`` keeps the setups' row
schema (``rows[].row``, ``rows[].ours`` …) and adds ``rows[].by_arms``: the same metrics per
arm count.
"""

from __future__ import annotations

import dataclasses
import gc
import platform
import tempfile
import time
from collections.abc import Callable, Sequence
from concurrent.futures import as_completed
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from nehmo_core.cluster import ClusterSpec, make_executor, pack_folder, unpack_folder
from nehmo_core.eval import records
from nehmo_core.eval.batch import init_worker
from nehmo_core.eval.episode import EpisodeSettings, run_episode
from nehmo_core.eval.episode_log import cell_metadata
from nehmo_core.eval.ha_tasks import HaTask, check_joint_convention, pair_distances
from nehmo_core.eval.metrics import (
    EpisodeResult,
    aggregate,
    evaluate_logs,
    failed_episode,
)
from nehmo_core.eval.planners import build_planners, unmodelled_peers
from nehmo_core.eval.report import error_notes, json_safe
from nehmo_core.eval.setups import OPT_KINDS, parse_row, row_slug
from nehmo_core.logs import remove_bag
from nehmo_core.planning.models.pair_frame import constrained_pairs
from nehmo_core.planning.models.registry import ModelRegistry, ValueModelSource
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.sim.cell_sim import CellSimulator

__all__ = ["PUBLISHED", "TIME_LIMIT", "TaskConfig", "run_tasks", "task_summary"]

TIME_LIMIT = 20.0
"""[s] per episode, as Ha et al.'s episodes."""
PUBLISHED: dict[str, dict[str, str]] = {
    "ha2020": {
        "label": "Ha et al. (decentralized RL)",
        "source": "Ha, Xu, Song, 'Learning a Decentralized Multi-arm Motion Planner', CoRL 2020, "
        "abstract: >90 % success for a 10-arm system; per-arm-count rates on its 48 shared "
        "tasks are not in our references",
    },
    "dgmap": {
        "label": "DG-MAP (diffusion + conflict search)",
        "source": "Parimi & Williams, CoRL 2025, Tables 1-2, on tasks of Ha et al.'s protocol: "
        "average success 0.975 / 0.968 / 0.945 / 0.928 / 0.926 / 0.924 with 3-8 arms",
    },
}


def _is_generated(task_id: str) -> bool:
    """A task of ``nehmo tasks generate`` (named ``gen_<n>arm_s<seed>_<k>``)."""
    return task_id.startswith("gen_")


@dataclass(frozen=True)
class TaskConfig:
    """What every episode of a task run shares."""

    out_dir: Path
    value_models: tuple[ValueModelSource, ...] = ()
    backend: str = "auto"
    planner_settings: PlannerSettings = field(default_factory=PlannerSettings)
    episode: EpisodeSettings = field(default_factory=lambda: EpisodeSettings(time_limit=TIME_LIMIT))


_STATE: dict[str, Any] = {}


def _registry(config: TaskConfig) -> ModelRegistry:
    key = (config.value_models, config.backend)
    if _STATE.get("key") != key:
        _STATE["key"] = key
        _STATE["registry"] = ModelRegistry(config.value_models, config.backend)
    registry: ModelRegistry = _STATE["registry"]
    return registry


def _log_path(config: TaskConfig, row: str, task: HaTask) -> Path:
    return config.out_dir / "logs" / row_slug(row) / f"task_{task.task_id}"


def _run(config: TaskConfig, row: str, task: HaTask) -> tuple[EpisodeResult, dict[str, Any]]:
    """One task's episode in a worker; an exception becomes an ``error`` result."""
    try:
        return _episode(config, row, task)
    except Exception as exc:
        failed = failed_episode(f"task {task.task_id} of row {row!r}", exc)
        return failed, {"value_models": {}, "unmodelled_peers": {}}
    finally:
        # the earlier task's planners and simulator are reference cycles holding torch and
        # PyBullet state: left to the collector's own pace, a worker grew to 8 GB over 300
        # generated tasks; collected after every task it stays near 1 GB
        gc.collect()


def _run_shipped(
    config: TaskConfig, row: str, task: HaTask
) -> tuple[EpisodeResult, dict[str, Any], dict[str, bytes]]:
    """:func:`_run` on a cluster node: the bag goes to a folder of the node's own and comes
    back with the result."""
    with tempfile.TemporaryDirectory(prefix="nehmo-task-") as tmp:
        local = dataclasses.replace(config, out_dir=Path(tmp))
        result, used = _run(local, row, task)
        return result, used, pack_folder(_log_path(local, row, task))


def _episode(config: TaskConfig, row: str, task: HaTask) -> tuple[EpisodeResult, dict[str, Any]]:
    cell, settings = task.cell, config.episode
    kinds = parse_row(row, cell)
    registry = _registry(config)
    planners = build_planners(
        cell, kinds, task.scenario, 1.0 / settings.rate, registry, config.planner_settings
    )
    # the last task's planners are let go only now: the shared worlds both use (a robot's own
    # world for self-clearance, ~0.5 s to build) stay open from one task to the next
    _STATE["planners"] = planners
    used = {
        "value_models": {
            k: registry.described.get(k, []) for k in set(kinds.values()) if k in OPT_KINDS
        },
        "unmodelled_peers": unmodelled_peers(planners),
        "epsilon": {a: p.epsilon_source for a, p in planners.items() if p.epsilon_source},
    }
    log_path = _log_path(config, row, task)
    remove_bag(log_path)
    with CellSimulator(cell, settings.substeps, settings.self_collision, settings.actuators) as sim:
        result = run_episode(
            cell,
            task.scenario,
            planners,
            settings,
            kinds=kinds,
            simulator=sim,
            log_path=log_path,
            metadata={"task": task.task_id, "task_file": str(task.path), "row": row, **used},
        )
    return result, used


def _uncovered(task: HaTask, config: TaskConfig, rows: Sequence[str]) -> str | None:
    """Why an Opt row cannot plan ``task`` (a pair in reach that no loaded model fits), or
    None. Every row then skips the task, so the rows compare on one task set."""
    registry = _registry(config)
    cell, margin = task.cell, config.planner_settings.opt.reach_margin
    kinds = {k for row in rows for k in parse_row(row, cell).values() if k in OPT_KINDS}
    for kind in sorted(kinds):
        geometry = [m.geometry for m in registry.models_for(kind, cell)]
        for arm in cell.arm_ids:
            uncovered = constrained_pairs(cell, arm, geometry, margin)[2]
            if uncovered:
                peer = uncovered[0]
                gap = np.linalg.norm(np.subtract(cell.arm(peer).base.xyz, cell.arm(arm).base.xyz))
                return (
                    f"no {kind} value model covers the pair {arm}-{peer} "
                    f"(bases {gap:.2f} m apart, within reach)"
                )
    return None


def _runnable(
    tasks: Sequence[HaTask], config: TaskConfig, rows: Sequence[str]
) -> tuple[list[HaTask], list[dict[str, Any]]]:
    """Tasks to run, and the skipped ones with the reason (obstacles; a pair no model covers)."""
    keep, skipped = [], []
    for task in tasks:
        check_joint_convention(task)
        reason = "obstacles" if task.obstacles else _uncovered(task, config, rows)
        if reason is None:
            keep.append(task)
        else:
            skipped.append({"task": task.task_id, "arms": task.arm_count, "reason": reason})
    return keep, skipped


def run_tasks(
    config: TaskConfig,
    rows: Sequence[str],
    tasks: Sequence[HaTask],
    workers: int = 1,
    progress: bool = True,
    on_row: Callable[[dict[str, Any]], None] | None = None,
    cluster: ClusterSpec | None = None,
    resume: bool = False,
) -> dict[str, Any]:
    """Run every row on every runnable task (over ``workers`` local processes, or as Ray tasks
    when ``cluster`` is Ray); return the summary (also what ``on_row`` gets, row by row). With
    ``resume``, tasks an earlier run of the same row finished are read from their bags."""
    from tqdm import tqdm

    runnable, skipped = _runnable(tasks, config, rows)
    for row in rows:  # fail early on a bad row
        for task in runnable:
            parse_row(row, task.cell)
    cluster = cluster or ClusterSpec("local")
    executor = make_executor(workers, cluster, init_worker)
    start = time.perf_counter()
    summaries = []
    try:
        for row in rows:
            t0 = time.perf_counter()
            used: dict[str, Any] = {"value_models": {}, "unmodelled_peers": {}, "epsilon": {}}
            by_id = {t.task_id: t for t in runnable}
            digest = {t.task_id: _fingerprint(config, row, t) for t in runnable}
            earlier = {
                t.task_id: found
                for t in (runnable if resume else ())
                if (found := records.read_finished(_log_path(config, row, t), digest[t.task_id]))
            }
            todo = [t for t in runnable if t.task_id not in earlier]
            for t in todo:  # an earlier record must not vouch for a bag being rewritten
                records.forget(_log_path(config, row, t))
            for found in earlier.values():
                for key in ("value_models", "unmodelled_peers"):
                    used[key].update(found[2][key])
            with tqdm(total=len(runnable), desc=f"tasks {row}", disable=not progress) as bar:
                bar.update(len(earlier))
                outputs = _outputs(config, row, todo, executor, cluster)
                failed: dict[str, EpisodeResult] = {}
                for task_id, (result, extra) in outputs:
                    if result.outcome == "error":
                        failed[task_id] = result
                    else:
                        log = _log_path(config, row, by_id[task_id])
                        records.write_record(log, digest[task_id], 0.0, extra)
                    for key in ("value_models", "unmodelled_peers"):
                        used[key].update(extra[key])
                    bar.update(1)
            # every result is read back from its bag (on the workers when they are local)
            logs = [_log_path(config, row, t) for t in runnable]
            known = [failed.get(t.task_id) for t in runnable]
            results = evaluate_logs(logs, None, executor, known)
            summary = _row_summary(config, row, runnable, results, used, time.perf_counter() - t0)
            summaries.append(summary)
            if on_row is not None:
                on_row(summary)
    finally:
        _STATE.pop("planners", None)  # an in-process run gives its last planners' worlds back
        if executor is not None:
            executor.shutdown(cancel_futures=True)
    return task_summary(config, summaries, tasks, skipped, workers, time.perf_counter() - start)


def _fingerprint(config: TaskConfig, row: str, task: HaTask) -> str:
    """What makes a task's episode the same episode (for ``resume``). The cell enters as its
    names and base poses: its ``repr`` holds sets, whose order changes from one process to the
    next (string hashing is salted), so a resumed run never matched an earlier one."""
    return records.fingerprint(
        row=row,
        task=task.task_id,
        cell=cell_metadata(task.cell),
        scenario=repr(task.scenario),
        planner_settings=config.planner_settings.to_dict(),
        value_models=[str(v) for v in config.value_models],
        backend=config.backend,
        episode=config.episode.to_dict(),
    )


def _outputs(
    config: TaskConfig,
    row: str,
    tasks: Sequence[HaTask],
    executor: Any,
    cluster: ClusterSpec,
) -> Any:
    """``(task id, (result, used))`` as tasks finish; a cluster's bags are written here."""
    if executor is None:
        yield from ((t.task_id, _run(config, row, t)) for t in tasks)
        return
    if not cluster.is_ray:
        futures = {executor.submit(_run, config, row, t): t.task_id for t in tasks}
        yield from ((futures[f], f.result()) for f in as_completed(futures))
        return
    shipped = {executor.submit(_run_shipped, config, row, t): t for t in tasks}
    for future in as_completed(shipped):
        result, used, files = future.result()
        task = shipped[future]
        unpack_folder(files, _log_path(config, row, task))
        yield task.task_id, (result, used)


def _row_summary(
    config: TaskConfig,
    row: str,
    tasks: Sequence[HaTask],
    results: Sequence[EpisodeResult],
    used: dict[str, Any],
    wall: float,
) -> dict[str, Any]:
    counts = sorted({t.arm_count for t in tasks})
    by_arms = {
        str(n): aggregate([r for t, r in zip(tasks, results, strict=True) if t.arm_count == n])
        for n in counts
    }
    return {
        "row": row,
        "ours": aggregate(results).to_dict(),
        "by_arms": {n: m.to_dict() for n, m in by_arms.items()},
        "wall_seconds": wall,
        "value_models": used["value_models"],
        "unmodelled_peers": used["unmodelled_peers"],
        "episodes": [
            {
                "task": t.task_id,
                "arms": t.arm_count,
                "outcome": r.outcome,
                "collision": r.collision_kind,
                "end_time": r.end_time,
                "log": str(_log_path(config, row, t)),
                "error": r.error,
            }
            for t, r in zip(tasks, results, strict=True)
        ],
    }


def task_summary(
    config: TaskConfig,
    rows: Sequence[dict[str, Any]],
    tasks: Sequence[HaTask],
    skipped: Sequence[dict[str, Any]],
    workers: int,
    wall: float,
) -> dict[str, Any]:
    distances = [d for t in tasks for d in pair_distances(t.cell)]
    return json_safe(
        {
            "setup": "ha_tasks",
            "tasks": len(tasks),
            "task_ids": [t.task_id for t in tasks],
            "skipped": list(skipped),
            "pair_base_distance_m": [min(distances), max(distances)] if distances else None,
            "success_rule": "every arm's wrapped joint error (L2) <= 0.1 rad at once within "
            f"{config.episode.time_limit:g} s, no collision (Ha et al.: end effectors within "
            "0.02 m and 0.1 rad, 20 s)",
            "published": PUBLISHED,
            "machine": {"python": platform.python_version(), "platform": platform.platform()},
            "workers": workers,
            "episode_settings": config.episode.to_dict(),
            "planner_settings": config.planner_settings.to_dict(),
            "value_model_sources": [str(s) for s in config.value_models],
            "wall_seconds": wall,
            "rows": list(rows),
        }
    )


def markdown(summary: dict[str, Any]) -> str:
    """SR / CR / stuck per row and per arm count."""
    counts = sorted({n for row in summary["rows"] for n in row["by_arms"]}, key=int)
    head = " | ".join(f"{n} arm{'s' if n != '1' else ''} SR/CR" for n in counts)
    generated = all(_is_generated(t) for t in summary["task_ids"])
    which = "Generated tasks (Ha et al.'s protocol)" if generated else "Ha et al.'s tasks"
    lines = [
        f"### {which} ({summary['tasks']} files, {len(summary['skipped'])} skipped)",
        "",
        f"| planners | tasks | SR % | CR % | stuck % | errors | {head} |",
        "|---|---|---|---|---|---|" + "---|" * len(counts),
    ]
    for row in summary["rows"]:
        ours = row["ours"]
        cells = []
        for n in counts:
            m = row["by_arms"].get(n)
            cells.append("–" if m is None else f"{m['sr']:.0f} / {m['cr_inter_arm']:.0f}")
        lines.append(
            f"| {row['row']} | {ours['episodes']} | {ours['sr']:.0f} | {ours['cr_inter_arm']:.0f} "
            f"| {ours['stuck_rate']:.0f} | {ours.get('errors', 0)} | {' | '.join(cells)} |"
        )
    lines += error_notes(summary["rows"])
    lines += ["", f"Success: {summary['success_rule']}."]
    if summary["skipped"]:
        listed = ", ".join(f"{s['task']} ({s['reason']})" for s in summary["skipped"])
        lines += ["", f"Skipped: {listed}."]
    where = "other tasks of Ha et al.'s protocol" if generated else "Ha et al.'s tasks"
    lines += ["", f"Published on {where} (cited, not rerun):"]
    lines += [f"- {p['label']}: {p['source']}." for p in summary["published"].values()]
    return "\n".join(lines) + "\n"
