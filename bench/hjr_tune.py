"""One tuning try: train a value network with given settings, validate it, log cost and error.

    ./run python bench/hjr_tune.py --system air3d --samples 4M --tag lr1e-3_cos \\
        --set learning_rate=1e-3 --set lr_schedule=cosine --set batch_size=2000

``--set key=value`` overrides a :class:`TrainSettings` field (``network.width=64`` for network
fields); values are parsed as JSON where they can be, else kept as strings. Every try appends one
JSON line (settings, wall time, samples/s, validation rows) to ``bench/results/hjr_tuning.jsonl``.
``--report`` rewrites the table of tries in ``bench/results/hjr_tuning.md`` from those lines,
keeping the hand-written notes above the ``<!-- tries -->`` marker.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import torch

from nehmo_core.hjr.ground_truth import ground_truth, validate
from nehmo_core.hjr.model_files import load_value_function
from nehmo_core.hjr.systems import HJISystem, make_system
from nehmo_core.hjr.train import train
from nehmo_core.hjr.train_cli import parse_count
from nehmo_core.hjr.train_settings import TrainSettings

RESULTS = Path(__file__).resolve().parent / "results"
TUNING_LOG = RESULTS / "hjr_tuning.jsonl"
TUNING_MD = RESULTS / "hjr_tuning.md"
MARKER = "<!-- tries -->"


def parse_value(text: str) -> Any:
    try:
        return json.loads(text)
    except json.JSONDecodeError:
        return text


def apply_overrides(settings: TrainSettings, pairs: list[str]) -> TrainSettings:
    """``["learning_rate=1e-3", "network.width=64"]`` applied to ``settings``."""
    top: dict[str, Any] = {}
    net: dict[str, Any] = {}
    for pair in pairs:
        key, _, value = pair.partition("=")
        if key.startswith("network."):
            net[key.removeprefix("network.")] = parse_value(value)
        else:
            top[key] = parse_value(value)
    return replace(settings, network=replace(settings.network, **net), **top)


def validation_taus(system: HJISystem) -> list[float]:
    """τ = 0, a few intermediate times and T [s] (every stored τ for the cheap Air3D grid)."""
    truth = ground_truth(system)
    taus = [float(t) for t in truth.taus]
    if system.state_dim <= 3:
        return taus
    return sorted({taus[0], taus[len(taus) // 2], *taus[-2:]})


def train_and_validate(system: HJISystem, settings: TrainSettings, out_dir: Path) -> dict[str, Any]:
    """Train (resuming a partial run in ``out_dir``) and validate; the run's record."""
    done = (out_dir / "model.json").exists()
    if not done:
        train(system, settings, out_dir, resume=True, progress=False)
    meta = json.loads((out_dir / "model.json").read_text())
    start = time.perf_counter()
    vf = load_value_function(out_dir)
    rows = validate(vf, system, taus=validation_taus(system))
    return {
        "system": system.name,
        "variant": settings.variant,
        "samples": settings.samples,
        "seed": settings.seed,
        "settings": settings.to_dict(),
        "train_wall_s": meta["wall_seconds"],
        "samples_per_s": settings.samples / max(meta["wall_seconds"], 1e-9),
        "validate_wall_s": time.perf_counter() - start,
        "mean_abs_error_T": rows[-1].mean_abs_error,
        "rows": [r.__dict__ for r in rows],
    }


def _describe(settings: dict[str, Any]) -> str:
    net = settings["network"]
    return (
        f"{net['hidden_layers']}×{net['width']}, b {settings['batch_size']}, "
        f"lr {settings['learning_rate']:g} {settings.get('lr_schedule', 'constant')}, "
        f"pre {settings['pretrain_fraction']:.3g}, cur {settings['curriculum_fraction']:.3g}"
        + (f", ω0 {net['omega0']:g}" if net.get("omega0", 30.0) != 30.0 else "")
        + (
            f", Dirichlet {settings['dirichlet_weight']:g}"
            if settings["dirichlet_weight"] != 40
            else ""
        )
        + (f", seed {settings['seed']}" if settings.get("seed", 0) else "")
    )


def write_report() -> None:
    """Rewrite the table of tries under :data:`MARKER` in ``hjr_tuning.md``."""
    records = [json.loads(line) for line in TUNING_LOG.read_text().splitlines() if line]
    head = TUNING_MD.read_text().split(MARKER)[0] if TUNING_MD.exists() else "# HJR tuning\n\n"
    lines = [
        MARKER,
        "",
        "| # | tag | system | variant | samples | settings | train [s] | samples/s "
        "| err τ_mid | err T |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for i, r in enumerate(records, 1):
        mid = r["rows"][len(r["rows"]) // 2]
        lines.append(
            f"| {i} | {r['tag']} | {r['system']} | {r['variant']} | {r['samples'] / 1e6:g}M | "
            f"{_describe(r['settings'])} | {r['train_wall_s']:.0f} | {r['samples_per_s']:.0f} | "
            f"{mid['mean_abs_error']:.4f} (τ={mid['tau']:.1f}) | **{r['mean_abs_error_T']:.4f}** |"
        )
    TUNING_MD.write_text(head + "\n".join(lines) + "\n")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--system", default="air3d")
    parser.add_argument("--variant", default="bc+sym")
    parser.add_argument("--samples", default="4M")
    parser.add_argument("--preset", default="cpu")
    parser.add_argument("--set", action="append", default=[], help="field=value override")
    parser.add_argument("--tag", help="name of the try (its run directory)")
    parser.add_argument("--report", action="store_true", help="only rewrite hjr_tuning.md")
    parser.add_argument("--runs", default=os.environ.get("NEHMO_TUNE_DIR", "/tmp/nehmo_tune"))
    args = parser.parse_args()
    if args.report:
        write_report()
        return 0
    if not args.tag:
        parser.error("--tag is required for a try")
    torch.set_num_threads(1)
    system = make_system(args.system)
    settings = TrainSettings.preset(args.preset, variant=args.variant)
    settings = apply_overrides(replace(settings, samples=parse_count(args.samples)), args.set)
    out_dir = Path(args.runs) / f"{args.system}_{args.variant.replace('+', '_')}_{args.tag}"
    record = {"tag": args.tag, **train_and_validate(system, settings, out_dir)}
    RESULTS.mkdir(parents=True, exist_ok=True)
    with TUNING_LOG.open("a") as handle:
        handle.write(json.dumps(record) + "\n")
    mid = record["rows"][len(record["rows"]) // 2]
    print(
        f"{args.tag}: {args.system} {args.variant} {args.samples}: "
        f"mean|err| T {record['mean_abs_error_T']:.4f}, τ={mid['tau']:.2f} "
        f"{mid['mean_abs_error']:.4f}, max T {record['rows'][-1]['max_abs_error']:.3f}; "
        f"{record['train_wall_s']:.0f} s ({record['samples_per_s']:.0f}/s)"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
