"""How many scenarios ask for goals that NeHMO's own safety margin forbids, and what became of them.

    ./run python bench/goal_margins.py --seeds 0,34,35   # bench/results/goal_margins.{json,md}
    ./run python bench/goal_margins.py --runs OUT1,OUT2 --out NAME   # bench/results/NAME.{json,md}
    ./run python bench/goal_margins.py --task-run OUT --tasks DIR --out NAME   # by arm count

For every scenario of a set, all arms are put at their goals and each arm's problem Opt is
built there as the planner would (worst-case peer prediction over ``t_plan``,
``V(τ, ·) ≥ ε``): the goal set is *inside the margin* when some arm's constraint is violated by
the zero step. Such an episode can end with every arm at its goal only within the success
tolerance, short of the exact goals, or by breaking the margin; most end stuck. The count is
given for the default ``t_plan`` and shorter planning horizons (peers at full speed, the paper's
game), and for peers that announce the hold bound ``k`` (every arm settled: ``τ = k·t_safe``,
:mod:`nehmo_core.planning.stages.speed_bounds`; ``k = 0``: the goals' learned distance itself
against ε). Seed 0 uses the committed tables (``bench/results/``), other seeds the fresh tables
under ``bench/results/fresh/seed<S>/``; the outcomes of their ``nehmo`` rows are cross-tabulated.

With ``--runs``: ``nehmo evaluate`` output folders (their ``summary.json`` and saved scenarios),
the ``nehmo`` row's success rate by the goals' *separation* (the smallest exact PyBullet distance
between two arms with every arm at its goal, in bins of :data:`SEPARATIONS`) beside the same
margin test at the certified ε of each cell's models.

With ``--task-run``: one ``nehmo evaluate --tasks DIR`` output folder and the task files it ran
(``--tasks``), the success rate of each row by arm count and goal separation, and each row's
outcomes by whether the task's goal set is inside the settled margin (NeHMO's models on the
task's own cell, every peer announcing the hold bound).
"""

from __future__ import annotations

import argparse
import itertools
import json
from collections import Counter
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np
from _report import machine_at_end, write_report

from nehmo_core.eval.ha_tasks import load_task
from nehmo_core.eval.scenario_sets import goal_separation
from nehmo_core.eval.setups import get_setup
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.factory import make_planner
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.sim.scenario_files import load_scenario_set

RESULTS = Path(__file__).resolve().parent / "results"
SETUPS = {  # setup → (table file, nehmo row)
    "dual_ur5": ("table_II_dual_ur5.json", "nehmo"),
    "triple_ur5": ("table_III_triple_ur5.json", "nehmo"),
    "five_ur5": ("table_III_five_ur5.json", "nehmo"),
    "ur5_kinova_challenging": ("table_IV_ur5_kinova_challenging.json", "nehmo/nehmo"),
}
T_PLANS = (0.1, 0.08, 0.04)
SEPARATIONS = (0.01, 0.05, 0.1, 0.2)  # [m] bin edges of the goals' exact separation
BOUNDS = (PlannerSettings().hold.bound, 0.0)


def nehmo_planners(
    cell: Any, models: Any, settings: PlannerSettings | None = None
) -> dict[str, NehmoPlanner]:
    """A NeHMO planner for every arm of ``cell``."""
    planners: dict[str, NehmoPlanner] = {}
    for arm in cell.arm_ids:
        planner = make_planner("nehmo", cell, arm, models, settings)
        assert isinstance(planner, NehmoPlanner)
        planners[arm] = planner
    return planners


def goal_margin(
    planners: dict[str, NehmoPlanner], goal: dict[str, np.ndarray], bound: float = 1.0
) -> float:
    """The smallest ``V − ε`` [m] of any arm's zero step with every arm at its goal, each peer
    planned against the speed bound ``bound`` (1: full speed)."""
    worst = np.inf
    for arm, planner in planners.items():
        peers = {a: q for a, q in goal.items() if a != arm}
        now = planner.current(goal[arm], peers, dict.fromkeys(planner.pairs, bound))
        if not now.ids:
            continue
        problem = planner.problem(np.zeros(planner.robot.dof), now)
        c, _ = problem.constraints.evaluate(np.zeros(planner.robot.dof))
        worst = min(worst, float(c.min()))
    return worst


def _where(seed: int) -> Path:
    return RESULTS if seed == 0 else RESULTS / "fresh" / f"seed{seed}"


def run_seed(seed: int, registry: ModelRegistry) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for setup_name, (table, row_name) in SETUPS.items():
        setup = get_setup(setup_name)
        cell = setup.load_cell()
        scenario_file = _where(seed) / "scenarios" / f"{setup_name}_seed{seed}.json"
        if not scenario_file.exists():
            print(f"seed {seed}: no {scenario_file}, skipped")
            continue
        scenarios = load_scenario_set(scenario_file)
        goals = [{a: np.asarray(q) for a, q in s.goal.items()} for s in scenarios.scenarios]
        models = registry.models_for("nehmo", cell)
        margins: dict[str, list[float]] = {}
        for t_plan in T_PLANS:
            settings = PlannerSettings().override({"opt.t_plan": t_plan})
            planners = nehmo_planners(cell, models, settings)
            margins[str(t_plan)] = [goal_margin(planners, g) for g in goals]
        planners = nehmo_planners(cell, models)
        for bound in BOUNDS:
            margins[f"k={bound:g}"] = [goal_margin(planners, g, bound) for g in goals]
        path = _where(seed) / table
        rows = json.loads(path.read_text())["rows"] if path.exists() else []
        outcome = {
            e["scenario"]: e["outcome"] for r in rows if r["row"] == row_name for e in r["episodes"]
        }
        settled = margins[f"k={BOUNDS[0]:g}"]
        cross = Counter(
            (outcome.get(i, "not run"), "inside" if m < 0 else "outside")
            for i, m in zip(scenarios.indices, settled, strict=True)
        )
        out[setup_name] = {
            "seed": seed,
            "scenarios": len(scenarios.scenarios),
            "inside_margin": {k: int(np.sum(np.array(v) < 0)) for k, v in margins.items()},
            "outcomes_by_margin": {f"{o}/{m}": n for (o, m), n in sorted(cross.items())},
            "row": row_name,
        }
        print(setup_name, json.dumps(out[setup_name]))
    return out


def run(seeds: list[int]) -> dict[str, Any]:
    registry = ModelRegistry()
    report: dict[str, Any] = {"machine": machine_at_end(), "seeds": {}}
    for seed in seeds:
        report["seeds"][str(seed)] = run_seed(seed, registry)
    return report


def markdown(report: dict[str, Any]) -> str:
    d = PlannerSettings()
    lines = [
        "# Goal sets inside NeHMO's safety margin",
        "",
        "A goal set is *inside the margin* when, with every arm at its goal, some arm's Opt "
        "constraint fails for the zero step: no safe Opt planner can hold every arm exactly at "
        "its goal, so such an episode succeeds only if the arms stop within the success "
        "tolerance short of the exact goals. Shipped models, default settings "
        f"(ε = {d.opt.epsilon}, t_safe = {d.opt.t_safe}). Columns: peers at full speed "
        f"(the paper's game) for three `t_plan`; every peer settled and keeping the hold bound k "
        f"(`V(k·t_safe) ≥ ε`; k = {BOUNDS[0]:g} is the default `hold.bound`; k = 0 compares the "
        "goals' learned distance with ε). Outcomes: the `nehmo` row of the table of that seed "
        f"(the run that produced it), against the margin at k = {BOUNDS[0]:g}.",
        "",
        "| setup | seed | scenarios | inside, full speed, t_plan = "
        + " / ".join(f"{t:g}" for t in T_PLANS)
        + " s | inside, settled k = "
        + " / ".join(f"{b:g}" for b in BOUNDS)
        + " | NeHMO outcome × margin |",
        "|---|---|---|---|---|---|",
    ]
    for seed, setups in report["seeds"].items():
        for name, r in setups.items():
            full = " / ".join(str(r["inside_margin"][str(t)]) for t in T_PLANS)
            settled = " / ".join(str(r["inside_margin"][f"k={b:g}"]) for b in BOUNDS)
            cross = ", ".join(f"{k}: {v}" for k, v in r["outcomes_by_margin"].items())
            lines.append(f"| {name} | {seed} | {r['scenarios']} | {full} | {settled} | {cross} |")
    lines += ["", f"Machine: {report['machine']}.", ""]
    return "\n".join(lines)


def bin_label(d: float) -> str:
    """The :data:`SEPARATIONS` bin of separation ``d`` [m], in cm."""
    edges = [0.0, *SEPARATIONS, np.inf]
    for lo, hi in itertools.pairwise(edges):
        if d < hi:
            return f"≥ {lo * 100:g} cm" if hi == np.inf else f"{lo * 100:g}–{hi * 100:g} cm"
    raise AssertionError(d)


def success_cell(counts: Mapping[str, int] | None) -> str:
    """``successes / episodes`` of one table cell (outcome counts), or a dash for None."""
    return "–" if counts is None else f"{counts.get('success', 0)} / {sum(counts.values())}"


def pooled(cells: Any) -> Counter[str]:
    """The outcome counts of several cells added up."""
    return sum((Counter(c) for c in cells), Counter())


def run_outputs(runs: list[Path], registry: ModelRegistry) -> dict[str, Any]:
    """Success by goal separation and by the settled margin, per evaluation output."""
    report: dict[str, Any] = {"machine": machine_at_end(), "runs": {}}
    for run_dir in runs:
        summary = json.loads((run_dir / "summary.json").read_text())
        cell = get_setup(summary["setup"]).load_cell()
        scenarios = load_scenario_set(next((run_dir / "scenarios").glob("*.json")))
        row = next(r for r in summary["rows"] if r["row"].split("/")[0] == "nehmo")
        outcome = {e["scenario"]: e["outcome"] for e in row["episodes"]}
        models = registry.models_for("nehmo", cell)
        planners = nehmo_planners(cell, models)
        bins: dict[str, Counter[str]] = {}
        margin: Counter[str] = Counter()
        with CellWorld(cell) as world:
            for i, sc in zip(scenarios.indices, scenarios.scenarios, strict=True):
                goal = {a: np.asarray(q) for a, q in sc.goal.items()}
                o = outcome.get(i, "not run")
                bins.setdefault(bin_label(goal_separation(world, goal)), Counter())[o] += 1
                inside = goal_margin(planners, goal, BOUNDS[0]) < 0
                margin[f"{o}/{'inside' if inside else 'outside'}"] += 1
        epsilon = next(iter(planners.values())).settings.opt.epsilon
        report["runs"][run_dir.name] = {
            "setup": summary["setup"],
            "seed": summary["seed"],
            "epsilon": epsilon,
            "by_separation": {k: dict(v) for k, v in bins.items()},
            "outcomes_by_margin": dict(sorted(margin.items())),
        }
        print(run_dir.name, json.dumps(report["runs"][run_dir.name]), flush=True)
    return report


def runs_markdown(report: dict[str, Any]) -> str:
    labels = [bin_label(x) for x in (0.0, *SEPARATIONS)]
    lines = [
        "# Success by how far apart the goals are",
        "",
        "NeHMO's successes / episodes of each evaluation, by the goals' separation: the smallest "
        "exact distance between two arms with every arm at its goal. The last column counts "
        "the episodes by outcome and by whether the goal set is inside the margin that rows "
        f"against settled peers keep (every peer announcing the hold bound "
        f"k = {BOUNDS[0]:g}): `bench/goal_margins.py` (its docstring).",
        "",
        "| run | setup | seed | ε [m] | "
        + " | ".join(labels)
        + " | all | outcome × settled margin |",
        "|---|---|---|---|" + "---|" * (len(labels) + 2),
    ]
    total: dict[str, Counter[str]] = {}
    for name, r in report["runs"].items():
        cells = []
        for label in labels:
            c = Counter(r["by_separation"].get(label, {}))
            total.setdefault(label, Counter()).update(c)
            cells.append(success_cell(c or None))
        every = pooled(r["by_separation"].values())
        cross = ", ".join(f"{k}: {v}" for k, v in r["outcomes_by_margin"].items())
        lines.append(
            f"| {name} | {r['setup']} | {r['seed']} | {r['epsilon']:.4g} | "
            + " | ".join(cells)
            + f" | {success_cell(every)} | {cross} |"
        )
    if len(report["runs"]) > 1:
        cells = [success_cell(total.get(x)) for x in labels]
        every = pooled(total.values())
        lines.append("| all | | | | " + " | ".join(cells) + f" | {success_cell(every)} | |")
    lines += ["", f"Machine: {report['machine']}.", ""]
    return "\n".join(lines)


def task_run(run_dir: Path, tasks: Path) -> dict[str, Any]:
    """Successes / episodes of every row of a task-set evaluation, by arm count and by the
    goals' separation (each task's own cell, from its file in ``tasks``), and by outcome and
    whether the task's goal set is inside the settled margin."""
    summary = json.loads((run_dir / "summary.json").read_text())
    registry = ModelRegistry()
    inside: dict[str, bool] = {}
    rows: dict[str, dict[str, dict[str, Counter[str]]]] = {}
    margins: dict[str, dict[str, Counter[str]]] = {}
    for row in summary["rows"]:
        by_arms = rows.setdefault(row["row"], {})
        for e in row["episodes"]:
            task = load_task(tasks / f"{e['task']}.json")
            with CellWorld(task.cell) as world:
                label = bin_label(goal_separation(world, task.scenario.goal))
            counts = by_arms.setdefault(str(e["arms"]), {}).setdefault(label, Counter())
            counts[e["outcome"]] += 1
            if e["task"] not in inside:
                inside[e["task"]] = _inside_settled_margin(task.cell, task.scenario.goal, registry)
            where = "inside" if inside[e["task"]] else "outside"
            cross = margins.setdefault(row["row"], {}).setdefault(str(e["arms"]), Counter())
            cross[f"{e['outcome']}/{where}"] += 1
    return {
        "machine": machine_at_end(),
        "run": run_dir.name,
        "rows": rows,
        "outcomes_by_margin": {
            row: {arms: dict(sorted(c.items())) for arms, c in by_arms.items()}
            for row, by_arms in margins.items()
        },
    }


def _inside_settled_margin(cell: Any, goal: Mapping[str, Any], registry: ModelRegistry) -> bool:
    """Whether some arm's rows break the margin with every arm settled at its goal (each peer
    announcing the hold bound)."""
    planners = nehmo_planners(cell, registry.models_for("nehmo", cell))
    goals = {a: np.asarray(q) for a, q in goal.items()}
    try:
        return goal_margin(planners, goals, BOUNDS[0]) < 0
    finally:
        for planner in planners.values():
            planner.close()


def task_run_markdown(report: dict[str, Any]) -> str:
    labels = [bin_label(x) for x in (0.0, *SEPARATIONS)]
    lines = [
        "# Success by arm count and how far apart the goals are",
        "",
        "Successes / tasks of each row, by the goals' separation (the smallest exact distance "
        "between two arms with every arm at its goal), and the tasks by outcome and by whether "
        "the goal set is inside the margin that rows against settled peers keep (every peer "
        f"announcing the hold bound k = {BOUNDS[0]:g}; NeHMO's models and margins whatever the "
        "row): `bench/goal_margins.py --task-run` (its docstring).",
        "",
        "| row | arms | " + " | ".join(labels) + " | all | outcome × settled margin |",
        "|---|---|" + "---|" * (len(labels) + 2),
    ]
    crosses = report.get("outcomes_by_margin", {})
    for row, by_arms in report["rows"].items():
        for arms, bins in sorted(by_arms.items(), key=lambda kv: int(kv[0])):
            every = pooled(bins.values())
            cells = [success_cell(bins.get(x)) for x in labels]
            cross = crosses.get(row, {}).get(arms, {})
            text = ", ".join(f"{k}: {v}" for k, v in cross.items())
            lines.append(
                f"| {row} | {arms} | " + " | ".join(cells) + f" | {success_cell(every)} | {text} |"
            )
    lines += ["", f"Machine: {report['machine']}.", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="0", help="comma-separated scenario-set seeds")
    parser.add_argument("--runs", help="comma-separated `nehmo evaluate` output folders")
    parser.add_argument("--task-run", help="one `nehmo evaluate --tasks` output folder")
    parser.add_argument("--tasks", help="the task files that run used (with --task-run)")
    parser.add_argument("--out", default="goal_separation", help="result name (with --runs)")
    args = parser.parse_args()
    if args.task_run:
        if not args.tasks:
            parser.error("--task-run needs --tasks DIR (the task files the run used)")
        report = task_run(Path(args.task_run), Path(args.tasks))
        print(write_report(RESULTS, args.out, report, task_run_markdown))
        return
    if args.runs:
        runs = [Path(r) for r in args.runs.split(",") if r]
        report = run_outputs(runs, ModelRegistry())
        print(write_report(RESULTS, args.out, report, runs_markdown))
        return
    seeds = [int(s) for s in args.seeds.split(",") if s]
    print(write_report(RESULTS, "goal_margins", run(seeds), markdown))


if __name__ == "__main__":
    main()
