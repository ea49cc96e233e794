"""Where the planner takes a pair: the cells and episodes of a build's visited-state certificates.

The uniform certificate (``certify:<game>``) speaks of the whole joint box, most of which the
planner never meets. After it, ``nehmo pair build`` runs the ``nehmo`` planner with the pair's
fresh models on small two-arm cells (``visit``) and certifies every value function again on the
pair states of those episodes (``certify-visited:<game>``: ``nehmo verify --distribution
visited`` at the planner's ``t_safe``). The card then holds both levels, and the planner keeps the
larger (:class:`~nehmo_core.planning.models.margins.CertifiedMargins`).

The cells (:func:`visit_cells`): the first robot at the origin facing +x; the second on the x axis
at :data:`LAYOUTS`' shares of the two arms' mean reach (clipped into the pair's base range),
turned by the stated yaw, so the arms face each other, stand at an angle and stand side by side.
Each runs ``episodes`` scenarios of its own seed (the build's seed + :data:`SEED_OFFSET` + the
layout's index); every command is recorded in the pair card.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

import yaml

if TYPE_CHECKING:
    from nehmo_core.pairs.build import PairBuild

__all__ = [
    "LAYOUTS",
    "SEED_OFFSET",
    "certify_stage",
    "summary_figures",
    "visit_cells",
    "visit_stage",
    "write_cells",
]

Stage = tuple[list[str], dict[str, Any]]  # a stage's commands as typed and its figures

LAYOUTS: tuple[tuple[float, float], ...] = (
    (0.6, math.pi),  # facing, close: the dual-arm cells of the paper at 0.6 m for 1 m reach
    (0.9, 0.75 * math.pi),  # at an angle
    (1.2, 0.5 * math.pi),  # side by side, far: only the outstretched arms meet
)
"""(base distance as a share of the two arms' mean reach, yaw of the second arm [rad])."""
SEED_OFFSET = 5005
CERTIFY_ATTEMPTS = 8
"""``nehmo verify --attempts`` of a build's certificates: levels tried 1 cm apart above the searched
one (β split among them); three left the rebuilt Panda pair 0.15 points above α = 1 %."""


def visit_cells(
    robots: tuple[str, str], reaches: tuple[float, float], base_range: tuple[float, float]
) -> list[dict[str, Any]]:
    """The cells of the visit stage, as the dicts of cell YAML files."""
    low, high = base_range
    mean_reach = 0.5 * (reaches[0] + reaches[1])
    ids = (f"{robots[0]}_0", f"{robots[1]}_{1 if robots[0] == robots[1] else 0}")
    cells = []
    for i, (share, yaw) in enumerate(LAYOUTS):
        distance = round(min(max(share * mean_reach, low), high), 3)
        cells.append(
            {
                "name": f"visit_{i}",
                "arms": [
                    {"id": ids[0], "robot": robots[0], "base": {"xyz": [0.0, 0.0, 0.0]}},
                    {
                        "id": ids[1],
                        "robot": robots[1],
                        "base": {"xyz": [distance, 0.0, 0.0], "rpy": [0.0, 0.0, yaw]},
                    },
                ],
            }
        )
    return cells


def write_cells(folder: Path, cells: list[dict[str, Any]]) -> list[Path]:
    """Each cell as ``folder/<name>.yaml``; their paths."""
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    for cell in cells:
        path = folder / f"{cell['name']}.yaml"
        path.write_text(
            "# a cell of nehmo pair build's visit stage (nehmo_core/pairs/visit.py)\n"
            + yaml.safe_dump(cell, sort_keys=False)
        )
        paths.append(path)
    return paths


def summary_figures(run: Path, cell: dict[str, Any]) -> dict[str, Any]:
    """What one cell's evaluation measured: its layout and the planner's outcomes."""
    ours = json.loads((run / "summary.json").read_text())["rows"][0]["ours"]
    second = cell["arms"][1]["base"]
    return {
        "cell": cell["name"],
        "base_distance_m": second["xyz"][0],
        "yaw_rad": round(second["rpy"][2], 4),
        **{k: ours[k] for k in ("episodes", "sr", "collisions", "self_collisions", "stuck")},
    }


def visit_stage(build: PairBuild) -> Stage:
    """Stage ``visit``: one ``nehmo evaluate`` per cell (a cell already run is kept)."""
    figures = build.state["stages"]["check"]["figures"]
    reaches = (
        figures["robots"][build.robots[0]]["reach_m"],
        figures["robots"][build.robots[1]]["reach_m"],
    )
    cells = visit_cells(build.robots, reaches, tuple(figures["base_range_m"]))
    paths = write_cells(build.work / "visit", cells)
    commands, rows = [], []
    for i, (cell, path) in enumerate(zip(cells, paths, strict=True)):
        run = build.work / "visit" / cell["name"]
        if not (run / "summary.json").exists():
            args = [
                "evaluate", "--setup", str(path), "--planners", "nehmo",
                "--episodes", str(build.budget.visit_episodes),
                "--seed", str(build.seed + SEED_OFFSET + i),
                "--workers", str(build.threads), "--out", str(run),
            ]  # fmt: skip
            commands.append(build.nehmo("visit", args))
        rows.append(summary_figures(run, cell))
    return commands, {"cells": rows}


def certify_stage(build: PairBuild, game: str, visited: bool) -> Stage:
    """Stages ``certify:<game>`` (uniform states) and ``certify-visited:<game>`` (the visit
    stage's): ``nehmo verify`` at the planner's ``t_safe``, recorded in the model card."""
    from nehmo_core.planning.settings import PlannerSettings
    from nehmo_core.sim.actuators import certificate_actuators

    tau = PlannerSettings().opt.t_safe
    logs = sorted(str(p) for p in (build.work / "visit").glob("visit_*/logs"))
    where = ["visited", *(a for p in logs for a in ("--logs", p))] if visited else ["uniform"]
    command = build.nehmo(
        f"certify{'-visited' if visited else ''}:{game}",
        [
            "verify", "--model", game, "--variant", build.variant,
            "--tau", f"{tau:g}", "--distribution", *where,
            "--samples", str(build.budget.certificate_samples),
            "--alpha", str(build.budget.alpha),
            "--search-samples", str(build.budget.search_samples),
            "--attempts", str(CERTIFY_ATTEMPTS),
            "--seed", str(build.seed), "--out", str(build.work / "certificates"), "--card",
            *build.cluster_args,
        ],
    )  # fmt: skip
    meta = json.loads((build.models / f"value_{game}_{build.slug}.json").read_text())
    certs = [
        c
        for c in meta["card"].get("certificates", [])
        if abs(c["tau"] - tau) < 1e-9
        and c["distribution"]["name"] == where[0]
        and certificate_actuators(c) == "ideal"  # not one made later under an actuator model
    ]
    keep = ("delta", "violations", "samples", "epsilon", "certified", "accepted_share")
    return [command], {"tau": tau, "distribution": where[0], **{k: certs[-1][k] for k in keep}}
