"""Planning speed of NeHMO on one thread, with CHOMP and the evaluation floor, side by side.

    OMP_NUM_THREADS=1 ./run python bench/planning_speed.py   # writes bench/results/planning_speed.*
    ... --repeats 1   # one pass (~4 min); the default 3 passes show how far the ratio moves

For 1, 2 and 4 peers (the dual-UR5 cell, and the centre arm of the three- and five-UR5 cells)
every arm runs NeHMO on scenarios sampled by the paper's protocol where the naive planner
collides (so the safety constraints matter), for ``--steps`` steps at 10 Hz. Reported per step
of the arm with that many peers: median, p95 and max of the plan() wall time, solver statuses
and fail-safe rate; the time of one batched ``V``/``∇V`` evaluation of all its peers (the floor
any solver pays at least once per step) and the ratio to it; CHOMP's centralized plan time on the
same scenarios and its ratio to NeHMO's per-step time; and IPOPT (the authors' solver) per step
on the dual cell for reference. The generated C stores each weight matrix once, as float, and
multiplies through it in float (``codegen.compact_weights``, the planner's default); the same
evaluation with CasADi's own layout (every matrix twice, as double, double products) runs beside
it, as a floor per peer count and as a full ``nehmo`` row on the dual
cell (``nehmo, CasADi layout``).

Value model: the shipped ``ur5_ur5`` ``bc+sym`` value function (``--model random`` for a
SIREN 3×128 with random weights: speed does not depend on the weights, but the constraint's
activity does). Steps where the naive step is already safe cost one evaluation; constrained steps
cost a few SQP iterations, so the distribution is bimodal and both kinds of step are reported
on their own as well. Two planners side by side on the same scenarios: ``nehmo`` (the default
settings: Opt plus the self-clearance rows, whose exact self-distances and Jacobians every step
pays for, and the stall escape) and ``nehmo_paper`` (the paper's Opt). Two more rows isolate
the solver: ``nehmo, Python SQP loop`` (the same SQP iterating in Python instead of C, same
answers) and ``nehmo, tight SQP`` (``sqp_tol`` 1e-7 rad, no screening); ``nehmo, no speed
bounds, single fail-safe`` is ``nehmo`` without the announced speed bounds and with the paper's
fail-safe (what those two cost). Like the planner nodes,
the bench freezes its long-lived objects out of the garbage collector before timing.
``planning_speed.png`` shows the step times of ``nehmo`` and ``nehmo_paper`` per cell as
histograms, naive-safe and constrained steps stacked, with the median and p95 marked.

The timed arm's peers all sit at the 0.6 m of the ``ur5_ur5`` model. The other arms of the three-
and five-UR5 cells also face peers at 0.85 m and 1.2 m; with ``--model shipped`` they carry the
cell's other shipped pair models for those (``ur5_ur5_diag``, ``ur5_ur5_opposite``), so every
pair of the closed loop is constrained, as in the evaluation. With ``--model random`` only the
0.6 m pairs are (the random stand-in exists for that pair only).
"""

from __future__ import annotations

import argparse
import gc
import itertools
import json
import math
import os
import platform
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import torch
from _report import cpu_model

from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.hjr import load_value_function
from nehmo_core.hjr.casadi_export import value_functions
from nehmo_core.planning.baselines.chomp import plan_chomp
from nehmo_core.planning.models.registry import ModelRegistry
from nehmo_core.planning.models.synthetic import planning_distance_model, random_value_function
from nehmo_core.planning.models.value_model import PairValueModel
from nehmo_core.planning.nehmo import NehmoPlanner
from nehmo_core.planning.numerics.codegen import compile_function
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.robots.model import Cell
from nehmo_core.sim.scenarios import Scenario, sample_scenario

RESULTS = Path(__file__).resolve().parent / "results"
CASES = (("dual_ur5", "ur5_0", 1), ("triple_ur5", "ur5_0", 2), ("five_ur5", "ur5_0", 4))
# plan() is called without peer_bounds here, so every peer counts as one that announces nothing;
# in cells of NeHMO arms all peers announce and the silent-path watch never acts: it is off
WATCH_OFF = PlannerSettings().override({"silent_watch.lookahead": 0.0})
VARIANTS = {
    "nehmo": WATCH_OFF,
    "nehmo, Python SQP loop": WATCH_OFF.override({"solver.sqp_native": False}),
    "nehmo, tight SQP": WATCH_OFF.override({"solver.sqp_tol": 1e-7, "solver.sqp_screen": math.inf}),
    "nehmo, no speed bounds": WATCH_OFF.override({"hold.bound": 1.0}),
    "nehmo_paper": PlannerSettings.preset("paper"),
}


def _naive_collides(world: CellWorld, scenario: Scenario, steps: int) -> bool:
    q = {a: np.array(v) for a, v in scenario.start.items()}
    for _ in range(steps):
        for a in q:
            q[a] = q[a] + np.clip(scenario.goal[a] - q[a], -0.05, 0.05)
        world.set_configuration(q)
        if world.in_collision(self_collision=False):
            return True
    return False


def _scenarios(cell_name: str, count: int, steps: int) -> list[Scenario]:
    cell = load_cell(cell_name)
    out: list[Scenario] = []
    with CellWorld(cell) as world:
        seed = 0
        while len(out) < count and seed < 500:
            scenario = sample_scenario(cell, np.random.default_rng(seed), world)
            seed += 1
            if _naive_collides(world, scenario, steps):
                out.append(scenario)
    return out


def _episode(
    cell_name: str, planners: dict[str, Any], scenario: Scenario, steps: int, arm: str
) -> tuple[list[float], list[str], list[int]]:
    q = {a: np.array(v) for a, v in scenario.start.items()}
    for p in planners.values():
        p.reset()
    times, statuses, iterations = [], [], []
    for _ in range(steps):
        commands = {}
        for a, planner in planners.items():
            result = planner.plan(q[a], q, scenario.goal[a])
            commands[a] = result.velocity
            if a == arm:
                times.append(result.telemetry.solve_time)
                statuses.append(result.telemetry.status)
                iterations.append(result.telemetry.iterations)
        q = {a: q[a] + 0.1 * commands[a] for a in q}
    return times, statuses, iterations


def far_models(registry: ModelRegistry, cell: Cell, model: PairValueModel) -> list[PairValueModel]:
    """The cell's shipped pair models for base distances other than ``model``'s (the outer
    arms' far peers), so that every pair of the closed loop is constrained."""
    return [
        m
        for m in registry.models_for("nehmo", cell)
        if not np.allclose(m.base2.xyz, model.base2.xyz)
    ]


def _floor(model: PairValueModel, peers: int, repeats: int = 2000) -> float:
    x = np.random.default_rng(0).uniform(-np.pi, np.pi, size=(peers, model.state_dim))
    model.evaluate(0.1, x)
    samples = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        model.evaluate(0.1, x)
        samples.append(time.perf_counter() - t0)
    return float(np.median(samples))


def _stats(times: list[float]) -> dict[str, float]:
    t = np.array(times) * 1e3
    return {
        "median_ms": float(np.median(t)),
        "p95_ms": float(np.percentile(t, 95)),
        "max_ms": float(t.max()),
        "mean_ms": float(t.mean()),
    }


def _summarize(
    report: dict[str, Any],
    case: tuple[str, str, int],
    kind: str,
    used: PairValueModel,
    plain: PairValueModel,
    timed: tuple[list[float], list[str], list[int]],
    chomp_times: list[float],
    scenarios: int,
) -> None:
    cell_name, _, peers = case
    times, statuses, iterations = timed
    floor = _floor(used, peers)
    stats = _stats(times)
    counts = {k: statuses.count(k) for k in sorted(set(statuses))}
    constrained = [t for t, s in zip(times, statuses, strict=True) if s != "naive"]
    naive = [t for t, s in zip(times, statuses, strict=True) if s == "naive"]
    sqp_iters = [i for i, s in zip(iterations, statuses, strict=True) if s != "naive"]
    report["cases"][f"{cell_name} {kind}"] = {
        "cell": cell_name,
        "planner": kind,
        "peers": peers,
        "scenarios": scenarios,
        "steps": len(times),
        "nehmo": stats,
        "nehmo_constrained_steps": _stats(constrained) if constrained else None,
        "nehmo_naive_steps": _stats(naive) if naive else None,
        "constrained_share": len(constrained) / len(times),
        "sqp_iterations_constrained": {
            "median": float(np.median(sqp_iters)) if sqp_iters else None,
            "p95": float(np.percentile(sqp_iters, 95)) if sqp_iters else None,
        },
        "statuses": counts,
        "by_status": {
            k: _stats([t for t, s in zip(times, statuses, strict=True) if s == k]) for k in counts
        },
        "fail_safe_rate": float(np.mean([s not in ("naive", "optimal") for s in statuses])),
        "p95_over_median": stats["p95_ms"] / stats["median_ms"],
        "floor_batched_v_grad_ms": floor * 1e3,
        "floor_casadi_layout_ms": _floor(plain, peers) * 1e3,
        "median_over_floor": stats["median_ms"] / (floor * 1e3),
        "chomp_plan_median_s": float(np.median(chomp_times)),
        "chomp_over_nehmo_step": float(np.median(chomp_times)) / (stats["median_ms"] / 1e3),
    }
    print(cell_name, kind, json.dumps(report["cases"][f"{cell_name} {kind}"]))


Steps = dict[str, tuple[list[float], list[str], list[int]]]


def _pass(
    cell_name: str,
    planners: dict[str, dict[str, Any]],
    scenarios: list[Scenario],
    steps: int,
    arm: str,
) -> Steps:
    """Every variant's closed loops once, by variant. The variants take turns scenario by
    scenario, so a drift in the machine's speed reaches all of them alike."""
    out: Steps = {kind: ([], [], []) for kind in planners}
    for scenario in scenarios:
        for kind, arms in planners.items():
            t, s, it = _episode(cell_name, arms, scenario, steps, arm)
            out[kind][0].extend(t)
            out[kind][1].extend(s)
            out[kind][2].extend(it)
    return out


def run(
    scenarios: int, steps: int, model_kind: str, repeats: int = 1
) -> tuple[dict[str, Any], Steps]:
    """The report, and every timed step (seconds, status, iterations) by ``"<cell> <planner>"``
    of the first pass. ``repeats`` > 1 runs the closed loops again that many times in all (the
    same work: planners reset per episode) and reports p95/median per pass."""
    torch.set_num_threads(1)
    if model_kind == "shipped":
        vf = load_value_function("ur5_ur5", variant="bc+sym")
        description = "shipped ur5_ur5 bc+sym"
        distance_source = "shipped"
    else:
        _, distance_source = planning_distance_model("ur5_ur5")
        vf = random_value_function("ur5_ur5", "bc+sym")
        description = "bc+sym SIREN 3x128, random weights (residual x0.05)"
    model = PairValueModel.from_value_function(vf, "bench_ur5_ur5_bcsym")
    _, graph = value_functions(vf, "bench_ur5_ur5_bcsym")
    plain_code = compile_function(graph, "compiled", compact=False)
    plain = replace(model, value_grad=plain_code.function, library=plain_code.library, _calls={})
    report: dict[str, Any] = {
        "machine": f"{platform.machine()} ({cpu_model()})",
        "cpu_count": os.cpu_count(),
        "load_average_at_start": os.getloadavg(),
        "threads": torch.get_num_threads(),
        "value_model": description,
        "distance_model": distance_source,
        "backend": model.backend,
        "settings": WATCH_OFF.to_dict(),
        "steps_per_scenario": steps,
        "cases": {},
    }
    chomp: dict[str, list[float]] = {}
    variants: list[tuple[tuple[str, str, int], str, PlannerSettings, PairValueModel]] = [
        (case, kind, settings, model)
        for case, (kind, settings) in itertools.product(CASES, VARIANTS.items())
    ]
    variants.insert(1, (CASES[0], "nehmo, CasADi layout", VARIANTS["nehmo"], plain))
    timed: Steps = {}  # by "<cell> <planner>"
    registry = ModelRegistry()
    for case in CASES:
        cell_name, arm, peers = case
        cell = load_cell(cell_name)
        chosen = _scenarios(cell_name, scenarios, 200)
        mine = [(kind, settings, used) for c, kind, settings, used in variants if c == case]
        far = far_models(registry, cell, model) if model_kind == "shipped" else []
        planners = {
            kind: {a: NehmoPlanner(cell, a, [used, *far], settings) for a in cell.arm_ids}
            for kind, settings, used in mine
        }
        assert all(len(p[arm].pairs) == peers for p in planners.values())
        timed_models = {
            p[arm].pairs[q].model_index for p in planners.values() for q in p[arm].pairs
        }
        assert timed_models == {0}, "the timed arm's peers must all use the bench's model"
        if model_kind == "shipped":
            assert all(not p.peers_unmodelled for ps in planners.values() for p in ps.values())
        # as the planner nodes do after start-up: long-lived objects out of the collector's
        # reach, so a full collection does not land inside a timed step
        gc.collect()
        gc.freeze()

        # passes after the first repeat the same work: how much of the ratio is the machine's
        passes = [_pass(cell_name, planners, chosen, steps, arm) for _ in range(repeats)]
        chomp[cell_name] = [
            plan_chomp(cell, scenario.start, scenario.goal).plan_time for scenario in chosen
        ]
        for kind, _, used in mine:
            done = timed[f"{cell_name} {kind}"] = passes[0][kind]
            _summarize(report, case, kind, used, plain, done, chomp[cell_name], len(chosen))
            runs = [p[kind] for p in passes]
            c = report["cases"][f"{cell_name} {kind}"]
            c["p95_over_median_per_pass"] = [
                float(np.percentile(t, 95) / np.median(t)) for t, _, _ in runs
            ]
            c["passes_same_statuses"] = all(r[1] == runs[0][1] for r in runs)
    # IPOPT, the authors' solver, on the dual cell for reference
    cell = load_cell("dual_ur5")
    ipopt = {
        a: NehmoPlanner(cell, a, [model], WATCH_OFF.override({"solver.name": "ipopt"}))
        for a in cell.arm_ids
    }
    scenario = _scenarios("dual_ur5", 1, 200)[0]
    t, s, _ = _episode("dual_ur5", ipopt, scenario, min(steps, 100), "ur5_0")
    report["ipopt_dual_one_scenario"] = {**_stats(t), "statuses": {k: s.count(k) for k in set(s)}}
    return report, timed


def plot(report: dict[str, Any], steps: Steps, path: Path) -> None:
    """Step-time histograms of ``nehmo`` and ``nehmo_paper`` per cell, naive-safe and
    constrained steps stacked, with the median and p95 marked: where the ratio comes from."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    planners = ("nehmo", "nehmo_paper")
    fig, axes = plt.subplots(
        len(planners), len(CASES), figsize=(4.2 * len(CASES), 5.6), squeeze=False
    )
    for row, planner in enumerate(planners):
        for col, (cell_name, _, peers) in enumerate(CASES):
            ax = axes[row][col]
            key = f"{cell_name} {planner}"
            times, statuses, _ = steps[key]
            t = np.array(times) * 1e3
            naive = np.array([s == "naive" for s in statuses])
            bins = np.geomspace(max(t.min(), 1e-3), t.max(), 40)
            ax.hist(
                [t[naive], t[~naive]],
                bins=bins,
                stacked=True,
                color=["#9cc3e4", "#c0392b"],
                label=["naive step safe", "constrained (SQP or fail-safe)"],
            )
            case = report["cases"][key]["nehmo"]
            for value, style, name in (
                (case["median_ms"], "-", "median"),
                (case["p95_ms"], "--", "p95"),
            ):
                ax.axvline(value, color="black", linestyle=style, linewidth=1, label=name)
            ax.set_xscale("log")
            ax.xaxis.set_major_locator(
                ticker.FixedLocator([0.05, 0.1, 0.2, 0.3, 0.5, 1, 2, 3, 5, 10, 20])
            )
            ax.xaxis.set_major_formatter(ticker.FormatStrFormatter("%g"))
            ax.xaxis.set_minor_formatter(ticker.NullFormatter())
            ax.set_xlim(bins[0] / 1.1, bins[-1] * 1.1)
            ratio = case["p95_ms"] / case["median_ms"]
            ax.set_title(f"{planner}, {peers} peer(s): p95/median {ratio:.2f}", fontsize=9)
            ax.set_xlabel("step time [ms]")
            ax.set_ylabel("steps")
            if row == 0 and col == 0:
                ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def _status_times(case: dict[str, Any], status: str) -> str:
    t = case["by_status"][status]
    return f"{status} {case['statuses'][status]} ({t['median_ms']:.2f} / {t['p95_ms']:.2f})"


def markdown(report: dict[str, Any]) -> str:
    lines = [
        "# Planning speed (one thread)",
        "",
        f"Machine: {report['machine']}, {report['cpu_count']} cores, load average at start "
        f"{tuple(round(x, 2) for x in report['load_average_at_start'])}. "
        f"V/∇V backend: {report['backend']}; value model: {report['value_model']}; distance: "
        f"{report['distance_model']}.",
        "",
        "| cell (peers) | planner | steps | median ms | p95 ms | max ms | p95/median "
        "| constrained steps | naive-safe median / p95 ms | constrained median / p95 ms "
        "| SQP iterations median / p95 "
        "| fail-safe | floor ms | median/floor | CHOMP s | CHOMP/NeHMO step |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for c in report["cases"].values():
        n, k, v = c["nehmo"], c["nehmo_constrained_steps"], c.get("nehmo_naive_steps")
        con = f"{k['median_ms']:.2f} / {k['p95_ms']:.2f}" if k else "-"
        nai = f"{v['median_ms']:.2f} / {v['p95_ms']:.2f}" if v else "-"
        it = c["sqp_iterations_constrained"]
        its = f"{it['median']:.0f} / {it['p95']:.0f}" if it["median"] is not None else "-"
        lines.append(
            f"| {c['cell']} ({c['peers']}) | {c['planner']} | {c['steps']} | "
            f"{n['median_ms']:.2f} | {n['p95_ms']:.2f} | "
            f"{n['max_ms']:.1f} | {c['p95_over_median']:.2f} | {c['constrained_share']:.0%} | "
            f"{nai} | {con} | {its} | {c['fail_safe_rate']:.1%} | "
            f"{c['floor_batched_v_grad_ms']:.3f} | {c['median_over_floor']:.1f} | "
            f"{c['chomp_plan_median_s']:.2f} | {c['chomp_over_nehmo_step']:.0f} |"
        )
    lines += [
        "",
        "p95/median over passes through the same closed loops (the table is the first pass; "
        "same statuses: every pass did the same work, step for step):",
        "",
        "| cell (peers) | planner | p95/median per pass | same statuses |",
        "|---|---|---|---|",
    ]
    for c in report["cases"].values():
        per_pass = " / ".join(f"{r:.2f}" for r in c["p95_over_median_per_pass"])
        same = "yes" if c["passes_same_statuses"] else "no"
        lines.append(f"| {c['cell']} ({c['peers']}) | {c['planner']} | {per_pass} | {same} |")
    lines += [
        "",
        "![Step-time histograms: naive-safe and constrained steps, median and p95]"
        "(planning_speed.png)",
    ]
    ip = report["ipopt_dual_one_scenario"]
    floors = {c["peers"]: c for c in report["cases"].values() if c["planner"] == "nehmo"}
    lines += [
        "",
        "One batched V/∇V evaluation, float weights stored once vs CasADi's layout (every "
        "matrix twice, as double): "
        + "; ".join(
            f"{p} peer(s) {c['floor_batched_v_grad_ms']:.3f} vs {c['floor_casadi_layout_ms']:.3f} "
            f"ms ({c['floor_casadi_layout_ms'] / c['floor_batched_v_grad_ms']:.1f}×)"
            for p, c in sorted(floors.items())
        )
        + ".",
        "",
        f"IPOPT (authors' settings) on one dual-UR5 scenario: median {ip['median_ms']:.1f} ms, "
        f"p95 {ip['p95_ms']:.1f} ms per step; statuses {ip['statuses']}.",
        "",
        "Statuses per case, with each status's steps' median / p95 ms: "
        + "; ".join(
            f"{k}: " + ", ".join(_status_times(c, s) for s in c["statuses"])
            for k, c in report["cases"].items()
        ),
        "",
    ]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenarios", type=int, default=8)
    parser.add_argument("--steps", type=int, default=150)
    parser.add_argument("--model", choices=("shipped", "random"), default="shipped")
    parser.add_argument(
        "--repeats",
        type=int,
        default=3,
        help="passes over the same closed loops, for the spread of p95/median (default 3)",
    )
    args = parser.parse_args()
    if args.repeats < 1:
        parser.error(f"--repeats must be >= 1; got {args.repeats}")
    report, steps = run(args.scenarios, args.steps, args.model, args.repeats)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "planning_speed.json").write_text(json.dumps(report, indent=2) + "\n")
    (RESULTS / "planning_speed.md").write_text(markdown(report))
    plot(report, steps, RESULTS / "planning_speed.png")
    print(markdown(report))


if __name__ == "__main__":
    main()
