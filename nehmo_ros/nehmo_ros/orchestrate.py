"""`orchestrate`: run the ROS node suite as separate processes, evaluate from the bags.

    orchestrate run --cell dual_ur5 --seed 0 --count 3 --planner nehmo --model synthetic --out out/
    orchestrate run --scenarios set.json --episodes 0,2 --out out/
    orchestrate evaluate out/episode_000 out/episode_001
    orchestrate replay out/episode_000 --rate 2.0

``run``: for every episode of the scenario set it starts the ``recorder`` (waits until it
records), one ``arm_planner`` per arm and the ``sim_bridge`` (simulated time on ``/clock``,
every node with ``use_sim_time``), each as its own rclpy process, in a DDS domain of its own
(``ROS_DOMAIN_ID``) kept on this machine (``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``). The bridge
starts the episode once every planner is up and exits when it ends; then planners and recorder
get SIGINT (SIGKILL after a bounded wait). Every episode bag (``<out>/episode_NNN/``, rosbag2
layout) is evaluated with
:mod:`nehmo_core.eval.metrics` (the batch runner's metrics); the per-episode results and the
aggregate (SR, CR, planning time, MPL) go to ``<out>/summary.json``. Process output goes to
``<out>/logs/<episode>/`` (``commands.json`` there holds every process's command line).

``replay`` republishes a bag's topics through rclpy with their recorded timing (scaled by
``--rate``), for inspection with other tools or re-recording; ``evaluate`` prints the metrics of
bags.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Iterator, Sequence
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from nehmo_core.errors import InvalidValueError, NehmoError, UnknownNameError
from nehmo_core.eval.metrics import EpisodeResult, aggregate, evaluate_log
from nehmo_core.eval.report import json_safe
from nehmo_core.eval.setups import parse_row
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import (
    ScenarioSet,
    generate_scenario_set,
    load_scenario_set,
    save_scenario_set,
)
from nehmo_ros.oneline import one_line

__all__ = ["SuiteSettings", "main", "run_episode", "run_suite"]


@dataclass(frozen=True)
class SuiteSettings:
    """How the suite is run (times [s], rates [Hz])."""

    planner: str = "nehmo"  # a row: one kind, or one per arm joined by '/'
    model: str = "shipped"
    time_limit: float = 20.0
    physics_rate: float = 100.0
    real_time_factor: float = 1.0
    domain_id: int | None = None
    startup_timeout: float = 60.0  # [s] for the recorder and the planners to come up
    stop_timeout: float = 10.0  # [s] after SIGINT before SIGKILL
    nice: int = 0  # added niceness of the children
    #: Added niceness of the recorder on top of ``nice``: the planners and the bridge come first
    #: when the CPUs are busy; the recorder's deep reader history absorbs its delays.
    recorder_nice: int = 10
    extra_planner_args: tuple[str, ...] = ()
    env: dict[str, str] = field(default_factory=dict)
    #: A colcon install space (``ros_ws/install``): the nodes then run as its executables after
    #: sourcing its ``setup.bash``, as a ROS user runs them; '' runs ``python -m <module>``.
    install_space: str = ""

    def __post_init__(self) -> None:
        if not 0 <= self.recorder_nice <= 19:
            raise InvalidValueError("recorder_nice", "must lie in [0, 19]", self.recorder_nice)
        for name in ("time_limit", "physics_rate", "real_time_factor", "startup_timeout"):
            if not getattr(self, name) > 0:
                raise InvalidValueError(name, "must be > 0", getattr(self, name))
        if self.domain_id is not None and not 0 <= self.domain_id <= 232:
            raise InvalidValueError("domain_id", "must lie in [0, 232]", self.domain_id)
        check_row_and_model(self.planner, self.model)
        if self.install_space and not (Path(self.install_space) / "setup.bash").is_file():
            raise InvalidValueError(
                "install_space",
                "must be a colcon install space (with setup.bash)",
                self.install_space,
            )


def check_row_and_model(planner: str, model: str) -> None:
    """What every ``arm_planner`` would reject, checked before any process starts: each kind
    of the row (one, or one per arm joined by '/') and each source of ``model``."""
    from nehmo_core.eval.planners import SYNTHETIC
    from nehmo_core.hjr.train import SHIPPED_VALUE_FUNCTIONS
    from nehmo_core.planning.factory import DECENTRALIZED
    from nehmo_ros.planners import model_sources

    for kind in planner.split("/"):
        if kind not in DECENTRALIZED:
            raise UnknownNameError("planner", kind, DECENTRALIZED)
    for source in model_sources(model):
        known = source.source in SHIPPED_VALUE_FUNCTIONS or source.source == SYNTHETIC
        if not known and not Path(source.source).exists():
            raise InvalidValueError(
                "model",
                "must be 'shipped', 'synthetic', a shipped pair "
                f"{sorted(SHIPPED_VALUE_FUNCTIONS)} or an existing path, per [KIND=]SOURCE item",
                str(source),
            )


def isolated_domain() -> int:
    """A DDS domain id for this run (100..219, from the process id)."""
    return 100 + os.getpid() % 120


def child_env(settings: SuiteSettings, domain_id: int) -> dict[str, str]:
    env = dict(os.environ)
    env.update(
        {
            "ROS_DOMAIN_ID": str(domain_id),
            "PYTHONUNBUFFERED": "1",
            "OMP_NUM_THREADS": "1",
            "MKL_NUM_THREADS": "1",
        }
    )
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"  # this machine only, unless overridden
    env.pop("ROS_STATIC_PEERS", None)
    # UDP only: with Fast DDS's shared-memory transport a SIGKILLed node stalled the surviving
    # ones (bridge steps up to 5 s apart) until its port was given up.
    env.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")
    env.update(settings.env)
    return env


class Process:
    """A child node process with its output in a file; stopped with SIGINT, then SIGKILL."""

    def __init__(self, name: str, argv: list[str], env: dict[str, str], log: Path, nice: int):
        self.name = name
        self.log = log
        self._out: IO[bytes] = open(log, "wb")  # noqa: SIM115 (closed in stop())
        self.proc = subprocess.Popen(
            argv,
            env=env,
            stdout=self._out,
            stderr=subprocess.STDOUT,
            preexec_fn=(lambda: os.nice(nice)) if nice else None,
        )

    def output(self) -> str:
        return self.log.read_text(errors="replace") if self.log.exists() else ""

    def wait_for(self, marker: str, timeout: float) -> bool:
        """True once ``marker`` appears in the output; False on exit or timeout."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if marker in self.output():
                return True
            if self.proc.poll() is not None:
                return False
            time.sleep(0.1)
        return False

    def stop(self, timeout: float) -> int | None:
        """SIGINT, wait up to ``timeout`` s, then SIGKILL; the exit status (None if killed)."""
        killed = False
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
                killed = True
        self._out.close()
        return None if killed else self.proc.returncode


#: The console script of each node module: (package, executable).
EXECUTABLES: dict[str, tuple[str, str]] = {
    "nehmo_ros.arm_planner": ("nehmo_ros", "arm_planner"),
    "nehmo_ros.recorder": ("nehmo_ros", "recorder"),
    "sim_bridge.bridge": ("sim_bridge", "sim_bridge"),
}


def node_command(
    module: str, params: dict[str, Any], extra: Sequence[str] = (), install_space: str = ""
) -> list[str]:
    """``python -m <module> --ros-args -p k:=v ...``; with ``install_space``, the same node as
    ``<install>/<pkg>/lib/<pkg>/<exe> --ros-args ...`` after sourcing ``<install>/setup.bash``."""
    args = ["--ros-args"]
    for key, value in params.items():
        text = str(value).lower() if isinstance(value, bool) else str(value)
        args += ["-p", f"{key}:={text}"]
    args += list(extra)
    if not install_space:
        return [sys.executable, "-m", module, *args]
    package, executable = EXECUTABLES[module]
    install = Path(install_space).resolve()
    exe = install / package / "lib" / package / executable
    script = f'source "{install}/setup.bash" && exec "{exe}" "$@"'
    return ["bash", "-c", script, executable, *args]


@dataclass(frozen=True)
class EpisodeRun:
    """One orchestrated episode: its log, its evaluation and how the processes ended."""

    index: int
    log: Path
    result: EpisodeResult | None
    exit_codes: dict[str, int | None]
    wall_seconds: float
    error: str = ""
    rmw: str = ""  # the middleware the nodes reported at start


@contextmanager
def _processes() -> Iterator[list[Process]]:
    procs: list[Process] = []
    try:
        yield procs
    finally:
        for p in procs:  # normally already stopped; on errors and Ctrl-C: stop them all
            p.stop(2.0)


def run_episode(
    scenario_file: Path,
    episode: int,
    out_dir: Path,
    settings: SuiteSettings,
) -> EpisodeRun:
    """Run one episode of ``scenario_file`` through the node suite; evaluate its log."""
    scenarios = load_scenario_set(scenario_file)
    cell = load_cell(scenarios.cell)
    kinds = parse_row(settings.planner, cell)
    domain_id = settings.domain_id if settings.domain_id is not None else isolated_domain()
    env = child_env(settings, domain_id)
    stem = f"episode_{episode:03d}"
    log_path = out_dir / stem
    logs = out_dir / "logs" / stem
    logs.mkdir(parents=True, exist_ok=True)
    if log_path.is_dir():
        shutil.rmtree(log_path)
    sim = {"use_sim_time": True}
    start = time.monotonic()
    codes: dict[str, int | None] = {}
    with _processes() as procs:
        commands: dict[str, list[str]] = {}

        def launch(name: str, argv: list[str]) -> Process:
            commands[name] = argv
            (logs / "commands.json").write_text(json.dumps(commands, indent=1) + "\n")
            nice = settings.nice + (settings.recorder_nice if name == "recorder" else 0)
            procs.append(Process(name, argv, env, logs / f"{name}.log", nice))
            return procs[-1]

        recorder = launch(
            "recorder",
            node_command(
                "nehmo_ros.recorder",
                {"cell": cell.name, "output": str(log_path), **sim},
                install_space=settings.install_space,
            ),
        )
        if not recorder.wait_for("recording", settings.startup_timeout):
            raise NehmoError(f"the recorder did not start:\n{recorder.output()[-2000:]}")
        for arm_id, kind in kinds.items():
            params = {"arm_id": arm_id, "cell": cell.name, "planner": kind, "model": settings.model}
            launch(
                f"planner_{arm_id}",
                node_command(
                    "nehmo_ros.arm_planner",
                    {**params, **sim},
                    ["-r", f"__node:=arm_planner_{arm_id}", *settings.extra_planner_args],
                    settings.install_space,
                ),
            )
        bridge = launch(
            "sim_bridge",
            node_command(
                "sim_bridge.bridge",
                {
                    "cell": cell.name,
                    "scenarios": str(scenario_file),
                    "episode": episode,
                    "sim_time": True,
                    "exit_when_done": True,
                    "time_limit": settings.time_limit,
                    "physics_rate": settings.physics_rate,
                    "real_time_factor": settings.real_time_factor,
                    "start_timeout": settings.startup_timeout,
                    "planners": settings.planner,
                    "min_subscribers": len(kinds) + 1,  # every planner and the recorder
                },
                install_space=settings.install_space,
            ),
        )
        budget = settings.startup_timeout + settings.time_limit / settings.real_time_factor + 30
        with suppress(subprocess.TimeoutExpired):
            bridge.proc.wait(budget)
        codes["sim_bridge"] = bridge.stop(settings.stop_timeout)
        for p in procs:
            if p is not bridge:
                codes[p.name] = p.stop(settings.stop_timeout)
        failed = {n: c for n, c in codes.items() if c != 0}
    wall = time.monotonic() - start
    rmw = reported_rmw(bridge.output())
    if failed:
        detail = "; ".join(f"{n}: exit {c}" for n, c in failed.items())
        return EpisodeRun(episode, log_path, None, codes, wall, f"processes failed ({detail})", rmw)
    try:
        result = evaluate_log(log_path)
    except NehmoError as exc:
        return EpisodeRun(episode, log_path, None, codes, wall, str(exc), rmw)
    return EpisodeRun(episode, log_path, result, codes, wall, rmw=rmw)


def reported_rmw(output: str) -> str:
    """The middleware a node named in its start-up line (``... rmw <name>``), or ''."""
    for line in output.splitlines():
        if ", rmw " in line:
            return line.rsplit(", rmw ", 1)[1].split()[0].strip(")")
    return ""


def run_suite(
    scenario_file: Path, episodes: Sequence[int], out_dir: Path, settings: SuiteSettings
) -> dict[str, Any]:
    """Run ``episodes`` of a scenario set; write and return the summary."""
    runs = []
    for episode in episodes:
        run = run_episode(scenario_file, episode, out_dir, settings)
        outcome = run.result.outcome if run.result else f"error: {run.error}"
        print(f"episode {episode}: {outcome} ({run.wall_seconds:.1f} s wall) -> {run.log}")
        runs.append(run)
    results = [r.result for r in runs if r.result is not None]
    summary = {
        "scenarios": str(scenario_file),
        "planner": settings.planner,
        "model": settings.model,
        "rmw": next((r.rmw for r in runs if r.rmw), ""),
        "metrics": aggregate(results).to_dict() if results else None,
        "episodes": [
            {
                "episode": r.index,
                "log": str(r.log),
                "outcome": r.result.outcome if r.result else None,
                "end_time": r.result.end_time if r.result else None,
                "path_length": r.result.path_length if r.result else None,
                "exit_codes": r.exit_codes,
                "wall_seconds": r.wall_seconds,
                "error": r.error,
            }
            for r in runs
        ],
    }
    (out_dir / "summary.json").write_text(json.dumps(json_safe(summary), indent=1) + "\n")
    return summary


def format_metrics(metrics: dict[str, Any] | None) -> str:
    """One line of the paper's metrics."""
    if metrics is None:
        return "no episode could be evaluated"
    pt, mpl = metrics["plan_time_ms"], metrics["mpl"]
    return (
        f"SR {metrics['sr']:.0f} %  CR {metrics.get('cr_inter_arm', metrics['cr']):.0f} %"
        f"  self {metrics.get('self_collision_rate', 0.0):.0f} %"
        f"  stuck {metrics['stuck_rate']:.0f} %"
        f"  plan time {pt['mean']:.2f} ± {pt['std']:.2f} ms  MPL {mpl['mean']:.2f} rad"
        f"  ({metrics['episodes']} episodes)"
    )


# ----------------------------------------------------------------------------------- replay
def replay(
    path: Path,
    rate: float,
    topics: Sequence[str] | None,
    domain_id: int | None,
    wait_s: float = 1.0,
) -> int:
    """Republish the messages of a bag through rclpy with their recorded timing (× 1/rate).

    Every topic's publisher is created first, then ``wait_s`` seconds pass for discovery before
    the first message. The serialized bytes go out as recorded; goals and the scenario are
    latched as the bridge publishes them. Topics of types this ROS install lacks are skipped
    (and listed).
    """
    import rclpy
    from rclpy.node import Node

    from nehmo_core.logs import iter_log, summarize
    from nehmo_ros.recorder import LATCHED, is_latched, message_class

    if not rate > 0:
        raise InvalidValueError("rate", "must be > 0", rate)
    if not wait_s >= 0:
        raise InvalidValueError("wait", "must be >= 0 [s]", wait_s)
    if domain_id is not None:
        os.environ["ROS_DOMAIN_ID"] = str(domain_id)
    in_bag = summarize(path).topics
    wanted = list(in_bag) if not topics else list(topics)
    unknown = sorted(set(wanted) - set(in_bag))
    if unknown:
        raise InvalidValueError("topics", f"must be topics of {path} {sorted(in_bag)}", unknown)
    rclpy.init(args=["orchestrate_replay"])
    node = Node("nehmo_replay")
    pubs: dict[str, Any] = {}
    skipped = []
    for topic in wanted:
        try:
            msg_class = message_class(in_bag[topic][0])
        except (ImportError, AttributeError, ValueError):
            skipped.append(topic)
            continue
        qos = LATCHED if is_latched(topic) else 100
        pubs[topic] = node.create_publisher(msg_class, topic, qos)
    if skipped:
        print(f"skipping topics of unknown types: {skipped}", file=sys.stderr)
    time.sleep(wait_s)
    count, t0_log, t0_wall = 0, None, time.monotonic()
    try:
        for rec in iter_log(path, list(pubs)):
            if not rclpy.ok():
                break
            t0_log = rec.log_time_ns if t0_log is None else t0_log
            due = t0_wall + (rec.log_time_ns - t0_log) / 1e9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            pubs[rec.topic].publish(rec.data)
            count += 1
        time.sleep(min(wait_s, 0.5))  # reliable subscribers fetch the last messages
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    print(f"replayed {count} messages on {len(pubs)} topics from {path}")
    return 0


# -------------------------------------------------------------------------------------- CLI
def _episodes(text: str | None, count: int) -> list[int]:
    if not text:
        return list(range(count))
    out = [int(x) for x in text.split(",") if x.strip()]
    bad = [x for x in out if not 0 <= x < count]
    if bad:
        raise InvalidValueError("--episodes", f"must lie in [0, {count - 1}]", bad)
    return out


def scenario_file_for(args: argparse.Namespace, out_dir: Path) -> Path:
    """The scenario set to run: given, or drawn from ``--seed``/``--count`` and saved."""
    if args.scenarios:
        return Path(args.scenarios).resolve()
    cell = load_cell(args.cell)
    scenarios: ScenarioSet = generate_scenario_set(cell, args.seed, args.count)
    return save_scenario_set(scenarios, out_dir / "scenarios.json").resolve()


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="orchestrate", description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run episodes through the node suite and evaluate them")
    run.add_argument("--cell", default="dual_ur5", help="shipped cell name or YAML path")
    run.add_argument("--scenarios", help="scenario set JSON (default: draw --count from --seed)")
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
        "--wait", type=float, default=1.0, help="[s] for discovery before the first message"
    )
    return parser


def _run(args: argparse.Namespace) -> int:
    out_dir = Path(args.out).resolve()
    out_dir.mkdir(parents=True, exist_ok=True)
    scenario_file = scenario_file_for(args, out_dir)
    count = len(load_scenario_set(scenario_file))
    settings = SuiteSettings(
        planner=args.planner,
        model=args.model,
        time_limit=args.time_limit,
        physics_rate=args.physics_rate,
        real_time_factor=args.real_time_factor,
        domain_id=args.domain_id,
        install_space=args.install_space,
    )
    summary = run_suite(scenario_file, _episodes(args.episodes, count), out_dir, settings)
    print(format_metrics(summary["metrics"]))
    print(f"summary: {out_dir / 'summary.json'}")
    if args.render and summary["episodes"] and summary["episodes"][0]["outcome"]:
        from nehmo_core.eval.render import render_episode

        for path in render_episode(summary["episodes"][0]["log"], out_dir / "renders"):
            print(f"render: {path}")
    return 0 if summary["metrics"] is not None else 1


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
            results = []
            for path in args.logs:
                with _readable(path):
                    results.append(evaluate_log(path))
            for path, r in zip(args.logs, results, strict=True):
                print(f"{path}: {r.outcome} at {r.end_time:.2f} s, path {r.path_length:.2f} rad")
            print(format_metrics(aggregate(results).to_dict()))
            return 0
        with _readable(args.log):
            return replay(Path(args.log), args.rate, args.topics, args.domain_id, args.wait)
    except (NehmoError, OSError) as exc:
        print(f"orchestrate: error: {one_line(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("orchestrate: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
