"""Does the ground-truth grid limit Table I's two-link figure? The 40M bc+sym seed models
against grid solutions of increasing resolution.

    OMP_NUM_THREADS=2 ./run python bench/hjr_grid_check.py            # 31⁴, 41⁴, 51⁴
    ./run python bench/hjr_grid_check.py --grids 31,41                # a subset

Solves (or loads from the cache) the two-link avoid value on each grid with hj_reachability and
reports mean and max |V − V_gt| at τ = 0.5 s and τ = T = 0.6 s for every seed run under
``bench/results/hjr_runs/two_link_bc_sym_40M_s*`` → ``bench/results/hjr_grid_check.md``.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from nehmo_core.hjr.ground_truth import ground_truth, validate
from nehmo_core.hjr.model_files import load_value_function
from nehmo_core.hjr.systems import make_system

RESULTS = Path(__file__).resolve().parent / "results"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--grids", default="31,41,51", help="points per joint, comma-separated")
    args = parser.parse_args()
    torch.set_num_threads(2)
    system = make_system("two_link")
    runs = sorted((RESULTS / "hjr_runs").glob("two_link_bc_sym_40M_s*"))
    if not runs:
        raise SystemExit("no two_link_bc_sym_40M_s* runs under bench/results/hjr_runs")
    models = {run.name.rsplit("_", 1)[1]: load_value_function(run) for run in runs}
    lines = [
        "# Two-link bc+sym at 40M against finer ground truths",
        "",
        "Mean (max) |V − V_gt| over each grid; `bench/hjr_grid_check.py`.",
        "",
        "| grid | solve s | " + " | ".join(f"{s} τ=0.5 | {s} τ=T" for s in models) + " |",
        "|---|---|" + "---|---|" * len(models),
    ]
    for n in (int(g) for g in args.grids.split(",")):
        t0 = time.perf_counter()
        truth = ground_truth(system, grid_shape=(n,) * system.state_dim)
        cells = []
        for vf in models.values():
            for row in validate(vf, system, taus=[0.5, system.horizon], truth=truth):
                cells.append(f"{row.mean_abs_error:.4f} ({row.max_abs_error:.2f})")
        lines.append(f"| {n}⁴ | {truth.solve_seconds:.0f} | " + " | ".join(cells) + " |")
        print(lines[-1], f"({time.perf_counter() - t0:.0f} s)", flush=True)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "hjr_grid_check.md").write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
