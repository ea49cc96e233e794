"""Collision rate under peer faults, through the arm_planner's own control loop (no middleware).

    python -m nehmo_ros.fault_episodes --count 20 --faults none,silent,teleport \\
        --policies fail_safe,hold,ignore --peer-planner naive --json faults.json

It lives in ``nehmo_ros`` although it imports no ROS package because it measures the node's
control loop (:mod:`nehmo_ros.control`) and parameters, not the core's planners. Every arm runs
the node's :class:`~nehmo_ros.control.ArmController` (same rules, planners built
by the node's :func:`~nehmo_ros.planners.build_planner`) against a
:class:`~nehmo_core.sim.cell_sim.CellSimulator`, in lock-step: each 40 ms tick every arm
receives joint states, ticks (the command applied during tick k was planned from tick k − 1's
states, as on the node) and the tick waits for every solve to finish, so deadline misses play
no part and only the injected fault differs between rows. Solves get a 1 s budget for the same
reason. Collisions are checked exactly, every pair, at 4 sub-steps per tick.

One arm, the *victim* (``ur5_0``), sees one *peer* (``ur5_1``) through a fault starting at
``--start`` seconds; every other view is exact:

``none``      no fault (the reference row);
``silent``    no state of the peer reaches the victim for ``--duration`` s (the peer keeps
              moving, planning with full information);
``teleport``  for ``--teleport-duration`` s the victim receives the peer's state displaced by
              ``--offset`` rad on its first three joints, then the truth again (two jumps).

The victim's policy: ``hold`` or ``fail_safe`` (the node's ``stale_policy``, with its stale and
jump tests on: ``peer_timeout`` 0.25 s, ``jump_margin`` 0.1 rad), or ``ignore`` (both tests
off: it plans against whatever it last received). With ``--peer-planner naive`` the peer does
not avoid anything, so the victim alone must keep the pair apart: the hard case for the
victim's fault handling. Scenarios: the dual-UR5 candidates of ``--seed`` in which naive
planners collide (the arms' paths cross).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from nehmo_core.errors import InvalidValueError, NehmoError, UnknownNameError
from nehmo_core.eval.episode import EpisodeSettings, reached
from nehmo_core.eval.scenario_sets import naive_collides
from nehmo_core.planning.opt.interface import Planner
from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.robots import load_cell
from nehmo_core.robots.model import Cell
from nehmo_core.sim.cell_sim import CellSimulator
from nehmo_core.sim.scenarios import Scenario, generate_scenario_set
from nehmo_ros.control import ArmController, ControlSettings
from nehmo_ros.oneline import one_line
from nehmo_ros.planners import build_planner

__all__ = ["FAULTS", "POLICIES", "FaultSettings", "run_fault_episode", "run_rows"]

FAULTS = ("none", "silent", "teleport")
POLICIES = ("fail_safe", "hold", "ignore")


@dataclass(frozen=True)
class FaultSettings:
    """One row: the fault, the victim's policy, who sees whom, when and how much."""

    fault: str = "none"
    policy: str = "hold"
    victim: str = "ur5_0"
    peer: str = "ur5_1"
    start: float = 0.4  # [s] simulated time the fault starts
    duration: float = 3.0  # [s] silence
    teleport_duration: float = 0.4  # [s] displaced states
    offset: float = 0.6  # [rad] displacement of the first three joints

    def __post_init__(self) -> None:
        if self.fault not in FAULTS:
            raise UnknownNameError("fault", self.fault, FAULTS)
        if self.policy not in POLICIES:
            raise UnknownNameError("policy", self.policy, POLICIES)
        for name in ("start", "duration", "teleport_duration"):
            if not getattr(self, name) >= 0:
                raise InvalidValueError(name, "must be >= 0 [s]", getattr(self, name))

    def view(self, observer: str, source: str, t: float, q: np.ndarray) -> np.ndarray | None:
        """What ``observer`` receives of ``source``'s true state ``q`` at ``t`` (None: nothing)."""
        if self.fault == "none" or (observer, source) != (self.victim, self.peer):
            return q
        if self.fault == "silent" and self.start <= t < self.start + self.duration:
            return None
        if self.fault == "teleport" and self.start <= t < self.start + self.teleport_duration:
            shown = q.copy()
            shown[:3] += self.offset
            return shown
        return q

    def control(self, arm_id: str) -> ControlSettings:
        """The victim's control settings per policy; every other arm runs the defaults."""
        if arm_id != self.victim:
            return ControlSettings()
        if self.policy != "ignore":
            return ControlSettings(stale_policy=self.policy)
        return ControlSettings(peer_timeout=1e9, jump_margin=math.inf)


def run_fault_episode(
    cell: Cell,
    scenario: Scenario,
    planners: Mapping[str, Planner],
    fault: FaultSettings,
    sim: CellSimulator,
    settings: EpisodeSettings | None = None,
) -> dict[str, Any]:
    """One lock-step episode; its outcome, end time and the victim's status counts."""
    s = settings or EpisodeSettings()
    dt, period_ns = s.period_ns / 1e9, s.period_ns
    sim.reset(scenario.start)
    controllers = {}
    for a in cell.arm_ids:
        planners[a].reset()
        controllers[a] = ArmController(cell, a, planners[a], fault.control(a))
    statuses: Counter[str] = Counter()
    outcome, t, pair = "stuck", 0.0, None
    try:
        for a, c in controllers.items():
            c.set_goal(cell.arm(a).robot.joint_names, list(scenario.goal[a]))
        for k in range(s.max_ticks):
            t = k * dt
            q = sim.positions()
            for a, c in controllers.items():
                for b in cell.arm_ids:
                    shown = fault.view(a, b, t, q[b])
                    if shown is not None:
                        names = cell.arm(b).robot.joint_names
                        c.update_state(b, names, list(shown), t, k * period_ns)
            decisions = {a: c.tick(t, k * period_ns) for a, c in controllers.items()}
            for c in controllers.values():
                if not c.wait_idle(60.0):
                    raise NehmoError("a solve took more than 60 s")
            statuses[decisions[fault.victim].status] += 1
            step = sim.step({a: d.velocity for a, d in decisions.items()}, dt)
            t = (k + 1) * dt
            if step.collisions:
                outcome = "collision"
                pair = sorted({tuple(sorted((c.arm_a, c.arm_b))) for c in step.collisions})
                break
            q = sim.positions()
            if reached(cell, q, scenario, s):
                outcome = "success"
                break
    finally:
        for c in controllers.values():
            c.stop()
    return {"outcome": outcome, "end_time": round(t, 3), "pairs": pair, "victim": dict(statuses)}


def run_rows(
    rows: Sequence[FaultSettings],
    count: int,
    seed: int = 0,
    peer_planner: str = "naive",
    model: str = "shipped",
    progress: bool = True,
) -> dict[str, Any]:
    """Every row on the same ``count`` scenarios; per row the episodes and the rates [%]."""
    cell = load_cell("dual_ur5")
    es = EpisodeSettings()
    with CellSimulator(cell, es.substeps, es.self_collision) as sim:
        scenarios = generate_scenario_set(
            cell, seed, count, naive_collides(cell, es, sim), max_candidates=40 * count
        )
        ps = PlannerSettings().override({"opt.deadline": 1.0})
        out: dict[str, Any] = {
            "cell": cell.name,
            "seed": seed,
            "indices": list(scenarios.indices),
            "peer_planner": peer_planner,
            "model": model,
            "rows": [],
        }
        for row in rows:
            kinds = {a: "nehmo" for a in cell.arm_ids}
            kinds[row.peer] = peer_planner
            planners = {a: build_planner(k, cell, a, model, ps) for a, k in kinds.items()}
            started = time.monotonic()
            episodes = []
            for i, scenario in enumerate(scenarios.scenarios):
                try:
                    episode = run_fault_episode(cell, scenario, planners, row, sim, es)
                except Exception as err:  # counted as a failure of its own kind; go on
                    episode = {
                        "outcome": "error",
                        "error": f"{type(err).__name__}: {one_line(err)}",
                    }
                episodes.append(episode)
                if progress:
                    print(
                        f"{row.fault}/{row.policy} {i + 1}/{count}: {episodes[-1]['outcome']}",
                        file=sys.stderr,
                        flush=True,
                    )
            outcomes = Counter(e["outcome"] for e in episodes)
            out["rows"].append(
                {
                    **asdict(row),
                    "episodes": episodes,
                    "cr": 100.0 * outcomes["collision"] / count,
                    "sr": 100.0 * outcomes["success"] / count,
                    "stuck": 100.0 * outcomes["stuck"] / count,
                    "errors": 100.0 * outcomes["error"] / count,
                    "wall_seconds": round(time.monotonic() - started, 1),
                }
            )
    return out


def markdown(result: Mapping[str, Any]) -> str:
    """The rows as a table."""
    lines = [
        f"dual_ur5, {len(result['indices'])} scenarios (seed {result['seed']}, naive collides), "
        f"victim nehmo ({result['model']}), peer {result['peer_planner']}",
        "",
        "| fault | victim policy | CR % | SR % | stuck % | errors % |",
        "|---|---|---|---|---|---|",
    ]
    for r in result["rows"]:
        policy = "—" if r["fault"] == "none" else r["policy"]
        lines.append(
            f"| {r['fault']} | {policy} | {r['cr']:.1f} | {r['sr']:.1f} | {r['stuck']:.1f} "
            f"| {r.get('errors', 0.0):.1f} |"
        )
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m nehmo_ros.fault_episodes``."""
    parser = argparse.ArgumentParser(
        prog="python -m nehmo_ros.fault_episodes", description=__doc__.split("\n\n")[0]
    )
    parser.add_argument("--count", type=int, default=20, help="scenarios per row")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--faults", default="none,silent,teleport")
    parser.add_argument("--policies", default="fail_safe,hold,ignore")
    parser.add_argument("--peer-planner", default="naive", help="the peer's planner kind")
    parser.add_argument("--model", default="shipped", help="the nehmo arms' value models")
    parser.add_argument("--start", type=float, default=0.4, help="[s] fault start")
    parser.add_argument("--duration", type=float, default=3.0, help="[s] silence")
    parser.add_argument("--teleport-duration", type=float, default=0.4, help="[s]")
    parser.add_argument("--offset", type=float, default=0.6, help="[rad] teleport displacement")
    parser.add_argument("--json", help="write the episodes and rates here")
    args = parser.parse_args(argv)
    try:
        if args.count < 1:
            raise InvalidValueError("--count", "must be >= 1", args.count)
        rows = []
        for fault in args.faults.split(","):
            policies = ["hold"] if fault == "none" else args.policies.split(",")
            for policy in policies:
                rows.append(
                    FaultSettings(
                        fault=fault,
                        policy=policy,
                        start=args.start,
                        duration=args.duration,
                        teleport_duration=args.teleport_duration,
                        offset=args.offset,
                    )
                )
        result = run_rows(rows, args.count, args.seed, args.peer_planner, args.model)
    except NehmoError as err:
        print(f"fault_episodes: error: {one_line(err)}", file=sys.stderr)
        return 2
    if args.json:
        with open(args.json, "w") as handle:
            json.dump(result, handle, indent=1)
    print(markdown(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
