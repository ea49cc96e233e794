"""Why NeHMO episodes end stuck: each stuck episode of the fresh tables, sorted by what held it.

    ./run python bench/stuck_reasons.py --seeds 41,42   # bench/results/stuck_reasons.{json,md}
    ./run python bench/stuck_reasons.py --run OUT --out NAME   # bench/results/NAME.{json,md}

With ``--seeds``: the ``nehmo`` rows of the fresh tables (``bench/results/fresh/seed<S>/``; the
logs are where those runs wrote them). With ``--run``: every row of one ``nehmo evaluate`` output
folder (its ``summary.json`` and logs), by arm count for task sets (``--tasks``). For each stuck
episode, with exact PyBullet distances:

- ``goals closer than the floor``: with every arm at its goal, some pair is closer than the floor
  against settled peers (``settled_epsilon``: 1 cm; 2 cm when seeds 41 and 42 ran, 5 cm up to
  seed 40), so no planner that keeps it can finish exactly;
- ``herded``: a stalled arm (> 0.1 rad from its goal at the end) ran its fail-safe in at least
  ``HERDED`` (half) of its plan() calls: a peer kept it where no step of its own kept its V row
  (often an arm whose near link sits by its own base), whatever the arms' last poses;
- ``blocked by a settled peer``: at the end an arm is within ``hold_tolerance`` of its goal
  (settled) and a peer still far from its own (> 0.1 rad) is within 0.2 m of it;
- ``mutual block``: no arm near a stalled arm is settled, but two arms are within 0.2 m;
- ``alone``: the stalled arm is farther than 0.2 m from every other (a local minimum of its own
  goal cost under the self-clearance rows, or a joint limit).
"""

from __future__ import annotations

import argparse
import itertools
import json
from collections import Counter
from pathlib import Path

from nehmo_core.eval.episode_log import read_episode_log
from nehmo_core.eval.metrics import goal_distance
from nehmo_core.eval.scenario_sets import goal_separation
from nehmo_core.geometry.pybullet_world import CellWorld
from nehmo_core.planning.settings import PlannerSettings

RESULTS = Path(__file__).resolve().parent / "results"
SETUPS = {
    "dual_ur5": ("table_II_dual_ur5.json", "nehmo"),
    "triple_ur5": ("table_III_triple_ur5.json", "nehmo"),
    "five_ur5": ("table_III_five_ur5.json", "nehmo"),
    "ur5_kinova_challenging": ("table_IV_ur5_kinova_challenging.json", "nehmo/nehmo"),
}
NEAR, FAR_FROM_GOAL = 0.2, 0.1  # [m], [rad]
# share of a stalled arm's plan() calls in its fail-safe (in dual_panda, seeds 60, 83, 84: the
# arm most in its fail-safe ran it in 14-20 % of its calls in the median success, 32-39 % at the
# 90th percentile, 56-100 % in most stuck episodes)
HERDED = 0.5
FLOOR = PlannerSettings().hold.settled_epsilon  # [m]
REASONS = (
    f"goals closer than {FLOOR * 100:g} cm",
    "herded",
    "blocked by a settled peer",
    "mutual block",
    "alone",
)


def reason(path: str, world: CellWorld | None) -> tuple[str, CellWorld]:
    log = read_episode_log(path)
    w = world or CellWorld(log.cell)
    ids = list(log.cell.arm_ids)
    pairs = list(itertools.combinations(ids, 2))
    if goal_separation(w, {a: log.goals[a] for a in ids}) < FLOOR:
        return REASONS[0], w
    final = {a: log.positions[a][-1] for a in ids}
    w.set_configuration(final)
    dist = {frozenset(p): w.distance(*p) for p in pairs}
    err = {a: goal_distance(final[a], log.goals[a], log.cell, a, "l2") for a in ids}
    settled = {a for a in ids if err[a] < PlannerSettings().hold.tolerance}
    stalled = [a for a in ids if err[a] > FAR_FROM_GOAL]
    for a in stalled:
        calls = [s.telemetry.fail_safe for _, s in log.statuses.get(a, [])]
        if calls and sum(calls) >= HERDED * len(calls):
            return REASONS[1], w
    for a in stalled:
        if any(b in settled and dist[frozenset((a, b))] < NEAR for b in ids if b != a):
            return REASONS[2], w
    if any(dist[frozenset((a, b))] < NEAR for a in stalled for b in ids if b != a):
        return REASONS[3], w
    return REASONS[4], w


def episodes_by_row(run: Path) -> list[tuple[str, int, list[dict]]]:
    """``(row, arm count, episodes)`` of one ``nehmo evaluate`` output, each episode's ``log``
    found where the run wrote it (relative paths are resolved inside ``run``)."""
    summary = json.loads((run / "summary.json").read_text())
    out = []
    for row in summary["rows"]:
        groups: dict[int, list[dict]] = {}
        for e in row["episodes"]:
            log = Path(e["log"])
            if not log.is_absolute() and not log.exists():  # relative to where it ran
                log = next(run.glob(f"logs/*/{log.name}"), log)
            groups.setdefault(int(e.get("arms", 0)), []).append({**e, "log": str(log)})
        out += [(row["row"], arms, episodes) for arms, episodes in sorted(groups.items())]
    return out


def by_run(run: Path, name: str) -> int:
    """The stuck episodes of every row of one ``nehmo evaluate`` output, by arm count."""
    out: dict[str, dict[str, dict[str, int]]] = {}
    lines = [
        f"# Why episodes end stuck: `{run.name}`",
        "",
        f"Written by `./run python bench/stuck_reasons.py --run OUT --out {name}`, OUT the "
        "evaluation's output folder (definitions in its docstring).",
        "",
        "| row | arms | episodes | stuck | " + " | ".join(REASONS) + " |",
        "|---|---|---|---|" + "---|" * len(REASONS),
    ]
    for row, arms, episodes in episodes_by_row(run):
        counts: Counter[str] = Counter()
        for e in episodes:
            if e["outcome"] == "stuck":
                why, world = reason(e["log"], None)  # each task has its own cell
                world.close()
                counts[why] += 1
        out.setdefault(row, {})[str(arms)] = dict(counts)
        lines.append(f"| {row} | {arms or '-'} | {len(episodes)} | {_cells(counts)}")
        print(lines[-1], flush=True)
    _write(name, out, lines)
    return 0


def _cells(counts: Counter[str]) -> str:
    """A table row's end: the stuck count, then the count of each reason."""
    return (
        " | ".join(str(n) for n in (sum(counts.values()), *(counts.get(r, 0) for r in REASONS)))
        + " |"
    )


def _write(name: str, out: dict, lines: list[str]) -> None:
    (RESULTS / f"{name}.json").write_text(json.dumps(out, indent=2) + "\n")
    (RESULTS / f"{name}.md").write_text("\n".join(lines) + "\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", default="41,42")
    parser.add_argument("--run", type=Path, help="an evaluation's output folder (summary.json)")
    parser.add_argument("--out", default="stuck_reasons_run", help="result name (with --run)")
    args = parser.parse_args()
    if args.run is not None:
        return by_run(args.run, args.out)
    out: dict[str, dict[str, dict[str, int]]] = {}
    lines = [
        "# Why NeHMO episodes end stuck",
        "",
        "Stuck episodes of the `nehmo` rows of the fresh tables (100 episodes per setup and seed), "
        "sorted by `bench/stuck_reasons.py` (definitions in its docstring).",
        "",
        "| setup | seed | stuck | " + " | ".join(REASONS) + " |",
        "|---|---|---|" + "---|" * len(REASONS),
    ]
    for seed in (int(s) for s in args.seeds.split(",")):
        for setup, (name, row_name) in SETUPS.items():
            table = json.loads((RESULTS / "fresh" / f"seed{seed}" / name).read_text())
            row = next(r for r in table["rows"] if r["row"] == row_name)
            world = None
            counts: Counter[str] = Counter()
            for e in row["episodes"]:
                if e["outcome"] == "stuck":
                    why, world = reason(e["log"], world)
                    counts[why] += 1
            if world is not None:
                world.close()
            out.setdefault(setup, {})[str(seed)] = dict(counts)
            lines.append(f"| {setup} | {seed} | {_cells(counts)}")
            print(lines[-1], flush=True)
    _write("stuck_reasons", out, lines)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
