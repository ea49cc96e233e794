"""Certificates for every shipped value function (``nehmo verify``), recorded in their model cards.

For each model, τ = t_plan (0.1 s) and t_safe (0.3 s), and for the planner's ``bc+sym`` models
also τ = hold_bound·t_safe (0.06 s: the horizon at which peers that announced a speed bound are
planned against), over two distributions: uniform over the
joint box, and the pair states visited by the ``nehmo`` planner in evaluation episodes of
development seed 31 (``--episodes-dir``; made by ``nehmo evaluate --planners nehmo --seed 31``
for dual_ur5, five_ur5 and ur5_kinova_challenging, 20 episodes each) and, for the pose-conditioned
``ur5_ur5_any``, the ``nehmo`` episodes of Ha et al.'s task files (``ha_tasks``: ``nehmo evaluate
--tasks ../shared/ha_benchmark/tasks --planners nehmo``), whose layouts span r = 0.31-1.60 m;
for ``ur5_kinova_any`` / ``kinova_ur5_any``, the ``nehmo`` episodes of the UR5-Kinova cell planned
with them alone (``ur5_kinova_any``: ``nehmo evaluate --setup ur5_kinova_challenging --planners
nehmo --seed 0 --value-model ur5_kinova_any --value-model kinova_ur5_any``, the Table IV comparison
of ``bench/results/any_layout_ur5_kinova.md``); for the Panda pairs (``bc``: the Panda has no
mirror map; the planner's models, so also at the settled horizon), the episodes of their build's
visit stage (``--episodes-dir runs/pairs/<pair>``: ``visit/visit_*``, made by ``nehmo pair
build``, which also certifies them at ``t_safe``; run with ``--only`` per pair).
Writes one JSON + Markdown per certificate under ``bench/results/certificates/`` and a table
``certificates.md``; ``--missing`` skips certificates whose JSON is already there (a resumed run).

    OMP_NUM_THREADS=1 ./run python bench/certify_models.py --episodes-dir runs/episodes
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

from nehmo_core.planning.settings import PlannerSettings
from nehmo_core.verify.report import (
    certificate_json_actuators,
    certificate_stem,
    certificates_table,
)

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "certificates"
MODELS = [  # (pair, variant, episode setups whose logs hold its pair states)
    ("ur5_ur5", "bc+sym", ("dual_ur5", "five_ur5")),
    ("ur5_ur5_diag", "bc+sym", ("five_ur5",)),
    ("ur5_ur5_opposite", "bc+sym", ("five_ur5",)),
    ("ur5_kinova", "bc+sym", ("ur5_kinova_challenging",)),
    ("kinova_ur5", "bc+sym", ("ur5_kinova_challenging",)),
    ("ur5_ur5", "bc", ("dual_ur5", "five_ur5")),
    ("ur5_ur5", "deepreach", ("dual_ur5", "five_ur5")),
    ("ur5_ur5_any", "bc+sym", ("ha_tasks",)),
    ("ur5_kinova_any", "bc+sym", ("ur5_kinova_any",)),
    ("kinova_ur5_any", "bc+sym", ("ur5_kinova_any",)),
    ("panda_panda_any", "bc", ("visit",)),
    ("ur5_panda_any", "bc", ("visit",)),
    ("panda_ur5_any", "bc", ("visit",)),
    ("kinova_gen3_6dof_kinova_gen3_6dof_any", "bc+sym", ("visit",)),
    ("kinova_gen3_6dof_panda_any", "bc", ("visit",)),
    ("panda_kinova_gen3_6dof_any", "bc", ("visit",)),
    ("ur5_kinova_gen3_6dof_far", "bc+sym", ("visit",)),
    ("kinova_gen3_6dof_ur5_far", "bc+sym", ("visit",)),
]
# the Panda pairs (bc: no mirror map) are the planner's models, so certified at the settled horizon
PLANNER_BC = {pair for pair, _, setups in MODELS if setups == ("visit",)}
TAUS = (0.3, 0.1)
_DEFAULTS = PlannerSettings()
SLOW_TAU = round(_DEFAULTS.hold.bound * _DEFAULTS.opt.t_safe, 6)  # a settled peer's rows [s]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes-dir", type=Path, required=True)
    parser.add_argument("--samples", type=int, default=3000)
    parser.add_argument("--only", help="comma-separated pair/variant names, e.g. ur5_ur5/bc+sym")
    parser.add_argument("--report-only", action="store_true")
    parser.add_argument(
        "--missing", action="store_true", help="only certificates without a JSON in the output"
    )
    args = parser.parse_args()
    OUT.mkdir(parents=True, exist_ok=True)
    only = set(args.only.split(",")) if args.only else None
    if not args.report_only:
        for tau in (*TAUS, SLOW_TAU):
            for pair, variant, setups in MODELS:
                if only and f"{pair}/{variant}" not in only:
                    continue
                if tau == SLOW_TAU and variant != "bc+sym" and pair not in PLANNER_BC:
                    continue
                logs = [a for s in setups for a in ("--logs", str(args.episodes_dir / s))]
                for dist in ("visited", "uniform"):
                    stem = certificate_stem(pair, variant, dist, tau)
                    if args.missing and (OUT / f"{stem}.json").exists():
                        continue
                    cmd = ["nehmo", "verify", "--model", pair, "--variant", variant]
                    cmd += [
                        "--tau",
                        str(tau),
                        "--distribution",
                        dist,
                        "--samples",
                        str(args.samples),
                    ]
                    cmd += [*(logs if dist == "visited" else []), "--out", str(OUT), "--card"]
                    print("$", " ".join(cmd), flush=True)
                    subprocess.run(cmd, check=True)
    certs = [json.loads(p.read_text()) for p in sorted(OUT.glob("*.json"))]
    table = certificates_table(
        sorted(
            certs,
            key=lambda c: (
                c["model"],
                c["tau"],
                c["distribution"]["name"],
                certificate_json_actuators(c),
            ),
        )
    )
    (OUT.parent / "certificates.md").write_text(
        "# Certificates of the shipped value functions\n\n"
        "α = 1 %, β = 1e-3; made by `bench/certify_models.py`. Visited states: `nehmo` episodes "
        "of seed 31 (dual_ur5, five_ur5, ur5_kinova_challenging, 20 each); for `ur5_ur5_any`, "
        "of Ha et al.'s 46 obstacle-free tasks; for the pairs made by `nehmo pair build` (the "
        "Panda's and Kinova's pairs, the far UR5-Kinova range), of their build's visit cells. "
        "`actuators`: how the controlled arm tracks its control in the rollouts (`nehmo verify "
        "--actuators`; `bench/results/actuators/README.md`). Wall times were measured with other "
        "jobs on the second core.\n\n" + table
    )
    print(table)
    return 0


if __name__ == "__main__":
    sys.exit(main())
