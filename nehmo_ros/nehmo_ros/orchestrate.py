"""`orchestrate`: run the ROS node suite as separate processes, evaluate from the bags.

    orchestrate run --cell dual_ur5 --seed 0 --count 3 --planner nehmo --model synthetic --out out/
    orchestrate run --scenarios set.json --episodes 0,2 --out out/
    orchestrate evaluate out/episode_000 out/episode_001
    orchestrate replay out/episode_000 --rate 2.0

``run``: for every episode of the scenario set it starts the ``recorder`` (waits until it
records), one ``arm_planner`` per arm (with ``--planner-processes K``, the arms' planner nodes
in K ``arm_planners`` processes instead: :mod:`.planner_group`) and the ``sim_bridge``
(simulated time on ``/clock``, every node with ``use_sim_time``), each as its own rclpy
process, in a DDS domain of its own (``ROS_DOMAIN_ID``) kept on this machine
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``). The bridge starts the episode once every
planner is up and exits when it ends; then planners and recorder get SIGINT (SIGKILL after a
bounded wait). Every episode bag (``<out>/episode_NNN/``, rosbag2 layout) is evaluated with
:mod:`nehmo_core.eval.metrics` (the batch runner's metrics); the per-episode results and the
aggregate (SR, CR, planning time, MPL) go to ``<out>/summary.json``. An episode whose node
exits early (its error line is printed at once) or whose bag cannot be read counts as an
``error``; the command then exits 1. Process output goes to
``<out>/logs/<episode>/`` (``commands.json`` there holds every process's command line).

``replay`` republishes a bag's topics through rclpy with their recorded timing (scaled by
``--rate``), for inspection with other tools or re-recording; it starts after ``--wait`` s of
discovery or, with ``--min-subscribers N``, as soon as every topic's publisher has N
subscriptions (an error if not within ``--wait`` s), and after the last message waits up to
``--wait`` s for reliable subscribers to acknowledge. ``evaluate`` prints the metrics of bags
(an unreadable one is an ``error`` in them, named on stderr, and the exit status is 2).

The pieces: :mod:`.suite_settings`, :mod:`.processes`, :mod:`.suite` (episodes and the
summary), :mod:`.replay`; this module is the command line.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.eval.metrics import aggregate, evaluate_or_error
from nehmo_core.sim.scenario_files import draw_scenario_set, load_scenario_set, save_scenario_set
from nehmo_ros.oneline import one_line
from nehmo_ros.replay import replay
from nehmo_ros.suite import format_metrics, run_suite
from nehmo_ros.suite_settings import SuiteSettings, layout_hint

__all__ = ["build_parser", "main"]


def _episodes(text: str | None, count: int) -> list[int]:
    if not text:
        return list(range(count))
    out = [int(x) for x in text.split(",") if x.strip()]
    bad = [x for x in out if not 0 <= x < count]
    if bad:
        raise InvalidValueError("--episodes", f"must lie in [0, {count - 1}]", bad)
    return out


def task_files(task_path: str, out_dir: Path) -> Path:
    """A task file (Ha et al.'s format, e.g. from ``nehmo tasks generate``) as a cell YAML and a
    one-scenario set beside it in ``out_dir``; returns the scenario set's path."""
    import yaml

    from nehmo_core.eval.ha_tasks import load_task
    from nehmo_core.sim.scenarios import ScenarioSet

    task = load_task(task_path)
    arms = [
        {
            "id": a.arm_id,
            "robot": a.robot.name,
            "base": {"xyz": [float(v) for v in a.base.xyz], "rpy": [float(v) for v in a.base.rpy]},
        }
        for a in task.cell.arms
    ]
    cell_file = out_dir / f"{task.task_id}.cell.yaml"
    cell_file.write_text(yaml.safe_dump({"name": task.task_id, "arms": arms}, sort_keys=False))
    scenarios = ScenarioSet(
        str(cell_file), 0, (0,), (task.scenario,), 1, {"task": str(Path(task_path).resolve())}
    )
    return save_scenario_set(scenarios, out_dir / f"{task.task_id}.scenarios.json").resolve()


def scenario_file_for(args: argparse.Namespace, out_dir: Path) -> Path:
    """The scenario set to run: a task's, given, or drawn from ``--seed``/``--count``."""
    if getattr(args, "task", None):
        return task_files(args.task, out_dir)
    if args.scenarios:
        return Path(args.scenarios).resolve()
    scenarios = draw_scenario_set(args.cell, args.seed, args.count)
    return save_scenario_set(scenarios, out_dir / "scenarios.json").resolve()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="orchestrate", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run episodes through the node suite and evaluate them")
    run.add_argument("--cell", default="dual_ur5", help="shipped cell name or YAML path")
    run.add_argument("--scenarios", help="scenario set JSON (default: draw --count from --seed)")
    run.add_argument(
        "--task",
        help="a task file (Ha et al.'s format, nehmo tasks generate): its cell and scenario",
    )
    run.add_argument("--seed", type=int, default=0)
    run.add_argument("--count", type=int, default=1)
    run.add_argument("--episodes", help="comma-separated episode positions (default: all)")
    run.add_argument("--planner", default="nehmo", help="kind, or one per arm joined by '/'")
    run.add_argument("--model", default="shipped", help="shipped | synthetic | [KIND=]PATH,...")
    run.add_argument("--time-limit", type=float, default=20.0, help="[s] simulated")
    run.add_argument("--physics-rate", type=float, default=100.0, help="[Hz]")
    run.add_argument("--real-time-factor", type=float, default=1.0)
    run.add_argument("--domain-id", type=int, help="DDS domain (default: one for this run)")
    run.add_argument(
        "--install-space",
        default="",
        help="run the nodes from a colcon install space (ros_ws/install)",
    )
    run.add_argument(
        "--planner-processes",
        type=int,
        default=0,
        help="run the planners in this many processes, several nodes each (default 0: one "
        "process per arm)",
    )
    run.add_argument(
        "--bridge-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a sim_bridge parameter, e.g. command_validity=0.2 (repeatable)",
    )
    run.add_argument(
        "--planner-param",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="set a parameter of every planner node, e.g. plan_age=.inf (repeatable)",
    )
    run.add_argument("--out", default="nehmo_runs", help="output directory")
    run.add_argument("--render", action="store_true", help="render the first episode")
    ev = sub.add_parser("evaluate", help="metrics of episode logs")
    ev.add_argument("logs", nargs="+")
    rp = sub.add_parser("replay", help="republish a log's topics with their timing")
    rp.add_argument("log")
    rp.add_argument("--rate", type=float, default=1.0, help="playback speed factor")
    rp.add_argument("--topics", nargs="*", help="only these topics")
    rp.add_argument("--domain-id", type=int)
    rp.add_argument(
        "--wait",
        type=float,
        default=1.0,
        help="[s] for discovery before the first message (at most, with --min-subscribers) "
        "and for reliable subscribers to acknowledge the last ones",
    )
    rp.add_argument(
        "--min-subscribers",
        type=int,
        default=0,
        help="start once every topic's publisher has this many subscriptions, an error if not "
        "within --wait (default 0: wait --wait s)",
    )
    return parser


def _split(text: str, option: str) -> tuple[str, str]:
    """``NAME=VALUE`` as its name and its raw value; an error naming ``option`` otherwise."""
    name, sep, value = text.partition("=")
    if not sep or not name.strip():
        raise InvalidValueError(option, "must be NAME=VALUE", text)
    return name.strip(), value.strip()


def _assignment(text: str, option: str = "--bridge-param") -> tuple[str, object]:
    """``NAME=VALUE`` with VALUE read as a YAML scalar (0.2, true, text)."""
    import yaml

    name, value = _split(text, option)
    return name, yaml.safe_load(value)


def _ros_param(text: str) -> str:
    """``NAME=VALUE`` as a ``--ros-args -p`` item, ``NAME:=VALUE``."""
    name, value = _split(text, "--planner-param")
    return f"{name}:={value}"


def _run(args: argparse.Namespace) -> int:
    out_dir = Path(args.out).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    scenario_file = scenario_file_for(args, out_dir)
    scenarios = load_scenario_set(scenario_file)
    count = len(scenarios)
    settings = SuiteSettings(
        planner=args.planner,
        model=args.model,
        time_limit=args.time_limit,
        physics_rate=args.physics_rate,
        real_time_factor=args.real_time_factor,
        domain_id=args.domain_id,
        install_space=args.install_space,
        planner_processes=args.planner_processes,
        bridge_params=tuple(_assignment(text) for text in args.bridge_param),
        extra_planner_args=tuple(
            arg for text in args.planner_param for arg in ("-p", _ros_param(text))
        ),
    )
    if hint := layout_hint(len(scenarios.scenarios[0].start), settings):
        print(f"orchestrate: note: {hint}", file=sys.stderr, flush=True)
    summary = run_suite(scenario_file, _episodes(args.episodes, count), out_dir, settings)
    print(format_metrics(summary["metrics"]))
    print(f"summary: {out_dir / 'summary.json'}")
    first = summary["episodes"][0] if summary["episodes"] else None
    if args.render and first and first["outcome"] != "error":
        from nehmo_core.eval.render import render_episode

        for path in render_episode(summary["episodes"][0]["log"], out_dir / "renders"):
            print(f"render: {path}")
    return 1 if summary["metrics"]["errors"] else 0


@contextmanager
def _readable(path: str) -> Iterator[None]:
    """Turn the MCAP library's errors about ``path`` into one that names the file."""
    from mcap.exceptions import McapError

    try:
        yield
    except McapError as exc:
        raise NehmoError(f"{path}: not a readable MCAP log ({exc})") from None


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the `orchestrate` console script."""
    args = build_parser().parse_args(argv)
    try:
        if args.command == "run":
            return _run(args)
        if args.command == "evaluate":
            results = [evaluate_or_error(path) for path in args.logs]
            for path, r in zip(args.logs, results, strict=True):
                if r.outcome == "error":
                    print(f"orchestrate: error: {r.error}", file=sys.stderr)
                else:
                    print(
                        f"{path}: {r.outcome} at {r.end_time:.2f} s, path {r.path_length:.2f} rad"
                    )
            print(format_metrics(aggregate(results).to_dict()))
            return 2 if any(r.outcome == "error" for r in results) else 0
        with _readable(args.log):
            return replay(
                Path(args.log),
                args.rate,
                args.topics,
                args.domain_id,
                args.wait,
                args.min_subscribers,
            )
    except (NehmoError, OSError) as exc:
        print(f"orchestrate: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("orchestrate: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
