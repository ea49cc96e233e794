"""The main job (``./run demo``): a dual-UR5 episode (or any cell's) through the ROS 2 node suite.

The ``sim_bridge``, one ``arm_planner`` per arm and the ``recorder`` run as separate processes
on rclpy (ROS 2 Jazzy, a DDS domain of their own, discovery kept on this machine), started,
stopped and evaluated by ``nehmo_ros.orchestrate``. The scenario is one where the naive planner
collides within a second, so the arms must coordinate. The metrics come from the rosbag2 bag alone
(``nehmo_core.eval``); a GIF and a distance plot of the episode are rendered from it too.

The planners use the shipped UR5-UR5 value function (``--model shipped``); ``--model
synthetic`` gives stand-ins for plumbing checks, ``--model PATH`` a training run directory.
Needs the ``nehmo_ros`` and ``sim_bridge`` packages and ROS 2 Jazzy's rclpy installed
(``./run`` installs them).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from nehmo_core.errors import InvalidValueError
from nehmo_ros.suite import format_metrics, run_suite
from nehmo_ros.suite_settings import SuiteSettings


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--cell",
        default="dual_ur5",
        help="shipped cell name or a cell YAML path (any layout, e.g. "
        "examples/cells/irregular_three_ur5.yaml)",
    )
    parser.add_argument("--seed", type=int, default=0, help="scenario set seed")
    parser.add_argument("--index", type=int, default=0, help="scenario index in the set")
    parser.add_argument("--planner", default="nehmo", help="planner kind (or one per arm, '/')")
    parser.add_argument("--model", default="shipped", help="shipped | synthetic | PATH")
    parser.add_argument("--time-limit", type=float, default=20.0, help="[s] of simulated time")
    parser.add_argument("--out", default="out/demo", help="output directory")
    parser.add_argument("--no-render", action="store_true", help="skip the GIF and plot")


def run(args: argparse.Namespace) -> int:
    from nehmo_core.eval.render import render_episode
    from nehmo_core.robots import load_cell
    from nehmo_core.sim.scenario_files import draw_scenario_set, save_scenario_set

    if args.index < 0:
        raise InvalidValueError("index", "must be >= 0", args.index)
    out = Path(args.out).resolve()
    if out.exists() and not out.is_dir():
        raise InvalidValueError("out", "must be a directory (it is a file)", str(out))
    settings = SuiteSettings(planner=args.planner, model=args.model, time_limit=args.time_limit)
    out.mkdir(parents=True, exist_ok=True)
    cell = load_cell(args.cell)
    scenarios = draw_scenario_set(args.cell, args.seed, args.index + 1)
    scenario_file = save_scenario_set(scenarios, out / "scenarios.json")
    print(
        f"{cell.name}, scenario {args.index} of seed {args.seed}: sim_bridge + "
        f"{len(cell.arms)} x arm_planner ({args.planner}, model {args.model}) + recorder "
        "as separate rclpy processes (ROS 2 Jazzy, this machine only)",
        flush=True,
    )
    t0 = time.perf_counter()
    summary = run_suite(scenario_file, [args.index], out, settings)
    episode = summary["episodes"][0]
    evaluated = episode["outcome"] != "error"
    print(f"  {format_metrics(summary['metrics'])}")
    if evaluated:
        print(f"  outcome {episode['outcome']} at {episode['end_time']:.2f} s simulated")
    print(f"  middleware: {summary.get('rmw') or 'unknown'} (rclpy)")
    print(f"  bag:      {episode['log']}")
    print(f"  summary:  {out / 'summary.json'}")
    print(f"  process outputs: {out / 'logs'}")
    if evaluated and not args.no_render:
        for path in render_episode(episode["log"], out / "renders"):
            print(f"  render:   {path}")
    print(f"  wall time: {time.perf_counter() - t0:.1f} s")
    return 0 if evaluated else 1


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m nehmo_ros.demo", description=__doc__)
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
