"""``nehmo distance``: generate datasets, train and evaluate the learned arm-arm distance."""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from nehmo_core.geometry.distance_data import PAIRS, DatasetSpec, generate


def _count(text: str) -> int:
    """Parse counts like ``300k`` or ``2M``."""
    t = text.strip().lower()
    mult = {"k": 1_000, "m": 1_000_000}.get(t[-1:], 1)
    return int(float(t[:-1] if mult > 1 else t) * mult)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    sub = parser.add_subparsers(dest="action", required=True)
    g = sub.add_parser("generate", help="sample joint pairs and label them with exact distances")
    g.add_argument("--pair", choices=sorted(PAIRS), required=True)
    g.add_argument("--uniform", type=_count, default=300_000, help="uniform samples (e.g. 300k)")
    g.add_argument("--boundary", type=_count, default=500_000, help="near-contact samples")
    g.add_argument("--seed", type=int, default=0)
    g.add_argument("--workers", type=int, default=2)
    g.add_argument("--out", type=Path, required=True, help="output .npz file")


def run(args: argparse.Namespace) -> int:
    if args.action == "generate":
        spec = DatasetSpec(args.pair, args.uniform, args.boundary, args.seed)
        t0 = time.perf_counter()
        q, d = generate(spec, workers=args.workers)
        wall = time.perf_counter() - t0
        args.out.parent.mkdir(parents=True, exist_ok=True)
        meta = {"spec": spec.__dict__, "wall_time_s": wall, "n": len(d)}
        np.savez_compressed(args.out, q=q, d=d, meta=json.dumps(meta))
        print(
            f"{len(d)} samples in {wall:.0f} s -> {args.out} "
            f"(colliding {np.mean(d < 0):.1%}, |d| < 0.1 m {np.mean(np.abs(d) < 0.1):.1%})"
        )
        return 0
    raise AssertionError(args.action)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="nehmo distance")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
