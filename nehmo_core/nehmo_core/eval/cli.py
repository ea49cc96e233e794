"""``nehmo evaluate``: episodes of one setup for several planner rows, metrics from the logs.

    nehmo evaluate --setup dual_ur5 --planners nehmo,naive,chomp --episodes 100 --seed 0 \\
        --out out/eval_dual --workers 2 --value-model runs/ur5_ur5_bc_sym

writes ``DIR/scenarios/<setup>_seed<seed>.json`` (the scenario set ``--seed`` selects),
``DIR/logs/<row>/episode_<i>/`` (one rosbag2 bag per episode), ``DIR/summary.json`` and
``DIR/summary.md`` (our numbers with the paper's beside them), and with ``--render`` a GIF and a
distance plot of the first episode of every row under ``DIR/renders/``.

    nehmo evaluate --tasks ../shared/ha_benchmark/tasks --planners nehmo,naive,ompl --out OUT

runs Ha et al.'s task files instead (:mod:`nehmo_core.eval.task_runner`): ``OUT/summary.json``
adds ``rows[].by_arms``, the metrics per arm count.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from nehmo_core.cluster import CLUSTER_HELP, parse_cluster
from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.eval.batch import BatchConfig, RowRun, run_rows
from nehmo_core.eval.episode import EpisodeSettings
from nehmo_core.eval.metrics import format_metrics
from nehmo_core.eval.report import markdown_table, setup_summary, write_summary
from nehmo_core.eval.scenario_sets import scenario_set_for
from nehmo_core.eval.setups import SETUPS, get_setup, parse_row, row_slug
from nehmo_core.eval.stalls import SYNTAX as STALLS_SYNTAX
from nehmo_core.eval.stalls import Stalls, parse_stalls
from nehmo_core.planning.models.registry import parse_value_models, snapshot_value_models
from nehmo_core.planning.settings import PlannerSettings, parse_assignments
from nehmo_core.sim.actuators import ACTUATOR_MODELS
from nehmo_core.sim.scenario_files import load_scenario_set
from nehmo_core.sim.scenarios import ScenarioSet

__all__ = ["add_arguments", "run"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    where = parser.add_mutually_exclusive_group(required=True)
    where.add_argument(
        "--setup",
        metavar="SETUP",
        help=f"evaluation setup ({', '.join(sorted(SETUPS))}) or a cell file (*.yaml: 20 s "
        "episodes, success within 0.1 rad)",
    )
    where.add_argument(
        "--tasks",
        type=Path,
        metavar="DIR",
        help="a directory of Ha et al.'s task JSON files (each its own cell; --episodes and "
        "--seed do not apply)",
    )
    parser.add_argument(
        "--planners",
        default="nehmo,naive",
        help="comma-separated rows; a row is a kind for every arm or kinds per arm joined by "
        "'/' (e.g. nehmo/reckless). Kinds: nehmo, nehmo_paper (no self-clearance rows), "
        "nehmo_no_sym, opt_deepreach, nehmo_wrap, naive, reckless, chomp, ompl",
    )
    parser.add_argument("--episodes", type=int, default=100, help="scenarios per row")
    parser.add_argument("--seed", type=int, default=0, help="selects the scenario set")
    parser.add_argument("--out", type=Path, required=True, help="output directory")
    parser.add_argument("--workers", type=int, default=1, help="worker processes (local)")
    parser.add_argument("--cluster", default="local", help=CLUSTER_HELP)
    parser.add_argument(
        "--resume",
        action="store_true",
        help="keep the episodes an earlier run into --out finished with the same settings",
    )
    parser.add_argument(
        "--value-model",
        action="append",
        default=[],
        metavar="[KIND=]SOURCE",
        help="value model source for the Opt rows: a shipped pair name, a run directory, a "
        ".safetensors file, or 'synthetic' (random stand-ins, smoke runs only); repeatable",
    )
    parser.add_argument(
        "--scenarios", type=Path, help="a scenario file to use instead of generating the set"
    )
    parser.add_argument(
        "--backend", default="auto", choices=("auto", "compiled", "vm"), help="V/∇V evaluation"
    )
    parser.add_argument(
        "--deadline", type=float, help="planner deadline [s] (default: one 25 Hz tick, 0.04)"
    )
    parser.add_argument(
        "--fail-safe-deadband",
        type=float,
        help="fail-safe joints with |dV/dq_j| below this share of the largest stay still "
        "(default 0.2; 0: the paper's fail-safe)",
    )
    parser.add_argument(
        "--no-self-clearance",
        action="store_true",
        help="the paper's Opt: no self-collision rows in Opt or the fail-safe",
    )
    parser.add_argument(
        "--no-escape",
        action="store_true",
        help="no stall escape: an arm that stops against a peer's constraint stays stopped",
    )
    parser.add_argument(
        "--planner-setting",
        action="append",
        default=[],
        metavar="GROUP.FIELD=VALUE",
        help="set a planner setting for every Opt row, e.g. opt.t_plan=0.08 or hold.bound=1 "
        "(names: docs/settings.md); repeatable",
    )
    parser.add_argument(
        "--actuators",
        choices=ACTUATOR_MODELS,
        default="ideal",
        help="how simulated arms carry commands out: ideal (q' = u, the paper's) or realistic "
        "(acceleration limits from the robot descriptions, command latency, joint-state noise)",
    )
    parser.add_argument(
        "--stalls",
        type=parse_stalls,
        default=Stalls(),
        metavar=STALLS_SYNTAX,
        help="overloaded planner processes (stress test, nehmo_core.eval.stalls): each tick a "
        "process stalls with chance RATE for 1..MAX_TICKS periods (default 5); arms spread over "
        "PROCESSES (0: one each); a command drives its arm for HOLD_TICKS periods (default 1, "
        "the bridge's command_validity; 5: a 0.2 s watchdog only); a late tick publishes zero "
        "('expire', the default, as arm_planner does) or its stale plan ('send')",
    )
    parser.add_argument(
        "--time-limit",
        type=float,
        default=None,
        metavar="SECONDS",
        help="episode length in simulated seconds (default: the setup's, 20 s for tasks); "
        "longer episodes tell arms that deadlock from arms that arrive late, but the success "
        "rule is then no longer the paper's",
    )
    parser.add_argument("--render", action="store_true", help="render each row's first episode")
    parser.add_argument("--no-progress", action="store_true", help="no progress bars")


def _scenarios(args: argparse.Namespace) -> ScenarioSet:
    setup = get_setup(args.setup)
    if args.scenarios is not None:
        saved = load_scenario_set(args.scenarios)
        if saved.cell != setup.cell:
            raise InvalidValueError(
                "--scenarios", f"must hold scenarios of cell {setup.cell!r}", saved.cell
            )
        return saved.head(min(args.episodes, len(saved)))

    def progress(kept: int, drawn: int) -> None:
        if not args.no_progress:
            print(f"\rscenarios: {kept}/{args.episodes} kept of {drawn}", end="", file=sys.stderr)

    made = scenario_set_for(setup, args.seed, args.episodes, args.out / "scenarios", None, progress)
    if not args.no_progress:
        print(file=sys.stderr)
    return made


def _run_tasks(args: argparse.Namespace, rows: list[str], settings: PlannerSettings) -> int:
    from nehmo_core.eval.ha_tasks import load_tasks
    from nehmo_core.eval.task_runner import TIME_LIMIT, TaskConfig, markdown, run_tasks

    tasks = load_tasks(args.tasks)
    config = TaskConfig(
        out_dir=args.out,
        value_models=snapshot_value_models(
            parse_value_models(args.value_model), args.out / "value_models"
        ),
        backend=args.backend,
        planner_settings=settings,
        episode=EpisodeSettings(
            time_limit=TIME_LIMIT if args.time_limit is None else args.time_limit,
            actuators=args.actuators,
            stalls=args.stalls,
        ),
    )

    def report(row: dict[str, object]) -> None:
        ours: dict[str, float] = row["ours"]  # type: ignore[assignment]
        print(f"tasks {row['row']}: {format_metrics(ours)}", file=sys.stderr)

    summary = run_tasks(
        config,
        rows,
        tasks,
        args.workers,
        not args.no_progress,
        report,
        parse_cluster(args.cluster),
        args.resume,
    )
    if summary["skipped"]:
        reasons = "; ".join(f"{s['task']}: {s['reason']}" for s in summary["skipped"])
        print(
            f"skipped {len(summary['skipped'])} of {len(tasks)} tasks ({reasons})", file=sys.stderr
        )
    path = args.out / "summary.json"
    path.write_text(json.dumps(summary, indent=1, allow_nan=False) + "\n")
    path.with_suffix(".md").write_text(markdown(summary))
    print(markdown(summary))
    print(f"wrote {path} and {path.with_suffix('.md')}", file=sys.stderr)
    return _errors_status({r["row"]: r["ours"]["errors"] for r in summary["rows"]})


def _errors_status(errors: dict[str, int]) -> int:
    """1 (and one line) when episodes of some row could not be evaluated, else 0."""
    failed = {row: n for row, n in errors.items() if n}
    if failed:
        listed = ", ".join(f"{row}: {n}" for row, n in failed.items())
        print(
            f"episodes that could not be evaluated (counted as failures): {listed}", file=sys.stderr
        )
        return 1
    return 0


def _episode_overrides(args: argparse.Namespace) -> tuple[tuple[str, object], ...]:
    """What the options change of the setup's episode settings."""
    overrides: list[tuple[str, object]] = []
    if args.actuators != "ideal":
        overrides.append(("actuators", args.actuators))
    if args.time_limit is not None:
        overrides.append(("time_limit", args.time_limit))
    if args.stalls != Stalls():
        overrides.append(("stalls", args.stalls))
    return tuple(overrides)


def run(args: argparse.Namespace) -> int:
    if args.episodes < 1:
        raise InvalidValueError("--episodes", "must be >= 1", args.episodes)
    if args.workers < 1:
        raise InvalidValueError("--workers", "must be >= 1", args.workers)
    cluster = parse_cluster(args.cluster)
    rows = [r.strip() for r in args.planners.split(",") if r.strip()]
    if not rows:
        raise InvalidValueError("--planners", "must name at least one row", args.planners)
    if args.time_limit is not None and not args.time_limit > 0:
        raise InvalidValueError("--time-limit", "must be > 0 [s]", args.time_limit)
    if Path(args.out).exists() and not Path(args.out).is_dir():
        raise InvalidValueError("--out", "must be a directory (it is a file)", str(args.out))
    if args.setup is not None:
        cell = get_setup(args.setup).load_cell()
        for row in rows:  # fail before any work on a bad row
            parse_row(row, cell)
    changes: dict[str, object] = {}
    if args.deadline is not None:
        changes["opt.deadline"] = args.deadline
    if args.fail_safe_deadband is not None:
        changes["fail_safe.deadband"] = args.fail_safe_deadband
    if args.no_self_clearance:
        changes["self_clearance.enabled"] = False
    if args.no_escape:
        changes["escape.enabled"] = False
    changes.update(parse_assignments(args.planner_setting))
    planner_settings = PlannerSettings().override(changes)
    if args.tasks is not None:
        return _run_tasks(args, rows, planner_settings)
    config = BatchConfig(
        setup=args.setup,
        out_dir=args.out,
        value_models=snapshot_value_models(
            parse_value_models(args.value_model), args.out / "value_models"
        ),
        backend=args.backend,
        planner_settings=planner_settings,
        # defaults: no override, so runs before these options resume as they were
        episode_overrides=_episode_overrides(args),
    )
    scenarios = _scenarios(args)

    def report(run: RowRun) -> None:
        line = format_metrics(run.metrics.to_dict())
        print(f"{args.setup} {run.row}: {line}, {run.wall_seconds:.0f} s wall", file=sys.stderr)
        for arm_id, note in sorted(run.epsilon.items()):
            print(f"  {arm_id}: {note}", file=sys.stderr)

    start = time.perf_counter()
    runs = run_rows(
        config,
        rows,
        scenarios,
        args.workers,
        not args.no_progress,
        report,
        cluster=cluster,
        resume=args.resume,
    )
    summary = setup_summary(
        args.setup,
        runs,
        {
            "seed": scenarios.seed,
            "episodes": len(scenarios),
            "scenario_candidates": scenarios.candidates,
            "workers": args.workers,
            "cluster": cluster.describe(),
            "value_model_sources": [str(s) for s in config.value_models],
            "episode_settings": config.episode_settings().to_dict(),
            "planner_settings": planner_settings.to_dict(),
            "wall_seconds": time.perf_counter() - start,
        },
    )
    path = write_summary(args.out, summary)
    print(markdown_table(summary))
    print(f"wrote {path} and {path.with_suffix('.md')}", file=sys.stderr)
    if args.render:
        from nehmo_core.eval.render import render_episode

        for r in runs:
            outputs = render_episode(r.logs[0], args.out / "renders" / row_slug(r.row))
            print(f"rendered {', '.join(str(o) for o in outputs)}", file=sys.stderr)
    bad = [r.row for r in runs if r.mismatches]
    if bad:
        print(f"log check failed for rows {bad}: see summary.json", file=sys.stderr)
        return 1
    return _errors_status({r.row: r.metrics.errors for r in runs})


def main(argv: list[str] | None = None) -> int:
    """``python -m nehmo_core.eval.cli``: the same command outside ``nehmo``."""
    parser = argparse.ArgumentParser(prog="nehmo evaluate", description=__doc__.split("\n")[0])
    add_arguments(parser)
    args = parser.parse_args(argv)
    try:
        return run(args)
    except NehmoError as exc:
        print(f"nehmo evaluate: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
