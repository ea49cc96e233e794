"""Plan one dual-UR5 episode with the batch runner and print its metrics.

    ./run python examples/02_batch_episode.py --row nehmo --seed 0 --index 0

Every arm runs its own planner (``--row``: ``nehmo``, ``naive``, ``nehmo/reckless``, ...) with
the shipped value functions; the episode is simulated at 25 Hz with exact collision checks and
logged as a rosbag2 bag, and the metrics are computed from that bag (as ``nehmo evaluate``).
"""

from __future__ import annotations

import argparse
import tempfile
from dataclasses import replace
from pathlib import Path

from nehmo_core.eval.batch import BatchConfig, run_rows
from nehmo_core.eval.setups import get_setup
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import generate_scenario_set


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--row", default="nehmo", help="planner kind, or one per arm joined by /")
    parser.add_argument("--seed", type=int, default=0, help="scenario set seed")
    parser.add_argument("--index", type=int, default=0, help="scenario of the set")
    parser.add_argument("--time-limit", type=float, default=20.0, help="[s] simulated")
    parser.add_argument("--out", default="", help="output directory (default: a temporary one)")
    args = parser.parse_args()

    cell = load_cell(get_setup("dual_ur5").cell)
    drawn = generate_scenario_set(cell, args.seed, args.index + 1)
    one = replace(drawn, indices=drawn.indices[-1:], scenarios=drawn.scenarios[-1:])
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(args.out or tmp)
        config = BatchConfig(
            setup="dual_ur5",
            out_dir=out,
            episode_overrides=(("time_limit", args.time_limit),),
        )
        (run,) = run_rows(config, [args.row], one, progress=False)
        result = run.results[0]
        m = run.metrics
        print(f"row {run.row}: {run.kinds}")
        print(
            f"outcome {result.outcome} at {result.end_time:.2f} s simulated, {result.ticks} ticks"
        )
        print(f"path length {result.path_length:.2f} rad; fail-safe commands {result.fail_safe}")
        print(f"success rate {m.sr:.0f} %, collision rate {m.cr:.0f} %")
        print(f"planning time {m.plan_time_ms[0]:.2f} ± {m.plan_time_ms[1]:.2f} ms per tick")
        print(f"log: {run.logs[0]}" if args.out else "log: (temporary)")


if __name__ == "__main__":
    main()
