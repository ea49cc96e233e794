"""Does the default SQP return the solutions of a tight one? Replayed on closed-loop steps.

    OMP_NUM_THREADS=1 ./run python bench/sqp_agreement.py   # writes bench/results/sqp_agreement.*

For the dual, three- and five-UR5 cells (1, 2 and 4 peers of the measured arm) every arm runs
``nehmo`` with the default solver on the planning-speed bench's scenarios. At every step of the
measured arm the same problem, from the same warm start and Hessian, is solved again with a
tight setting: the SQP stopping at a 1e-9 rad step with every V row in every iteration (no
screening). The closed loop follows the default answer. Reported per cell: how the statuses
pair up, the largest joint difference of the two steps [rad] where both are optimal, the
relative cost difference, the smallest constraint value of the default answer, and the time of
both solves (median and p95 over the constrained steps). The default solver iterates in C; each
problem is also solved by its Python loop (``solver.sqp_native`` false, the same algorithm), and the
last columns say how often the two agree on status and iteration count and how far their steps
are apart. Where the default reports ``infeasible`` (the planner falls back to its fail-safe),
IPOPT (tol 1e-8, up to 300 iterations, same warm start) tries the problem as well: the last
column counts the steps where it finds a point satisfying every constraint within 1e-6 m, i.e.
fail-safe steps that Opt did not need. For scale, where the tight SQP is optimal IPOPT also
solves the problem with the authors' settings (tol 1e-3, at most 30 iterations, from ``y = 0``):
how far its answers are from the tight ones, where it reports success.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections import Counter
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import torch
from planning_speed import CASES, _scenarios, far_models

from nehmo_core.hjr import load_value_function
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.opt.problem import OptProblem
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.planning.solvers.base import make_solver
from nehmo_core.planning.solvers.ipopt import IpoptSolver
from nehmo_core.planning.solvers.sqp import SolveResult, solve_sqp
from nehmo_core.robots import load_cell

RESULTS = Path(__file__).resolve().parent / "results"


class _Both:
    """The default solver, with the tight one run beside it on the measured arm's problems."""

    def __init__(self) -> None:
        self.settings = PlannerSettings()
        self.default = make_solver(self.settings)
        self.ipopt = IpoptSolver(tol=1e-8, max_iter=300)
        self.authors = IpoptSolver(
            self.settings.solver.ipopt_tol, self.settings.solver.ipopt_max_iter
        )
        self.record = False
        self.rows: list[dict[str, Any]] = []

    def __call__(
        self,
        problem: OptProblem,
        y_start: np.ndarray,
        deadline: float,
        hessian: np.ndarray | None = None,
    ) -> SolveResult:
        start = time.perf_counter()
        fast = self.default(problem, y_start, np.inf, hessian)
        middle = time.perf_counter()
        if self.record:
            tight = solve_sqp(problem, y_start, 1e-9, 100, np.inf, hessian, screen=None)
            end = time.perf_counter()
            d = self.settings
            python = solve_sqp(
                problem,
                y_start,
                d.solver.sqp_tol,
                d.solver.sqp_max_iter,
                np.inf,
                hessian,
                screen=d.solver.sqp_screen,
                native=False,
            )
            ipopt_found = None
            if fast.status == "infeasible":
                ref = self.ipopt.solve(problem, y_start)
                c, _ = problem.constraints.evaluate(ref.y)
                ipopt_found = ref.status == "optimal" and float(c.min()) >= -1e-6
            both = fast.status == tight.status == "optimal"
            authors_dy = None
            if tight.status == "optimal":
                theirs = self.authors.solve(problem, np.zeros_like(y_start))
                if theirs.success:
                    authors_dy = float(np.abs(theirs.y - tight.y).max())
            self.rows.append(
                {
                    "fast": fast.status,
                    "tight": tight.status,
                    "dy": float(np.abs(fast.y - tight.y).max()) if both else None,
                    "dcost": (
                        abs(problem.cost(fast.y) - problem.cost(tight.y))
                        / max(problem.cost(tight.y), 1e-12)
                        if both
                        else None
                    ),
                    "min_c": float(fast.constraint.min()) if fast.success else None,
                    "ipopt_found": ipopt_found,
                    "authors_dy": authors_dy,
                    "tight_optimal": tight.status == "optimal",
                    "python_same": python.status == fast.status
                    and python.iterations == fast.iterations,
                    "python_dy": float(np.abs(fast.y - python.y).max()),
                    "t_fast": middle - start,
                    "t_tight": end - middle,
                }
            )
        return fast


def _cell(
    cell_name: str, arm: str, model: PairValueModel, scenarios: int, steps: int
) -> dict[str, Any]:
    cell = load_cell(cell_name)
    solvers = {a: _Both() for a in cell.arm_ids}
    models = [model, *far_models(ModelRegistry(), cell, model)]  # every pair constrained
    # plan() gets no peer_bounds here, so every peer would count as silent; in cells of NeHMO
    # arms the silent-path watch never acts, so it is off
    watch_off = PlannerSettings().override({"silent_watch.lookahead": 0.0})
    planners = {
        a: NehmoPlanner(cell, a, models, watch_off, solver=solvers[a]) for a in cell.arm_ids
    }
    for scenario in _scenarios(cell_name, scenarios, 200):
        q = {a: np.array(v) for a, v in scenario.start.items()}
        for p in planners.values():
            p.reset()
        for _ in range(steps):
            commands = {}
            for a, planner in planners.items():
                solvers[a].record = a == arm
                commands[a] = planner.plan(q[a], q, scenario.goal[a]).velocity
            q = {a: q[a] + 0.1 * commands[a] for a in q}
    rows = solvers[arm].rows
    solved = [r for r in rows if r["dy"] is not None]
    constrained = [r for r in rows if r["fast"] != "naive"]
    dy = np.array([r["dy"] for r in solved])
    dcost = np.array([r["dcost"] for r in solved])
    theirs = np.array([r["authors_dy"] for r in rows if r["authors_dy"] is not None])
    t_fast = np.array([r["t_fast"] for r in constrained]) * 1e3
    t_tight = np.array([r["t_tight"] for r in constrained]) * 1e3
    return {
        "cell": cell_name,
        "peers": len(planners[arm].pairs),
        "steps": len(rows),
        "status_pairs": {
            f"{a} / {b}": n
            for (a, b), n in Counter((r["fast"], r["tight"]) for r in rows).most_common()
        },
        "both_optimal": len(solved),
        "dy_rad": {
            "median": float(np.median(dy)),
            "p95": float(np.percentile(dy, 95)),
            "max": float(dy.max()),
        },
        "relative_cost_difference_max": float(dcost.max()),
        "ipopt_authors_dy_rad": {
            "tight_optimal": sum(r["tight_optimal"] for r in rows),
            "ipopt_success": len(theirs),
            "median": float(np.median(theirs)) if len(theirs) else None,
            "p95": float(np.percentile(theirs, 95)) if len(theirs) else None,
            "max": float(theirs.max()) if len(theirs) else None,
        },
        "python_loop_same_status_and_iterations": sum(r["python_same"] for r in rows),
        "infeasible_steps": sum(r["fast"] == "infeasible" for r in rows),
        "infeasible_but_ipopt_solved": sum(bool(r["ipopt_found"]) for r in rows),
        "python_loop_dy_max_rad": max(r["python_dy"] for r in rows),
        "min_constraint_default": min(r["min_c"] for r in rows if r["min_c"] is not None),
        "constrained_solve_ms": {
            "default_median": float(np.median(t_fast)),
            "default_p95": float(np.percentile(t_fast, 95)),
            "tight_median": float(np.median(t_tight)),
            "tight_p95": float(np.percentile(t_tight, 95)),
        },
    }


def markdown(report: dict[str, Any]) -> str:
    lines = [
        "# Default SQP against a tight one, on the same problems",
        "",
        f"Default: `sqp_tol` {report['sqp_tol']:g} rad, `sqp_screen` {report['sqp_screen']:g} m. "
        "Tight: 1e-9 rad, every V row in every iteration. Same problem, warm start and Hessian; "
        "the closed loop follows the default. IPOPT (authors): tol 1e-3, at most 30 iterations, "
        "from y = 0, on the steps where the tight SQP is optimal.",
        "",
        "| cell (peers) | steps | statuses default / tight | both optimal | max joint difference "
        "median / p95 / max [rad] | max relative cost difference | min V − ε of default [m] "
        "| IPOPT (authors) − tight: successes, max joint difference median / p95 / max [rad] "
        "| constrained solve ms, default median / p95 | tight median / p95 "
        "| C loop = Python loop (status and iterations) | max C − Python step difference [rad] "
        "| default infeasible: IPOPT finds a solution |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in report["cells"]:
        d, t = c["dy_rad"], c["constrained_solve_ms"]
        pairs = ", ".join(f"{k}: {n}" for k, n in c["status_pairs"].items())
        a = c["ipopt_authors_dy_rad"]
        authors = f"{a['ipopt_success']} of {a['tight_optimal']}"
        if a["median"] is not None:
            authors += f", {a['median']:.1e} / {a['p95']:.1e} / {a['max']:.1e}"
        lines.append(
            f"| {c['cell']} ({c['peers']}) | {c['steps']} | {pairs} | {c['both_optimal']} | "
            f"{d['median']:.1e} / {d['p95']:.1e} / {d['max']:.1e} | "
            f"{c['relative_cost_difference_max']:.1e} | {c['min_constraint_default']:.1e} | "
            f"{authors} | "
            f"{t['default_median']:.2f} / {t['default_p95']:.2f} | "
            f"{t['tight_median']:.2f} / {t['tight_p95']:.2f} | "
            f"{c['python_loop_same_status_and_iterations']} of {c['steps']} | "
            f"{c['python_loop_dy_max_rad']:.1e} | "
            f"{c['infeasible_but_ipopt_solved']} of {c['infeasible_steps']} |"
        )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=4)
    parser.add_argument("--steps", type=int, default=150)
    args = parser.parse_args()
    torch.set_num_threads(1)
    vf = load_value_function("ur5_ur5", variant="bc+sym")
    model = PairValueModel.from_value_function(vf, "bench_ur5_ur5_bcsym")
    defaults = PlannerSettings()
    report = {
        "sqp_tol": defaults.solver.sqp_tol,
        "sqp_screen": defaults.solver.sqp_screen,
        "cells": [
            _cell(cell_name, arm, model, args.scenarios, args.steps) for cell_name, arm, _ in CASES
        ],
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "sqp_agreement.json").write_text(json.dumps(report, indent=2) + "\n")
    (RESULTS / "sqp_agreement.md").write_text(markdown(report))
    print(markdown(report))


if __name__ == "__main__":
    main()
