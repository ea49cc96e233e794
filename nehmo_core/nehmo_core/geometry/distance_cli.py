"""``nehmo distance``: generate datasets, train and evaluate the learned arm-arm distance."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from nehmo_core.cluster import make_executor, parse_cluster
from nehmo_core.errors import InvalidValueError, ModelFileError, as_options
from nehmo_core.geometry.distance_data import (
    CONDITIONED_PAIRS,
    PAIRS,
    DatasetSpec,
    generate,
)
from nehmo_core.geometry.distance_model import distance_model_path, load_distance_file
from nehmo_core.geometry.distance_train import (
    DistanceTrainSettings,
    calibrate_offset,
    evaluate,
    train,
)
from nehmo_core.hjr.train_cli import parse_count
from nehmo_core.robots.registry import pair_base_range

ALL_PAIRS = sorted([*PAIRS, *CONDITIONED_PAIRS])
_GENERATE_OPTIONS = {"n_uniform": "--uniform", "n_boundary": "--boundary"}
_TRAIN_OPTIONS = {
    "epochs": "--epochs",
    "seed": "--seed",
    "hidden": "--hidden",
    "keypoints": "--keypoints",
}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    g = sub.add_parser("generate", help="sample joint pairs and label them with exact distances")
    g.add_argument("--pair", choices=ALL_PAIRS, required=True)
    g.add_argument("--uniform", default="300k", help="uniform samples (e.g. 300k, 0: none)")
    g.add_argument("--boundary", default="500k", help="near-contact samples (e.g. 500k, 0: none)")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--workers", type=int, default=2)
    g.add_argument(
        "--cluster",
        default="local",
        help="where the labels are computed: 'local' (--workers processes), 'ray', "
        "'ray://HOST:PORT' or 'ray:HOST:PORT' (docs/cluster.md); the labels are the same",
    )
    g.add_argument("--out", type=Path, required=True, help="output .npz file")
    t = sub.add_parser("train", help="fit a distance model on a generated dataset")
    t.add_argument("--pair", choices=ALL_PAIRS, required=True)
    t.add_argument(
        "--data",
        type=Path,
        nargs="+",
        required=True,
        help="training .npz files from 'generate' (several are joined; distinct seeds)",
    )
    t.add_argument("--test", type=Path, help="held-out .npz (fresh seed) to report accuracy on")
    t.add_argument("--hidden", type=str, default="128,128,128", help="hidden widths, e.g. 128,128")
    t.add_argument("--epochs", type=int, default=DistanceTrainSettings.epochs)
    t.add_argument(
        "--keypoints",
        default=DistanceTrainSettings.keypoints,
        help="where the model's keypoints come from: 'links' (the robot description's link "
        "origins and points) or 'geometry' (points in the bulk of each link's collision "
        "geometry, stored in the model card)",
    )
    t.add_argument("--seed", type=int, default=0)
    t.add_argument("--out", type=Path, help="output .safetensors (default: the shipped model)")
    c = sub.add_parser(
        "calibrate",
        help="raise a model's conservative offset so a calibration set meets a false-safe rate",
    )
    c.add_argument("--pair", choices=ALL_PAIRS, required=True)
    c.add_argument("--data", type=Path, required=True, help="calibration .npz (not test data)")
    c.add_argument("--test", type=Path, help="held-out .npz to re-report accuracy on")
    c.add_argument("--target", type=float, default=0.015, help="false-safe rate to reach")
    c.add_argument(
        "--unbiased",
        action="store_true",
        help="no offset: the model keeps its fit (the offset from training removed); its "
        "conservative level is then what 'nehmo pair build' certifies on contact states",
    )
    c.add_argument("--model", type=Path, help="model .safetensors (default: the shipped model)")
    e = sub.add_parser("evaluate", help="accuracy of a distance model on a labelled .npz")
    e.add_argument("--pair", choices=ALL_PAIRS, required=True)
    e.add_argument("--data", type=Path, required=True)
    e.add_argument("--model", type=Path, help="model .safetensors (default: the shipped model)")


def run(args: argparse.Namespace) -> int:
    if args.action == "generate":
        with as_options(_GENERATE_OPTIONS):
            spec = DatasetSpec(
                args.pair,
                parse_count(args.uniform, "--uniform", minimum=0),
                parse_count(args.boundary, "--boundary", minimum=0),
                args.seed,
            )
            if args.workers < 1:
                raise InvalidValueError("--workers", "must be >= 1", args.workers)
            cluster = parse_cluster(args.cluster)
            t0 = time.perf_counter()
            executor = make_executor(1, cluster) if cluster.is_ray else None
            try:
                q, d = generate(spec, workers=args.workers, executor=executor)
            finally:
                if executor is not None:
                    executor.shutdown()
        wall = time.perf_counter() - t0
        args.out.parent.mkdir(parents=True, exist_ok=True)
        meta = {"spec": spec.__dict__, "wall_time_s": wall, "n": len(d)}
        np.savez_compressed(args.out, q=q, d=d, meta=json.dumps(meta))
        print(
            f"{len(d)} samples in {wall:.0f} s -> {args.out} "
            f"(colliding {np.mean(d < 0):.1%}, |d| < 0.1 m {np.mean(np.abs(d) < 0.1):.1%})"
        )
        return 0
    if args.action == "train":
        return _train(args)
    if args.action == "calibrate":
        return _calibrate(args)
    if args.action == "evaluate":
        path = args.model or distance_model_path(args.pair)
        q, d, _ = load_dataset(args.data)
        print(json.dumps(evaluate(load_distance_file(path, args.pair), q, d), indent=2))
        return 0
    raise AssertionError(args.action)


def load_dataset(path: Path) -> tuple[np.ndarray, np.ndarray, dict[str, object]]:
    """Read a dataset written by ``generate`` (plain arrays; no pickled objects)."""
    if not path.exists():
        raise ModelFileError(f"dataset not found: {path}")
    with np.load(path, allow_pickle=False) as f:
        return f["q"], f["d"], json.loads(str(f["meta"]))


def _calibrate(args: argparse.Namespace) -> int:
    """Offset = max(current, the one the calibration set needs), or 0 with ``--unbiased``; the
    card records the offset before, the one the calibration set needed and the choice."""
    path = args.model or distance_model_path(args.pair)
    model = load_distance_file(path, args.pair)
    card = json.loads(path.with_suffix(".json").read_text())
    before = float(model.output_offset)
    q, d, meta = load_dataset(args.data)
    needed = calibrate_offset(model, q, d, args.target)  # sets the offset it found
    offset = 0.0 if args.unbiased else max(before, needed)
    with torch.no_grad():
        model.output_offset.fill_(offset)
    card["training"]["output_offset_m"] = offset
    card.setdefault("calibrations", []).append(
        {
            "data": meta,
            "target_false_safe": args.target,
            "needed_m": needed,
            "before_m": before,
            "unbiased": bool(args.unbiased),
        }
    )
    if args.test is not None:
        qt, dt, meta_t = load_dataset(args.test)
        card["accuracy_held_out"] = {"data": meta_t, **evaluate(model, qt, dt)}
    card.pop("config", None)
    card.pop("format_version", None)
    model.save(path, card)
    print(f"offset {before * 1000:.1f} mm -> {offset * 1000:.1f} mm; wrote {path}")
    return 0


def _training_data(
    pair: str, paths: list[Path]
) -> tuple[np.ndarray, np.ndarray, dict[str, object] | list[dict[str, object]]]:
    """Join the datasets of ``paths``: all of ``pair``, each from its own seed."""
    parts = [load_dataset(p) for p in paths]
    seeds: dict[object, Path] = {}
    for path, (_, _, meta) in zip(paths, parts, strict=True):
        spec = meta.get("spec")
        got = spec.get("pair") if isinstance(spec, dict) else None
        if got != pair:
            raise InvalidValueError("--data", f"must hold samples of pair {pair!r}", str(path))
        seed = spec.get("seed") if isinstance(spec, dict) else None
        if seed in seeds:
            raise InvalidValueError(
                "--data", f"files must come from distinct seeds ({seeds[seed].name} too)", str(path)
            )
        seeds[seed] = path
    q = np.concatenate([p[0] for p in parts])
    d = np.concatenate([p[1] for p in parts])
    metas = [p[2] for p in parts]
    return q, d, metas[0] if len(metas) == 1 else metas


def _train(args: argparse.Namespace) -> int:
    try:
        hidden = tuple(int(h) for h in args.hidden.split(","))
    except ValueError:
        raise InvalidValueError(
            "--hidden", "must be comma-separated integers", args.hidden
        ) from None
    with as_options(_TRAIN_OPTIONS):
        settings = DistanceTrainSettings(
            hidden=hidden, epochs=args.epochs, seed=args.seed, keypoints=args.keypoints
        )
    q, d, meta = _training_data(args.pair, args.data)
    model, summary = train(args.pair, q, d, settings)
    card: dict[str, object] = {
        "pair": args.pair,
        "what": "learned signed distance [m] between the two arms' collision geometry",
        "inputs": (
            "q = (q_arm1, q_arm2, r): joints [rad] in each robot's URDF joint order, arm 2's base "
            f"at (r, 0, 0) facing arm 1, r in {list(pair_base_range(args.pair))} m"
            if args.pair in CONDITIONED_PAIRS
            else "q = (q_arm1, q_arm2) [rad] in each robot's URDF joint order"
        ),
        "data": {"train": meta, "file": ", ".join(p.name for p in args.data)},
        "training": {**settings.__dict__, **summary},
    }
    if args.test is not None:
        qt, dt, meta_t = load_dataset(args.test)
        card["accuracy_held_out"] = {"data": meta_t, **evaluate(model, qt, dt)}
    out = args.out or distance_model_path(args.pair)
    model.save(out, card)
    print(
        json.dumps({k: card[k] for k in ("training", "accuracy_held_out") if k in card}, indent=2)
    )
    print(f"wrote {out} and {out.with_suffix('.json')}")
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="nehmo distance")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
