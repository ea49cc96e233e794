"""Table I of the paper: validation error of deepreach, bc and bc+sym against data usage.

    ./run python bench/hjr_table1.py                                   # everything (days on CPU)
    ./run python bench/hjr_table1.py --systems air3d --budgets 40M     # a subset
    ./run python bench/hjr_table1.py --report-only                     # tables and figures only

Protocol (paper § IV-A): deepreach and bc at 10M, 20M, 40M, 60M, 80M samples, bc+sym at 10M,
20M, 40M (it trains on X_train only, "half the data"); every run with the same settings
(``--preset``, default ``cpu``), seeds ``0 … --seeds−1``. The error is mean |V − V_gt| over the
hj_reachability grid (Air3D 51³, two-link 41⁴) at τ = T, in the value's physical units; the
record also keeps intermediate τ, max error, BRT volumes and falsely safe/unsafe shares.

Resumable: each run lives in ``bench/results/hjr_runs/<system>_<variant>_<budget>_s<seed>/`` and
is skipped once its ``result.json`` exists (an unfinished run resumes from its checkpoint).
Writes ``bench/results/hjr_table1.{json,md,png}`` and ``hjr_slices_<system>.png``.
Runs one at a time on one torch thread; start it under ``nice`` when the machine is shared.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from hjr_tune import train_and_validate

from nehmo_core.hjr.ground_truth import ground_truth
from nehmo_core.hjr.model_files import load_value_function
from nehmo_core.hjr.systems import make_system
from nehmo_core.hjr.train_cli import parse_count
from nehmo_core.hjr.train_settings import PRESETS, TrainSettings

RESULTS = Path(__file__).resolve().parent / "results"
RUNS = RESULTS / "hjr_runs"
SYSTEMS = ("air3d", "two_link")
VARIANTS = ("bc+sym", "bc", "deepreach")  # run order: the method first
BUDGETS = (10_000_000, 20_000_000, 40_000_000, 60_000_000, 80_000_000)
SYM_MAX_BUDGET = 40_000_000  # bc+sym stops at half the largest budget
PRIORITY = (40_000_000, 10_000_000, 20_000_000, 60_000_000, 80_000_000)  # run order of budgets
BAR = {"air3d": 0.014, "two_link": 0.010}  # the bar for bc+sym at 40M

# Paper Table I (mean l1 validation error, 3 seeds); None where the paper has "-".
PAPER: dict[str, dict[str, list[float | None]]] = {
    "air3d": {
        "deepreach": [0.187, 0.124, 0.035, 0.016, 0.015],
        "bc": [0.074, 0.051, 0.027, 0.017, 0.014],
        "bc+sym": [0.054, 0.028, 0.014, None, None],
    },
    "two_link": {
        "deepreach": [0.125, 0.046, 0.024, 0.017, 0.016],
        "bc": [0.052, 0.051, 0.040, 0.011, 0.010],
        "bc+sym": [0.052, 0.044, 0.010, None, None],
    },
}
LABEL = {"air3d": "Air3D", "two_link": "Simple arm (two-link)"}
SHORTFALL = {
    "two_link": (
        "  Why: the error grows with τ (the PDE residual left at the end of training "
        "integrates over the horizon); at τ = 0.5 s, where the authors validate the two-link "
        "pair, it is under the bar. Six two-link-specific changes to the Air3D-tuned `cpu` "
        "preset, one at a time, did not help at 40M (`hjr_tuning.md` #18–#22): batch 250 "
        "0.0147, curriculum over 0.3 of the steps 0.0123, ω0 = 15 0.0117, learning rate 1e-4 "
        "0.0120, 4 hidden layers 0.0126; width 128 diverged to 5× the loss by 26M and was "
        "stopped. The Dirichlet weight does matter: at 10 instead of 40 (the only change), "
        "the two-link pair reaches 0.0095 ± 0.0001 over seeds 0, 1, 2 (0.0094, 0.0095, "
        "0.0095) at τ = T (`hjr_tuning.md` #24–#26), under the bar; the table above keeps "
        "the `cpu` preset for every cell. The grid is not the limit: against finer ground "
        "truths the three seeds "
        "score 0.0121–0.0125 (31⁴), 0.0114–0.0118 (41⁴), 0.0110–0.0114 (51⁴). One 40M "
        "two-link run takes ~21 min on a quiet core."
    ),
}
COLOR = {"deepreach": "tab:gray", "bc": "tab:blue", "bc+sym": "tab:red"}


def budget_label(samples: int) -> str:
    return f"{samples // 1_000_000}M" if samples % 1_000_000 == 0 else str(samples)


def run_dir(system: str, variant: str, samples: int, seed: int) -> Path:
    return RUNS / f"{system}_{variant.replace('+', '_')}_{budget_label(samples)}_s{seed}"


def planned_runs(args: argparse.Namespace) -> list[tuple[str, str, int, int]]:
    """``(system, variant, samples, seed)`` in priority order."""
    budgets = [parse_count(b, "budgets") for b in args.budgets.split(",")]
    runs = []
    for seed in range(args.seeds):
        for budget in sorted(budgets, key=lambda b: (*PRIORITY, b).index(b)):
            for system in args.systems.split(","):
                for variant in args.variants.split(","):
                    if variant == "bc+sym" and budget > SYM_MAX_BUDGET and not args.sym_all:
                        continue
                    runs.append((system, variant, budget, seed))
    return runs


def run_all(args: argparse.Namespace, settings: TrainSettings) -> None:
    for system_name, variant, samples, seed in planned_runs(args):
        out = run_dir(system_name, variant, samples, seed)
        if (out / "result.json").exists():
            continue
        system = make_system(system_name)
        run_settings = replace(settings, variant=variant, samples=samples, seed=seed)
        print(f"run {out.name} ...", flush=True)
        record = train_and_validate(system, run_settings, out)
        record["preset"] = args.preset
        (out / "result.json").write_text(json.dumps(record, indent=2) + "\n")
        for stale in ("checkpoint.safetensors", "checkpoint.json"):
            (out / stale).unlink(missing_ok=True)  # the model is what stays
        print(
            f"  mean|V−V_gt| at T = {record['mean_abs_error_T']:.4f}, "
            f"train {record['train_wall_s']:.0f} s",
            flush=True,
        )


# ------------------------------------------------------------------------------------------------
# Report
# ------------------------------------------------------------------------------------------------


def collect() -> list[dict[str, Any]]:
    return [json.loads(p.read_text()) for p in sorted(RUNS.glob("*/result.json"))]


def summarize(records: list[dict[str, Any]]) -> dict[str, Any]:
    """``{system: {variant: {budget: {mean, std, seeds, wall_s, ...}}}}``."""
    table: dict[str, Any] = {}
    for r in records:
        cell = table.setdefault(r["system"], {}).setdefault(r["variant"], {})
        cell.setdefault(budget_label(r["samples"]), []).append(r)
    out: dict[str, Any] = {}
    for system, variants in table.items():
        for variant, budgets in variants.items():
            for budget, runs in budgets.items():
                errors = np.array([r["mean_abs_error_T"] for r in runs])
                mid = [r["rows"][len(r["rows"]) // 2] for r in runs]
                out.setdefault(system, {}).setdefault(variant, {})[budget] = {
                    "mean_abs_error_T": float(errors.mean()),
                    "std": float(errors.std()),
                    "seeds": [r["seed"] for r in runs],
                    "max_abs_error_T": float(
                        np.mean([r["rows"][-1]["max_abs_error"] for r in runs])
                    ),
                    "tau_mid": mid[0]["tau"],
                    "mean_abs_error_mid": float(np.mean([m["mean_abs_error"] for m in mid])),
                    "falsely_safe_T": float(np.mean([r["rows"][-1]["falsely_safe"] for r in runs])),
                    "train_wall_s": [round(r["train_wall_s"], 1) for r in runs],
                    "samples_per_s": float(np.mean([r["samples_per_s"] for r in runs])),
                }
    return out


def _cell(summary: dict[str, Any], system: str, variant: str, budget: str) -> str:
    entry = summary.get(system, {}).get(variant, {}).get(budget)
    if entry is None:
        return "·"
    text = f"{entry['mean_abs_error_T']:.4f}"
    if len(entry["seeds"]) > 1:
        text += f" ± {entry['std']:.4f}"
    return text


def markdown(summary: dict[str, Any], settings: TrainSettings, preset: str) -> str:
    labels = [budget_label(b) for b in BUDGETS]
    lines = [
        "# Table I: HJR validation error against data usage",
        "",
        "Mean |V − V_gt| over the hj_reachability grid at τ = T (Air3D 51³, T = 1.1 s; two-link "
        "41⁴, T = 0.6 s), physical value units. Ours (1 CPU thread, x86_64) / paper "
        "(3 seeds, GPU). `·` = not run yet; `-` = not in the protocol.",
        "",
        "| system | variant | " + " | ".join(labels) + " |",
        "|---|---|" + "---|" * len(labels),
    ]
    for system in SYSTEMS:
        for variant in ("deepreach", "bc", "bc+sym"):
            cells = []
            for label, paper in zip(labels, PAPER[system][variant], strict=True):
                paper_text = "-" if paper is None else f"{paper:.3f}"
                ours = _cell(summary, system, variant, label)
                if paper is None and ours == "·":
                    ours = "-"
                cells.append(f"{ours} / {paper_text}")
            lines.append(f"| {LABEL[system]} | {variant} | " + " | ".join(cells) + " |")
    lines += ["", "## The bar (issue 3): bc+sym at 40M", ""]
    for system in SYSTEMS:
        entry = summary.get(system, {}).get("bc+sym", {}).get("40M")
        if entry is None:
            lines.append(f"- {LABEL[system]}: not run yet (bar ≤ {BAR[system]}).")
            continue
        ok = "reached" if entry["mean_abs_error_T"] <= BAR[system] else "NOT reached"
        lines.append(
            f"- {LABEL[system]}: {entry['mean_abs_error_T']:.4f} vs bar ≤ {BAR[system]}: {ok} "
            f"(at τ = {entry['tau_mid']:g} s: {entry['mean_abs_error_mid']:.4f})."
        )
        if ok != "reached":
            lines.append(SHORTFALL.get(system, ""))
    lines += [
        "",
        "## Every run",
        "",
        "| system | variant | samples | seeds | mean err T | mean err τ_mid | max err T "
        "| falsely safe T | train wall [s] | samples/s |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for system, variants in summary.items():
        for variant, budgets in variants.items():
            for budget, e in sorted(budgets.items(), key=lambda kv: parse_count(kv[0])):
                lines.append(
                    f"| {system} | {variant} | {budget} | {e['seeds']} | "
                    f"{e['mean_abs_error_T']:.4f} | {e['mean_abs_error_mid']:.4f} "
                    f"(τ={e['tau_mid']:.1f}) | {e['max_abs_error_T']:.3f} | "
                    f"{e['falsely_safe_T']:.4f} | {e['train_wall_s']} | {e['samples_per_s']:.0f} |"
                )
    net = settings.network
    lines += [
        "",
        "## Settings",
        "",
        f"Preset `{preset}`: SIREN {net.hidden_layers}×{net.width} (ω0 = {net.omega0}, input "
        f"scaling `{net.input_scaling}`), batch {settings.batch_size}, Adam "
        f"{settings.learning_rate:g} with `{settings.lr_schedule}` decay to "
        f"{settings.lr_final_fraction:g}×, pretraining {settings.pretrain_fraction:.3g} of the "
        f"steps, curriculum over {settings.curriculum_fraction:.3g} of the rest, boundary share "
        f"{settings.boundary_fraction:.3g}, Dirichlet weight {settings.dirichlet_weight:g}. "
        "Budget = states drawn, pretraining included. Wall times are single-thread training "
        "under `nice -n 10` on a 2-core CPU shared with other training jobs, so they are "
        "upper bounds. How these settings were chosen: `hjr_tuning.md`.",
        "",
        f"Machine: {platform.machine()}, torch {torch.__version__}.",
    ]
    return "\n".join(lines) + "\n"


def plot_table(summary: dict[str, Any], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=False)
    millions = np.array(BUDGETS) / 1e6
    for ax, system in zip(axes, SYSTEMS, strict=True):
        for variant in ("deepreach", "bc", "bc+sym"):
            paper = PAPER[system][variant]
            xs = [m for m, p in zip(millions, paper, strict=True) if p is not None]
            ys = [p for p in paper if p is not None]
            ax.plot(xs, ys, "--", color=COLOR[variant], alpha=0.5, label=f"{variant} (paper)")
            ours = summary.get(system, {}).get(variant, {})
            if ours:
                pts = sorted((parse_count(b) / 1e6, e["mean_abs_error_T"]) for b, e in ours.items())
                ax.plot(*zip(*pts, strict=True), "o-", color=COLOR[variant], label=variant)
        ax.axhline(BAR[system], color="k", lw=0.8, ls=":", label=f"bar {BAR[system]}")
        ax.set_yscale("log")
        ax.set_xticks(millions)
        ax.set_xlabel("data usage [million samples]")
        ax.set_ylabel("mean |V − V_gt| at τ = T")
        ax.set_title(LABEL[system])
        ax.grid(alpha=0.3, which="both")
    axes[0].legend(fontsize=7, ncol=2)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _slice_runs(system: str) -> list[tuple[str, Path]]:
    """Per variant, the finished run with the largest budget ≤ 40M (seed 0)."""
    chosen = []
    for variant in ("deepreach", "bc", "bc+sym"):
        for budget in (40_000_000, 20_000_000, 10_000_000):
            path = run_dir(system, variant, budget, 0)
            if (path / "result.json").exists():
                chosen.append((f"{variant} {budget_label(budget)}", path))
                break
    return chosen


def plot_slices(system_name: str, path: Path) -> bool:
    """Learned V at τ = T on a 2-D slice with the learned (solid) and true (dashed) V = 0."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    runs = _slice_runs(system_name)
    if not runs:
        return False
    system = make_system(system_name)
    truth = ground_truth(system)
    tau = float(truth.taus[-1])
    true = truth.value_at(tau)
    c = truth.coordinate_vectors
    index: list[Any]  # per column: the x3 index (Air3D) or the (q²₁, q²₂) indices
    if system_name == "air3d":
        headings = [0.0, np.pi / 2, np.pi]  # θ [rad]; x3 = θ / (1.2π)
        index = [int(np.argmin(np.abs(c[2] - h / (1.2 * np.pi)))) for h in headings]
        titles = [f"θ = {np.degrees(c[2][k] * 1.2 * np.pi):.0f}°" for k in index]
        axes_names = ("x1 [m]", "x2 [m]")
    else:
        k3, k4 = int(np.argmin(np.abs(c[2]))), int(np.argmin(np.abs(c[3] - np.pi / 2)))
        index = [(k3, k4)]
        titles = [f"q²₁ = {c[2][k3]:.2f}, q²₂ = {c[3][k4]:.2f} rad"]
        axes_names = ("q¹₁ [rad]", "q¹₂ [rad]")
    a, b = np.meshgrid(c[0], c[1], indexing="ij")
    fig, axes = plt.subplots(
        len(runs),
        len(index),
        figsize=(3.4 * len(index) + 1.2, 3.3 * len(runs) + 0.6),
        squeeze=False,
        layout="constrained",
    )
    for row, (name, run) in enumerate(runs):
        vf = load_value_function(run, system)
        for col, k in enumerate(index):
            if system_name == "air3d":
                fixed = np.full_like(a, c[2][k])
                states = np.stack([a, b, fixed], -1).reshape(-1, 3)
                v_true = true[:, :, k]
            else:
                f3, f4 = np.full_like(a, c[2][k[0]]), np.full_like(a, c[3][k[1]])
                states = np.stack([a, b, f3, f4], -1).reshape(-1, 4)
                v_true = true[:, :, k[0], k[1]]
            v = np.asarray(vf.value(tau, states), dtype=np.float64).reshape(a.shape)
            ax = axes[row, col]
            mesh = ax.pcolormesh(a, b, v, cmap="RdBu", shading="auto", vmin=-1, vmax=1)
            ax.contour(a, b, v, levels=[0.0], colors="k", linewidths=1.5)
            ax.contour(a, b, v_true, levels=[0.0], colors="lime", linewidths=1.2, linestyles="--")
            err = np.abs(v - v_true).mean()
            ax.set_title(f"{name}, {titles[col]}\nmean|err| on slice {err:.3f}", fontsize=8)
            ax.set_xlabel(axes_names[0], fontsize=8)
            ax.set_ylabel(axes_names[1], fontsize=8)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=7)
    fig.colorbar(mesh, ax=axes, shrink=0.6, label="learned V (τ = T)")
    fig.suptitle(
        f"{LABEL[system_name]}, τ = T = {tau:g} s\nlearned V = 0 (black) vs ground truth "
        "(green, dashed)",
        fontsize=9,
    )
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return True


def report(settings: TrainSettings, preset: str) -> None:
    records = collect()
    summary = summarize(records)
    RESULTS.mkdir(parents=True, exist_ok=True)
    payload = {
        "generated": time.strftime("%Y-%m-%d %H:%M:%S"),
        "preset": preset,
        "settings": settings.to_dict(),
        "paper": PAPER,
        "bar": BAR,
        "summary": summary,
        "runs": [{k: v for k, v in r.items() if k != "settings"} for r in records],
    }
    (RESULTS / "hjr_table1.json").write_text(json.dumps(payload, indent=2) + "\n")
    (RESULTS / "hjr_table1.md").write_text(markdown(summary, settings, preset))
    plot_table(summary, RESULTS / "hjr_table1.png")
    for system in SYSTEMS:
        plot_slices(system, RESULTS / f"hjr_slices_{system}.png")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--systems", default=",".join(SYSTEMS))
    parser.add_argument("--variants", default=",".join(VARIANTS))
    parser.add_argument("--budgets", default=",".join(budget_label(b) for b in BUDGETS))
    parser.add_argument("--seeds", type=int, default=1, help="seeds 0 … N−1")
    parser.add_argument("--preset", default="cpu", help=f"one of {sorted(PRESETS)}")
    parser.add_argument("--sym-all", action="store_true", help="bc+sym at every budget too")
    parser.add_argument("--report-only", action="store_true", help="no training")
    args = parser.parse_args()
    torch.set_num_threads(1)
    settings = TrainSettings.preset(args.preset)
    if not args.report_only:
        run_all(args, settings)
    report(settings, args.preset)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
