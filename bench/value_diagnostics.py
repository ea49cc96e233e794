"""Have the value networks learned the HJ PDE, or only the boundary ``V = l``?

    ./run python bench/value_diagnostics.py   # writes bench/results/value_diagnostics.{json,md}

For every shipped value function and every Table I run in ``bench/results/hjr_runs`` whose
weights are at hand (the repository keeps their logs only):
:func:`nehmo_core.hjr.diagnostics.pde_diagnostics` on 8192 states drawn as training draws them.
A residual ratio near 1 means the network meets the PDE no better than ``V = l`` does (its
residual stayed at zero: a distance, not a reachability value); the Table I runs, which agree
with a grid solver, show what a learned value gives.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import torch
from _report import machine_at_end, write_report

from nehmo_core.hjr import load_value_function
from nehmo_core.hjr.diagnostics import pde_diagnostics
from nehmo_core.hjr.model_files import SHIPPED_VALUE_FUNCTIONS

RESULTS = Path(__file__).resolve().parent / "results"


def run(samples: int) -> dict[str, Any]:
    torch.set_num_threads(1)
    rows: list[dict[str, Any]] = []
    for name, variants in SHIPPED_VALUE_FUNCTIONS.items():
        for variant in variants:
            d = pde_diagnostics(load_value_function(name, variant=variant), samples)
            rows.append({"model": f"{name} {variant}", "kind": "shipped", **d.to_dict()})
            print(rows[-1])
    # the Table I runs whose weights are at hand (the repository keeps their logs, not weights)
    runs = (RESULTS / "hjr_runs").glob("*_40M_s0/model.safetensors")
    for run_dir in sorted(path.parent for path in runs):
        d = pde_diagnostics(load_value_function(run_dir), samples)
        rows.append({"model": run_dir.name, "kind": "Table I run", **d.to_dict()})
        print(rows[-1])
    return {"samples": samples, "rows": rows, "machine": machine_at_end()}


def markdown(report: dict[str, Any]) -> str:
    lines = [
        "# Value networks against the HJ PDE",
        "",
        f"{report['samples']} states per model, drawn as training draws them (folded into "
        "X_train for bc+sym), τ uniform in [0, T]. Residual: mean |∂W/∂τ − min(0, H(x, ∇W))| "
        "in the network's normalized units (the training loss's `pde` term); trivial: the same "
        "for W = l̂. A ratio near 1 means the network's residual NN stayed at zero: V(τ, x) = "
        "l(x) for every τ, a distance rather than a reachability value.",
        "",
        "| model | kind | residual | trivial (V = l) | ratio | H(∇l) < 0 share "
        "| mean l − V(T) [m] | p99 l − V(T) [m] |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in report["rows"]:
        lines.append(
            f"| {r['model']} | {r['kind']} | {r['pde_residual']:.4f} | "
            f"{r['trivial_residual']:.4f} | {r['residual_ratio']:.3f} | "
            f"{r['must_fall_share']:.2f} | {r['mean_fall_at_horizon']:.4f} | "
            f"{r['p99_fall_at_horizon']:.4f} |"
        )
    lines += ["", f"Machine: {report['machine']}.", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=8192, help="states per model")
    args = parser.parse_args()
    print(write_report(RESULTS, "value_diagnostics", run(args.samples), markdown))


if __name__ == "__main__":
    main()
