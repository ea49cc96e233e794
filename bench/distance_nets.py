"""Benchmark of the shipped learned distances: accuracy against the exact distance on fresh
samples, and throughput at batch 1 and batch 1024 on one thread.

    ./run python bench/distance_nets.py            # writes bench/results/distance_nets.{json,md}

Fresh samples use seeds the training data never used: 20,000 uniform over the joint box
(the headline figures) and 20,000 stratified near contact (the boundary figures).
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

import numpy as np
import torch

from nehmo_core.geometry.distance_data import (
    DatasetSpec,
    exact_distances,
    generate,
    uniform_samples,
)
from nehmo_core.geometry.distance_model import SHIPPED_DISTANCE_MODELS, load_distance_model
from nehmo_core.geometry.distance_train import evaluate

RESULTS = Path(__file__).resolve().parent / "results"


def _throughput(model: torch.nn.Module, dof: int, batch: int, repeats: int) -> dict[str, float]:
    q = torch.rand(batch, dof, dtype=torch.float64) * 6.0 - 3.0
    out = {}
    with torch.no_grad():
        model(q)
        t = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            model(q)
            t.append(time.perf_counter() - t0)
    out["value_median_s"] = float(np.median(t))
    qg = q.clone().requires_grad_(True)
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        d = model(qg)
        torch.autograd.grad(d.sum(), qg)
        t.append(time.perf_counter() - t0)
    out["value_and_grad_median_s"] = float(np.median(t))
    out["evals_per_s"] = batch / out["value_median_s"]
    out["evals_with_grad_per_s"] = batch / out["value_and_grad_median_s"]
    return out


def _compiled_throughput(model: torch.nn.Module, repeats: int = 2000) -> dict[str, object]:
    """Batch-1 value and gradient through the generated-C export used by the planner."""
    from nehmo_core.geometry.distance_casadi import distance_function
    from nehmo_core.planning.numerics.codegen import compile_function

    compiled = compile_function(distance_function(model), "auto")  # type: ignore[arg-type]
    fn = compiled.function
    q = np.random.default_rng(0).uniform(-3, 3, size=model.dof)  # type: ignore[arg-type]
    fn(q)
    t = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn(q)
        t.append(time.perf_counter() - t0)
    median = float(np.median(t))
    return {"backend": compiled.backend, "value_and_grad_median_s": median, "per_s": 1.0 / median}


def throughput_only() -> None:
    """Refresh the throughput figures of an existing report (accuracy untouched)."""
    torch.set_num_threads(1)
    path = RESULTS / "distance_nets.json"
    report = json.loads(path.read_text())
    for pair in SHIPPED_DISTANCE_MODELS:
        model = load_distance_model(pair)
        r = report["pairs"][pair]
        r["batch_1"] = _throughput(model, model.dof, 1, 300)
        r["batch_1024"] = _throughput(model, model.dof, 1024, 20)
        r["compiled_batch_1"] = _compiled_throughput(model)
    path.write_text(json.dumps(report, indent=2) + "\n")
    (RESULTS / "distance_nets.md").write_text(_markdown(report))
    print(_markdown(report))


def run(n: int, workers: int) -> dict[str, object]:
    torch.set_num_threads(1)
    report: dict[str, object] = {"machine": platform.processor() or platform.machine(), "pairs": {}}
    for pair in SHIPPED_DISTANCE_MODELS:
        model = load_distance_model(pair)
        q_u = uniform_samples(pair, n, np.random.default_rng(7_000_001))
        d_u = exact_distances(pair, q_u, workers, f"{pair} uniform")
        # Near-contact set: boundary samples grown from a fresh uniform draw (uniform part dropped).
        q_all, d_all = generate(DatasetSpec(pair, n, n, seed=7_000_002), workers)
        q_b, d_b = q_all[n:], d_all[n:]
        report["pairs"][pair] = {  # type: ignore[index]
            "uniform": evaluate(model, q_u, d_u),
            "near_contact": evaluate(model, q_b, d_b),
            "batch_1": _throughput(model, model.dof, 1, 300),
            "batch_1024": _throughput(model, model.dof, 1024, 20),
            "compiled_batch_1": _compiled_throughput(model),
        }
    return report


def _markdown(report: dict[str, object]) -> str:
    lines = [
        "# Learned arm-arm distance: accuracy and throughput",
        "",
        "Accuracy on fresh samples against the exact PyBullet distance; throughput on one thread.",
        "",
        "| pair | samples | MAE [cm] | MAE d<10cm [cm] | collision acc. | false-safe "
        "| false-unsafe | torch evals/s b=1 | torch evals/s b=1024 | torch with grad b=1 "
        "| compiled value+grad/s b=1 |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for pair, r in report["pairs"].items():  # type: ignore[attr-defined]
        for kind in ("uniform", "near_contact"):
            a = r[kind]
            lines.append(
                f"| {pair} | {kind} ({a['n']}) | {100 * a['mae_m']:.2f} | "
                f"{100 * a['mae_near_m']:.2f} | {100 * a['collision_accuracy']:.1f} % | "
                f"{100 * a['false_safe_rate']:.2f} % | {100 * a['false_unsafe_rate']:.2f} % | "
                f"{r['batch_1']['evals_per_s']:.0f} | {r['batch_1024']['evals_per_s']:.0f} | "
                f"{r['batch_1']['evals_with_grad_per_s']:.0f} | "
                f"{r.get('compiled_batch_1', {}).get('per_s', float('nan')):.0f} |"
            )
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--samples", type=int, default=20_000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument(
        "--throughput-only", action="store_true", help="refresh throughput, keep accuracy"
    )
    args = parser.parse_args()
    if args.throughput_only:
        throughput_only()
        return
    report = run(args.samples, args.workers)
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / "distance_nets.json").write_text(json.dumps(report, indent=2) + "\n")
    (RESULTS / "distance_nets.md").write_text(_markdown(report))
    print(_markdown(report))


if __name__ == "__main__":
    main()
