"""What a frozen peer leaves free: the path of each stuck episode's stalled arm with its peers
standing still.

    ./run python bench/frozen_peer_paths.py --runs OUT1,OUT2 --out NAME  # results/NAME.{json,md}

For every stuck episode of ``nehmo evaluate`` output folders (each row, by arm count): the first
stall, from ``START`` s on, checked every ``EVERY`` s, is the first arm more than ``FAR`` rad from
its goal that gains less than ``GAIN`` rad over the next ``WINDOW`` s. From that tick RRT-Connect
plans for the stalled arm alone, every other arm frozen where it stands
(:func:`~nehmo_core.planning.baselines.ompl.plan_arm_alone`: ``--clearance`` from the frozen
arms, no self-collision, ``--search`` s). Each stall is one of:

- ``straight``: a path as long as the straight line to the goal (within 1 %): where the peers
  stand does not block it, the rows against their worst case do;
- ``detour``: a longer path (its length in rad, summed over segments, is listed);
- ``goal blocked`` / ``start blocked``: the goal, or where the arm stands, is within the
  clearance of a frozen arm (nothing is searched);
- ``not found`` within the search time; ``no stall``: no arm met the rule.
"""

from __future__ import annotations

import argparse
import json
from collections import Counter
from pathlib import Path

import numpy as np
from stuck_reasons import RESULTS, episodes_by_row

from nehmo_core.eval.episode_log import EpisodeLog, read_episode_log
from nehmo_core.eval.metrics import goal_distance
from nehmo_core.planning.baselines.ompl import plan_arm_alone

START, EVERY, WINDOW = 3.0, 0.4, 2.0  # [s]
FAR, GAIN = 0.3, 0.1  # [rad]
KINDS = ("straight", "detour", "goal blocked", "start blocked", "not found", "no stall")


def first_stall(log: EpisodeLog) -> tuple[float, str, dict[str, np.ndarray], np.ndarray] | None:
    """``(time [s], arm, every arm's joints, the arm's goal)`` at an episode's first stall."""
    stamps = np.asarray(log.stamps, float) * 1e-9
    for t in np.arange(START, stamps[-1] - WINDOW, EVERY):
        k, k2 = (int(np.searchsorted(stamps, x)) for x in (t, t + WINDOW))
        for arm in log.cell.arm_ids:
            e0, e1 = (
                goal_distance(log.positions[arm][i], log.goals[arm], log.cell, arm, "l2")
                for i in (k, k2)
            )
            if e0 > FAR and e0 - e1 < GAIN:
                configuration = {a: np.asarray(log.positions[a][k]) for a in log.cell.arm_ids}
                return float(stamps[k]), arm, configuration, np.asarray(log.goals[arm])
    return None


def probe(path: str, clearance: float, search: float) -> dict:
    """One stuck episode's first stall and what RRT-Connect finds from it."""
    log = read_episode_log(path)
    stall = first_stall(log)
    if stall is None:
        return {"kind": "no stall"}
    t, arm, configuration, goal = stall
    found = plan_arm_alone(log.cell, arm, configuration, goal, clearance, search)
    straight = float(np.linalg.norm(goal - configuration[arm]))
    if found.blocked:
        kind = f"{found.blocked} blocked"
    elif not found.solved:
        kind = "not found"
    else:
        kind = "straight" if found.length <= 1.01 * straight + 1e-6 else "detour"
    return {
        "kind": kind,
        "t": round(t, 2),
        "arm": arm,
        "goal_error": round(straight, 3),
        "length": round(found.length, 3),
        "search_s": round(found.plan_time, 3),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", required=True, help="comma-separated evaluation output folders")
    parser.add_argument("--out", required=True, help="result name under bench/results/")
    parser.add_argument("--clearance", type=float, default=0.11, help="[m] from frozen arms")
    parser.add_argument("--search", type=float, default=2.0, help="[s] of RRT-Connect per stall")
    args = parser.parse_args()
    lines = [
        "# What a frozen peer leaves free",
        "",
        f"`./run python bench/frozen_peer_paths.py --runs OUT1,... --out {args.out} --clearance "
        f"{args.clearance:g} --search {args.search:g}` (rules in its docstring): each stuck "
        "episode's first stall, the stalled arm planned alone with every other arm frozen.",
        "",
        "| run | row | arms | stuck | " + " | ".join(KINDS) + " |",
        "|---|---|---|---|" + "---|" * len(KINDS),
    ]
    out: dict[str, dict[str, list[dict]]] = {}
    runs = [Path(r) for r in args.runs.split(",") if r]
    for run, (row, arms, episodes) in ((r, x) for r in runs for x in episodes_by_row(r)):
        found = []
        for e in episodes:
            if e["outcome"] == "stuck":
                name = Path(e["log"]).name
                found.append(
                    {"episode": e.get("task", name), **probe(e["log"], args.clearance, args.search)}
                )
                print(row, arms, found[-1], flush=True)
        out.setdefault(f"{run.name} {row}", {})[str(arms)] = found
        counts = Counter(f["kind"] for f in found)
        cells = " | ".join(str(counts.get(k, 0)) for k in KINDS)
        lines.append(f"| {run.name} | {row} | {arms or '-'} | {len(found)} | {cells} |")
    detours = [
        f for rows in out.values() for fs in rows.values() for f in fs if f["kind"] == "detour"
    ]
    if detours:
        lengths = ", ".join(f"{f['length']:.1f}" for f in detours)
        lines += ["", f"Detour lengths [rad, summed over segments]: {lengths}."]
    (RESULTS / f"{args.out}.json").write_text(json.dumps(out, indent=1) + "\n")
    (RESULTS / f"{args.out}.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
