"""Sustained load: five arms, the bridge and the recorder for ten minutes.

    python bench/ros_load.py [--duration 600] [--model shipped] [--allow-unmodelled]
                             [--goal-period 8] [--keep DIR]

Starts the node suite for cell ``five_ur5`` (one ``arm_planner`` per arm, ``sim_bridge`` at 100 Hz,
``recorder``) as separate rclpy processes (ROS 2 Jazzy, Fast DDS, discovery on this machine only),
in a DDS domain of its own, in wall time. The episode is scenario 0 of seed 0; to keep every arm
moving for the whole run this script republishes each arm's goal every ``--goal-period`` seconds,
alternating between the scenario's goal and start (the bridge runs with ``stop_on_collision:=false``
and ``stop_on_success:=false``, so the episode never ends; collisions are counted). After
``--duration`` s the planners and the bridge get SIGINT, then the recorder, and the recorder's bag
is read.

Reported (``bench/results/ros_load.json`` and ``.md``):

- command periods per arm at the planner (its timer's publish instants, ``publish_wall_ns``)
  and at the recorder (receive times), percentiles and the share within 40 ± 5 ms;
- solve times, deadline misses, fail-safes and solver errors per arm (the planners' counters);
- dropped messages: what each node says it published (its stop line) against what the
  recorder logged per topic, gaps in the planners' tick counters carried by the statuses, and
  the joint states each planner received against what the bridge published (best-effort
  sensor QoS: drops there are allowed, and counted);
- memory: the RSS of every process sampled every ``--sample-every`` s; the growth from the
  first sample after the warm-up (10 % of the run) to the last, and the least-squares slope.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import re
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np
from _report import machine_at_end, write_report

from nehmo_core.logs import iter_log, summarize
from nehmo_core.logs.messages import DiagnosticArray, DiagnosticStatus
from nehmo_core.logs.topics import COLLISIONS_TOPIC
from nehmo_core.logs.writer import remove_bag
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenario_files import save_scenario_set
from nehmo_core.sim.scenarios import generate_scenario_set
from nehmo_ros.processes import Process, child_env, isolated_domain, node_command, reported_rmw
from nehmo_ros.suite_settings import SuiteSettings

RESULTS = Path(__file__).resolve().parent / "results"
PERIOD_MS, TOLERANCE_MS = 40.0, 5.0
CELL = "five_ur5"
EXECUTOR_ENV = "NEHMO_EXECUTOR"  # nehmo_ros.node_support's (read by the nodes)


# ------------------------------------------------------------------------------ measurements
def percentiles(values: np.ndarray, unit: float = 1.0) -> dict[str, Any]:
    """Count, p1/p50/p99/p99.9 and max of ``values`` × ``unit``."""
    if len(values) == 0:
        return {"count": 0}
    v = np.asarray(values, dtype=np.float64) * unit
    q = np.percentile(v, [1, 50, 99, 99.9])
    return {
        "count": len(v),
        "p1": round(float(q[0]), 2),
        "p50": round(float(q[1]), 2),
        "p99": round(float(q[2]), 2),
        "p99.9": round(float(q[3]), 2),
        "max": round(float(v.max()), 2),
    }


def period_stats(stamps_ns: list[int], skip_s: float) -> dict[str, Any]:
    """Periods [ms] between consecutive ``stamps_ns`` after ``skip_s`` s: percentiles, share
    within 40 ± 5 ms."""
    t = np.sort(np.asarray(stamps_ns, dtype=np.int64))
    if len(t) < 2:
        return {"count": 0}
    t = t[t >= t[0] + skip_s * 1e9]
    periods = np.diff(t) / 1e6
    out = percentiles(periods)
    if len(periods):
        out["within_40pm5_pct"] = round(
            float(100.0 * np.mean(np.abs(periods - PERIOD_MS) <= TOLERANCE_MS)), 2
        )
    return out


def rss_mb(pid: int) -> float | None:
    """Resident set size [MB] of ``pid`` (None once it has exited)."""
    try:
        text = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return None
    match = re.search(r"^VmRSS:\s+(\d+) kB", text, re.MULTILINE)
    return int(match.group(1)) / 1024.0 if match else None


def cpu_seconds(pid: int) -> float | None:
    """User + system CPU time [s] of ``pid`` so far (None once it has exited)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def cpu_share(samples: list[tuple[float, float]], warmup_s: float) -> float | None:
    """CPU seconds per wall second of one process after ``warmup_s`` (1.0: one whole core)."""
    kept = [(t, c) for t, c in samples if t >= warmup_s]
    if len(kept) < 2 or kept[-1][0] <= kept[0][0]:
        return None
    return round((kept[-1][1] - kept[0][1]) / (kept[-1][0] - kept[0][0]), 3)


def memory_stats(samples: list[tuple[float, float]], warmup_s: float) -> dict[str, Any]:
    """Growth of one process's RSS: first (after ``warmup_s``) vs last, slope [MB/min]."""
    kept = [(t, m) for t, m in samples if t >= warmup_s] or samples
    if not kept:
        return {}
    t = np.array([s[0] for s in kept])
    m = np.array([s[1] for s in kept])
    slope = float(np.polyfit(t / 60.0, m, 1)[0]) if len(kept) >= 3 else float("nan")
    return {
        "samples": len(kept),
        "first_mb": round(float(m[0]), 1),
        "last_mb": round(float(m[-1]), 1),
        "max_mb": round(float(m.max()), 1),
        "growth_mb": round(float(m[-1] - m[0]), 1),
        "slope_mb_per_min": round(slope, 3),
    }


def stop_counts(output: str, prefix: str) -> dict[str, Any]:
    """The JSON of a node's ``<prefix>: ... counts {...}`` stop line ({} when missing)."""
    for line in reversed(output.splitlines()):
        if line.startswith(prefix) and "counts {" in line:
            return dict(json.loads(line[line.index("counts {") + len("counts ") :]))
    return {}


# --------------------------------------------------------------------------------- the run
class GoalCycler:
    """Republishes every arm's goal, alternating between the scenario's goal and start."""

    def __init__(self, domain: int, goals: dict[str, list[dict[str, Any]]]) -> None:
        os.environ["ROS_DOMAIN_ID"] = str(domain)
        os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
        import rclpy
        from rclpy.node import Node
        from rclpy.qos import DurabilityPolicy, QoSProfile
        from sensor_msgs.msg import JointState

        self.rclpy = rclpy
        self.message = JointState
        rclpy.init(args=["ros_load"])
        self.node = Node("ros_load_goals")
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.pubs = {
            a: self.node.create_publisher(JointState, f"/{a}/goal", latched) for a in goals
        }
        self.goals = goals
        self.count = 0

    def publish(self) -> None:
        self.count += 1
        for arm_id, (goal, start) in self.goals.items():
            target = start if self.count % 2 else goal
            msg = self.message(name=target["name"], position=target["position"])
            self.pubs[arm_id].publish(msg)

    def close(self) -> None:
        self.node.destroy_node()
        self.rclpy.try_shutdown()


def stop_all(procs: dict[str, Process], names: list[str], timeout: float) -> dict[str, Any]:
    """One SIGINT to each of ``names`` at once, then wait (SIGKILL after ``timeout``)."""
    for name in names:
        if procs[name].proc.poll() is None:
            procs[name].proc.send_signal(signal.SIGINT)
    end = time.monotonic() + timeout
    for name in names:
        try:
            procs[name].proc.wait(max(end - time.monotonic(), 0.1))
        except subprocess.TimeoutExpired:
            procs[name].proc.kill()
    return {name: procs[name].stop(5.0) for name in names}


def run(args: argparse.Namespace, out: Path) -> dict[str, Any]:
    cell = load_cell(CELL)
    domain = isolated_domain()
    env = child_env(SuiteSettings(model=args.model), domain)
    env[EXECUTOR_ENV] = args.executor
    scenario_set = generate_scenario_set(cell, 0, 1)
    scenario_file = save_scenario_set(scenario_set, out / "scenarios.json")
    scenario = scenario_set.scenarios[0]
    log = out / "ros_load_bag"
    remove_bag(log)
    procs: dict[str, Process] = {}

    def launch(name: str, module: str, params: dict[str, Any]) -> Process:
        argv = node_command(module, params, ["-r", f"__node:={name}"])
        nice = SuiteSettings().recorder_nice if name == "recorder" else 0  # as orchestrate runs it
        procs[name] = Process(name, argv, env, out / f"{name}.log", nice)
        return procs[name]

    memory: dict[str, list[tuple[float, float]]] = {}
    cpu: dict[str, list[tuple[float, float]]] = {}  # (wall s, CPU s) per process
    cycler = None
    started = time.monotonic()
    try:
        recorder = launch(
            "recorder",
            "nehmo_ros.recorder",
            {"cell": cell.name, "output": str(log), "stamp_source": "receive"},
        )
        if not recorder.wait_for("recording", 120):
            raise RuntimeError(recorder.output())
        for arm_id in cell.arm_ids:
            params = {
                "arm_id": arm_id,
                "cell": cell.name,
                "planner": "nehmo",
                "model": args.model,
                "allow_unmodelled": args.allow_unmodelled,
            }
            launch(f"planner_{arm_id}", "nehmo_ros.arm_planner", params)
        for arm_id in cell.arm_ids:
            if not procs[f"planner_{arm_id}"].wait_for("of cell", 300):
                raise RuntimeError(procs[f"planner_{arm_id}"].output())
        bridge = launch(
            "bridge",
            "sim_bridge.bridge",
            {
                "cell": cell.name,
                "scenarios": str(scenario_file),
                "time_limit": args.duration + 600.0,
                "stop_on_collision": False,
                "stop_on_success": False,  # arms at the scenario's goals: the episode runs on
                "physics_rate": args.physics_rate,  # = the joint-state rate
                "planners": "nehmo",
                "min_subscribers": len(cell.arm_ids) + 1,  # every planner and the recorder
            },
        )
        if not bridge.wait_for("episode started", 120):
            raise RuntimeError(bridge.output())
        names = {a.arm_id: list(a.robot.joint_names) for a in cell.arms}
        goals = {
            a: [
                {"name": names[a], "position": [float(x) for x in scenario.goal[a]]},
                {"name": names[a], "position": [float(x) for x in scenario.start[a]]},
            ]
            for a in cell.arm_ids
        }
        cycler = GoalCycler(domain, goals)
        t0 = time.monotonic()
        next_goal, next_sample = t0 + args.goal_period, t0
        while (now := time.monotonic()) < t0 + args.duration:
            if now >= next_sample:
                for name, p in procs.items():
                    mb = rss_mb(p.proc.pid)
                    if mb is not None:
                        memory.setdefault(name, []).append((now - t0, mb))
                    used = cpu_seconds(p.proc.pid)
                    if used is not None:
                        cpu.setdefault(name, []).append((now - t0, used))
                next_sample += args.sample_every
            if now >= next_goal:
                cycler.publish()
                next_goal += args.goal_period
            time.sleep(0.05)
    finally:
        nodes = [name for name in procs if name != "recorder"]
        codes = stop_all(procs, nodes, 30.0)  # planners and bridge together, then the recorder
        codes.update(stop_all(procs, ["recorder"], 60.0))
        if cycler is not None:
            cycler.close()
    outputs = {name: p.output() for name, p in procs.items()}
    result = analyse(log, list(cell.arm_ids), outputs, skip_s=5.0)
    sim_s = re.search(r"sim_bridge: stopped, episode running t=([0-9.]+)", outputs["bridge"])
    result.update(
        {
            "bridge_simulated_s": float(sim_s.group(1)) if sim_s else None,
            "bridge_realtime_factor": round(float(sim_s.group(1)) / args.duration, 3)
            if sim_s
            else None,
            "cell": cell.name,
            "scenario": {"seed": 0, "index": 0},
            "rmw": reported_rmw(outputs["bridge"]),
            "model": args.model,
            "allow_unmodelled": args.allow_unmodelled,
            "duration_s": args.duration,
            "goal_period_s": args.goal_period,
            "wall_s": round(time.monotonic() - started, 1),
            "exit_codes": codes,
            "memory": {
                name: memory_stats(samples, 0.1 * args.duration)
                for name, samples in sorted(memory.items())
            },
            "physics_rate_hz": args.physics_rate,
            "executor": args.executor,
            "cpu_share": {
                name: cpu_share(samples, 0.1 * args.duration) for name, samples in cpu.items()
            },
        }
    )
    return result


def analyse(
    log: Path, arm_ids: list[str], outputs: dict[str, str], skip_s: float
) -> dict[str, Any]:
    """Periods, solve times, counters and message accounting from the log and stop lines."""
    summary = summarize(log)
    logged = {topic: count for topic, (_, count) in summary.topics.items()}
    publish: dict[str, list[int]] = {a: [] for a in arm_ids}
    receive: dict[str, list[int]] = {a: [] for a in arm_ids}
    solve: dict[str, list[float]] = {a: [] for a in arm_ids}
    ticks: dict[str, list[int]] = {a: [] for a in arm_ids}
    last: dict[str, dict[str, str]] = {}
    topics = [f"/{a}/planner/status" for a in arm_ids]
    topics += [f"/{a}/velocity_controller/commands" for a in arm_ids]
    for rec in iter_log(log, topics):
        arm = rec.topic.split("/")[1]
        if rec.topic.endswith("/commands"):
            receive[arm].append(rec.log_time_ns)
        elif isinstance(rec.message, DiagnosticStatus):
            values = {kv.key: kv.value for kv in rec.message.values}
            publish[arm].append(int(values["publish_wall_ns"]))
            solve_time = float(values["solve_time"])
            if math.isfinite(solve_time):  # NaN: a missed deadline, no solve finished in time
                solve[arm].append(solve_time)
            ticks[arm].append(int(values["ticks"]))
            last[arm] = values
    bridge = stop_counts(outputs.get("bridge", ""), "sim_bridge:")
    states_published = bridge.get("published", {}).get("joint_states_per_arm")
    per_arm: dict[str, Any] = {}
    for a in arm_ids:
        planner = stop_counts(outputs.get(f"planner_{a}", ""), "arm_planner:")
        published = planner.get("published", {})
        t = np.asarray(ticks[a])
        gaps = int(np.sum(np.diff(t) - 1)) if len(t) > 1 else 0
        received_states = planner.get("received_joint_states", {})
        values = last.get(a, {})
        per_arm[a] = {
            "periods_at_planner_ms": period_stats(publish[a], skip_s),
            "periods_at_recorder_ms": period_stats(receive[a], skip_s),
            "solve_time_ms": percentiles(np.asarray(solve[a]), 1e3),
            "ticks": int(values.get("ticks", 0)),
            "deadline_misses": int(values.get("deadline_misses", 0)),
            "fail_safes": int(values.get("fail_safes", 0)),
            "solver_errors": int(values.get("solver_errors", 0)),
            "holds": int(values.get("holds", 0)),
            "commands": {
                "published": published.get("commands"),
                "logged": logged.get(f"/{a}/velocity_controller/commands", 0),
            },
            "statuses": {
                "published": published.get("statuses"),
                "logged": logged.get(f"/{a}/planner/status", 0),
                "tick_gaps": gaps,
            },
            "joint_states": {
                "published": states_published,
                "logged": logged.get(f"/{a}/joint_states", 0),
                "received_by_own_planner": received_states.get(a),
                "received_by_planners_min": min(received_states.values(), default=None),
            },
        }
    pairs: Counter[str] = Counter()
    for rec in iter_log(log, [COLLISIONS_TOPIC]):
        if isinstance(rec.message, DiagnosticArray):
            for status in rec.message.status:
                v = {kv.key: kv.value for kv in status.values}
                pairs[f"{v.get('arm_a')}-{v.get('arm_b')}"] += 1
    return {
        "arms": per_arm,
        "collision_messages": logged.get(COLLISIONS_TOPIC, 0),
        "collision_steps_by_pair": dict(pairs),
        "log_messages": summary.message_count,
    }


# ------------------------------------------------------------------------------------ report
def _dropped(counts: dict[str, Any]) -> str:
    published, logged = counts.get("published"), counts.get("logged", 0)
    if published is None:
        return f"? / {logged}"
    return f"{published - logged} of {published}"


def markdown(r: dict[str, Any]) -> str:
    lines = [
        f"# Load: {r['duration_s']:.0f} s, cell {r['cell']} (5 planners, bridge, recorder)",
        "",
        f"{r['machine']}; rclpy on {r.get('rmw') or '?'}; scenario 0 of seed 0; model {r['model']};"
        f" goals alternate every {r['goal_period_s']:g} s;"
        f" exit codes {r['exit_codes']}; {r['log_messages']} messages logged,"
        f" {r['collision_messages']} collision messages (colliding steps by pair, self-collisions"
        f" as a-a: {r['collision_steps_by_pair']}; "
        + (
            "planners could leave peers no given model covers unconstrained"
            if r.get("allow_unmodelled")
            else "every planner constrains every peer in reach"
        )
        + "); the bridge"
        " simulated"
        f" {r['bridge_simulated_s']} s (real-time factor {r['bridge_realtime_factor']}: below 1"
        f" the {r.get('physics_rate_hz', 100):g} Hz physics, which is also the joint-state rate,"
        " did not keep up); executor "
        f"{r.get('executor', 'single')}.",
        "",
        "CPU per process (CPU seconds per wall second after the first 10 % of the run; 1.0 is"
        " one core of two): "
        + ", ".join(f"{k} {v}" for k, v in sorted(r.get("cpu_share", {}).items()))
        + f"; total {sum(v for v in r.get('cpu_share', {}).values() if v):.2f}.",
        "",
        "## Command periods and solves",
        "",
        "| arm | where | periods | within 40±5 ms | p1 / p50 / p99 / p99.9 [ms] | max [ms] |",
        "|---|---|---|---|---|---|",
    ]
    for arm, s in r["arms"].items():
        for where in ("periods_at_planner_ms", "periods_at_recorder_ms"):
            p = s[where]
            lines.append(
                f"| {arm} | {where.split('_')[2]} | {p.get('count', 0)} |"
                f" {p.get('within_40pm5_pct', 0):.2f} % | {p.get('p1')} / {p.get('p50')} /"
                f" {p.get('p99')} / {p.get('p99.9')} | {p.get('max')} |"
            )
    lines += [
        "",
        "| arm | ticks | deadline misses | fail-safes | solver errors | solve p50 / p99 [ms] |",
        "|---|---|---|---|---|---|",
    ]
    for arm, s in r["arms"].items():
        st = s["solve_time_ms"]
        lines.append(
            f"| {arm} | {s['ticks']} | {s['deadline_misses']} | {s['fail_safes']} |"
            f" {s['solver_errors']} | {st.get('p50')} / {st.get('p99')} |"
        )
    lines += [
        "",
        "## Messages (dropped = published − logged by the recorder)",
        "",
        "| arm | commands dropped | statuses dropped | status tick gaps | joint states dropped"
        " | joint states received by the planners (min) |",
        "|---|---|---|---|---|---|",
    ]
    for arm, s in r["arms"].items():
        js = s["joint_states"]
        lines.append(
            f"| {arm} | {_dropped(s['commands'])} | {_dropped(s['statuses'])} |"
            f" {s['statuses']['tick_gaps']} | {_dropped(js)} |"
            f" {js['received_by_planners_min']} of {js['published']} |"
        )
    lines += [
        "",
        "## Memory (RSS after the first 10 % of the run)",
        "",
        "| process | samples | first [MB] | last [MB] | max [MB] | growth [MB] | slope [MB/min] |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, m in r["memory"].items():
        lines.append(
            f"| {name} | {m.get('samples')} | {m.get('first_mb')} | {m.get('last_mb')} |"
            f" {m.get('max_mb')} | {m.get('growth_mb')} | {m.get('slope_mb_per_min')} |"
        )
    return "\n".join(lines) + "\n"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=600.0, help="[s] of load")
    parser.add_argument("--model", default="shipped")
    parser.add_argument(
        "--allow-unmodelled",
        action="store_true",
        help="let planners leave peers no given model covers unconstrained (e.g. with --model "
        "ur5_ur5,ur5_ur5_diag, to compare against the full shipped set)",
    )
    parser.add_argument("--goal-period", type=float, default=8.0, help="[s] between goal flips")
    parser.add_argument("--sample-every", type=float, default=5.0, help="[s] between RSS samples")
    parser.add_argument(
        "--physics-rate", type=float, default=100.0, help="[Hz] the bridge's steps and joint states"
    )
    parser.add_argument(
        "--executor", default="events", choices=("single", "events"), help="how the nodes spin"
    )
    parser.add_argument("--keep", help="directory for the log and the process outputs")
    parser.add_argument("--results", default=str(RESULTS), help="where the report goes")
    parser.add_argument("--name", default="ros_load", help="report name: <results>/<name>.md")
    args = parser.parse_args()
    if not (args.duration > 0 and args.goal_period > 0 and args.sample_every > 0):
        parser.error("--duration, --goal-period and --sample-every must be > 0")
    out = Path(args.keep or tempfile.mkdtemp(prefix="ros_load_"))
    out.mkdir(parents=True, exist_ok=True)
    result = run(args, out)
    result["machine"] = machine_at_end()
    print(write_report(Path(args.results), args.name, result, markdown))
    print(f"log and process outputs: {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
