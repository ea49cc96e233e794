"""Run the ROS 2 node suite on one episode of a custom cell and print the metrics from its bag.

    ./run python examples/03_node_suite.py --time-limit 5 --out out/example03

The ``sim_bridge``, one ``arm_planner`` per arm and the ``recorder`` run as separate rclpy
processes in a DDS domain of their own, on simulated time (as ``orchestrate run`` does). The
cell is written here: two UR5s 0.6 m apart along y (the shipped ``dual_ur5`` turned by 90°,
so the shipped ``ur5_ur5`` value function covers the pair). Every node gets the cell by name;
naming the cell by its YAML path lets each of them load it. ``--cell`` takes a shipped cell
name or another YAML path instead. The scenario set is drawn from ``--seed`` and saved next
to the bag.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import save_scenario_set
from nehmo_core.sim.scenarios import generate_scenario_set
from nehmo_ros.suite import format_metrics, run_suite
from nehmo_ros.suite_settings import SuiteSettings


def write_cell(path: Path) -> Path:
    """Two UR5s facing each other 0.6 m apart along y; named by the file's absolute path."""
    path = path.resolve()
    half_pi = math.pi / 2
    path.write_text(
        f"name: {path}\n"
        "arms:\n"
        "  - id: ur5_0\n"
        "    robot: ur5\n"
        f"    base: {{xyz: [0.0, 0.0, 0.0], rpy: [0.0, 0.0, {half_pi}]}}\n"
        "  - id: ur5_1\n"
        "    robot: ur5\n"
        f"    base: {{xyz: [0.0, 0.6, 0.0], rpy: [0.0, 0.0, {-half_pi}]}}\n"
    )
    return path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cell", default="", help="shipped name or YAML path (default: custom)")
    parser.add_argument("--seed", type=int, default=0, help="scenario set seed")
    parser.add_argument("--planner", default="nehmo", help="kind, or one per arm joined by /")
    parser.add_argument("--model", default="shipped", help="shipped | synthetic | [KIND=]PATH")
    parser.add_argument("--time-limit", type=float, default=20.0, help="[s] simulated")
    parser.add_argument("--out", default="out/example03", help="output directory")
    args = parser.parse_args()

    out = Path(args.out).resolve()
    out.mkdir(parents=True, exist_ok=True)
    cell = load_cell(args.cell or write_cell(out / "cell.yaml"))
    scenario_file = save_scenario_set(
        generate_scenario_set(cell, args.seed, 1), out / "scenarios.json"
    )
    settings = SuiteSettings(planner=args.planner, model=args.model, time_limit=args.time_limit)
    summary = run_suite(scenario_file, [0], out, settings)
    episode = summary["episodes"][0]
    print(f"cell {Path(cell.name).name}: arms {list(cell.arm_ids)}")
    print(format_metrics(summary["metrics"]))
    print(f"outcome {episode['outcome']}; bag {episode['log']}")
    print(f"summary {out / 'summary.json'}")


if __name__ == "__main__":
    main()
