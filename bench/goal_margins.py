"""How many scenarios ask for goals that NeHMO's own safety margin forbids, and what became of them.

    ./run python bench/goal_margins.py     # writes bench/results/goal_margins.{json,md}

For every scenario of the committed seed-0 sets, all arms are put at their goals and each arm's
problem Opt is built there as the planner would (worst-case peer prediction over ``t_plan``,
``V(t_safe, ·) ≥ ε``): the goal set is *inside the margin* when some arm's constraint is
violated by the zero step. Such an episode can end with every arm at its goal only within the
success tolerance, short of the exact goals, or by breaking the margin; most end stuck. The
count is given for the default ``t_plan`` and for shorter planning horizons (the paper's remark
that a faster solve allows a shorter adversarial horizon), and cross-tabulated with the outcomes
of the ``nehmo`` rows in the committed tables.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from _report import machine_at_end, write_report

from nehmo_core.eval.planners import ModelRegistry
from nehmo_core.eval.setups import get_setup
from nehmo_core.planning.factory import make_planner
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.sim.scenarios import load_scenario_set

RESULTS = Path(__file__).resolve().parent / "results"
SETUPS = {  # setup → (table file, nehmo row)
    "dual_ur5": ("table_II_dual_ur5.json", "nehmo"),
    "triple_ur5": ("table_III_triple_ur5.json", "nehmo"),
    "five_ur5": ("table_III_five_ur5.json", "nehmo"),
    "ur5_kinova_challenging": ("table_IV_ur5_kinova_challenging.json", "nehmo/nehmo"),
}
T_PLANS = (0.1, 0.08, 0.04)


def goal_margin(planners: dict[str, NehmoPlanner], goal: dict[str, np.ndarray]) -> float:
    """The smallest ``V − ε`` [m] of any arm's zero step with every arm at its goal."""
    worst = np.inf
    for arm, planner in planners.items():
        peers = {a: q for a, q in goal.items() if a != arm}
        now = planner._current(goal[arm], peers)
        if not now.ids:
            continue
        problem = planner._problem(np.zeros(planner.robot.dof), now)
        c, _ = problem.constraints.evaluate(np.zeros(planner.robot.dof))
        worst = min(worst, float(c.min()))
    return worst


def run() -> dict[str, Any]:
    registry = ModelRegistry()
    out: dict[str, Any] = {"machine": machine_at_end(), "setups": {}}
    for setup_name, (table, row_name) in SETUPS.items():
        setup = get_setup(setup_name)
        cell = setup.load_cell()
        scenarios = load_scenario_set(RESULTS / "scenarios" / f"{setup_name}_seed0.json")
        models = registry.models_for("nehmo", cell)
        margins: dict[str, list[float]] = {}
        for t_plan in T_PLANS:
            settings = PlannerSettings(t_plan=t_plan)
            planners = {a: make_planner("nehmo", cell, a, models, settings) for a in cell.arm_ids}
            margins[str(t_plan)] = [
                goal_margin(planners, {a: np.asarray(q) for a, q in s.goal.items()})  # type: ignore[arg-type]
                for s in scenarios.scenarios
            ]
        rows = json.loads((RESULTS / table).read_text())["rows"]
        outcome = {
            e["scenario"]: e["outcome"] for r in rows if r["row"] == row_name for e in r["episodes"]
        }
        default = margins[str(PlannerSettings().t_plan)]
        cross = Counter(
            (outcome.get(i, "not run"), "inside" if m < 0 else "outside")
            for i, m in zip(scenarios.indices, default, strict=True)
        )
        out["setups"][setup_name] = {
            "scenarios": len(scenarios.scenarios),
            "inside_margin": {k: int(np.sum(np.array(v) < 0)) for k, v in margins.items()},
            "outcomes_by_margin": {f"{o}/{m}": n for (o, m), n in sorted(cross.items())},
            "row": row_name,
        }
        print(setup_name, json.dumps(out["setups"][setup_name]))
    return out


def markdown(report: dict[str, Any]) -> str:
    lines = [
        "# Goal sets inside NeHMO's safety margin",
        "",
        "A goal set is *inside the margin* when, with every arm at its goal, some arm's Opt "
        "constraint `V(t_safe, ·) ≥ ε` (worst-case peer over `t_plan`) fails for the zero step: "
        "no safe Opt planner can hold every arm exactly at its goal, so such an episode succeeds "
        "only if the arms stop within the success tolerance short of the exact goals. "
        "Seed-0 scenario sets, shipped models, default settings "
        f"(ε = {PlannerSettings().epsilon}, t_safe = {PlannerSettings().t_safe}).",
        "",
        "| setup | scenarios | inside, t_plan = "
        + " / ".join(f"{t:g}" for t in T_PLANS)
        + " s | NeHMO outcome × margin (default t_plan) |",
        "|---|---|---|---|",
    ]
    for name, r in report["setups"].items():
        inside = " / ".join(str(r["inside_margin"][str(t)]) for t in T_PLANS)
        cross = ", ".join(f"{k}: {v}" for k, v in r["outcomes_by_margin"].items())
        lines.append(f"| {name} | {r['scenarios']} | {inside} | {cross} |")
    lines += ["", f"Machine: {report['machine']}.", ""]
    return "\n".join(lines)


def main() -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()
    print(write_report(RESULTS, "goal_margins", run(), markdown))


if __name__ == "__main__":
    main()
