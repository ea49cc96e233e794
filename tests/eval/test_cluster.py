"""``nehmo evaluate --cluster ray`` on a Ray cluster of three hosts, against the local runner.

The hosts are network namespaces made by this test (``tests/_netns.py``): a head (GCS, no CPU
for tasks; the driver runs here) and two worker nodes of one CPU each, every node its own
``ray start`` process with its own address; the workers keep Ray's session files in a private
mount namespace, as separate machines would. A 20-episode evaluation runs once with the local
runner (two processes) and once on the cluster, where one worker process is killed while it runs
an episode. The per-episode outcomes must be the same, every episode counted once.

Also here, without a cluster: ``--cluster`` parsing, Ray missing, ``--resume``, and
``nehmo verify``'s rollouts on a Ray instance of this machine against the same in-process.
"""

from __future__ import annotations

import builtins
import json
import os
import secrets
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from _eval_helpers import record_calls
from _netns import Host, hosts, own_namespaces, require_netns

from nehmo_core import cluster as cluster_module
from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.eval import batch as batch_module
from nehmo_core.eval.batch import BatchConfig, run_rows
from nehmo_core.geometry.distance_data import labelled, uniform_samples
from nehmo_core.hjr import load_value_function
from nehmo_core.pairs.build import PairBuild
from nehmo_core.robots import load_cell
from nehmo_core.sim.scenarios import generate_scenario_set
from nehmo_core.verify.certify import RemoteRollouts, VerifySettings, worst_margins
from nehmo_core.verify.truth import exact_margin

SETUP, ROW, EPISODES, SEED = "dual_ur5", "nehmo", 20, 7
PREFIX = f"nehmo-ray-{os.getpid()}-"
SUBNET = "10.232.0"
PORT = 6379
RAY = str(Path(sys.executable).with_name("ray"))
RUN_TIMEOUT = 900.0  # [s] generous: a loaded CI machine
STORE = "--object-store-memory=100000000"  # 100 MB a node: bags are small, /dev/shm is shared


# -- without a cluster ---------------------------------------------------------------------------
@pytest.mark.parametrize(
    ("spec", "kind", "address"),
    [
        (None, "local", None),
        ("local", "local", None),
        ("ray", "ray", None),
        ("ray://head:10001", "ray", "ray://head:10001"),
        ("ray:10.0.0.1:6379", "ray", "10.0.0.1:6379"),
    ],
)
def test_cluster_specs(spec: str | None, kind: str, address: str | None) -> None:
    parsed = cluster_module.parse_cluster(spec)
    assert (parsed.kind, parsed.address) == (kind, address)


@pytest.mark.parametrize("spec", ["dask", "ray://", "ray:", "Ray"])
def test_a_bad_cluster_is_one_clear_error(spec: str) -> None:
    with pytest.raises(InvalidValueError, match="--cluster") as info:
        cluster_module.parse_cluster(spec)
    assert repr(spec) in str(info.value)


def test_without_ray_the_option_says_what_to_install(monkeypatch: pytest.MonkeyPatch) -> None:
    real_import = builtins.__import__

    def no_ray(name: str, *args: Any, **kwargs: Any) -> Any:
        if name == "ray" or name.startswith("ray."):
            raise ImportError("No module named 'ray'")
        return real_import(name, *args, **kwargs)

    monkeypatch.delitem(sys.modules, "ray", raising=False)
    monkeypatch.setattr(builtins, "__import__", no_ray)
    with pytest.raises(NehmoError, match=r"pip install 'nehmo-core\[ray\]'"):
        cluster_module.make_executor(2, cluster_module.parse_cluster("ray"))


def test_resume_keeps_finished_episodes_and_runs_the_rest(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scenarios = generate_scenario_set(load_cell(SETUP), 3, 4)
    config = BatchConfig(setup=SETUP, out_dir=tmp_path)
    (first,) = run_rows(config, ["naive"], scenarios, workers=1, progress=False)
    logs = first.logs
    # as if the run had stopped during episode 2: its record is gone, its bag half written
    logs[2].with_name(logs[2].name + ".done.json").unlink()
    ran = record_calls(monkeypatch, batch_module, "_episode", lambda config, job, _: job.position)
    (again,) = run_rows(config, ["naive"], scenarios, workers=1, progress=False, resume=True)
    assert ran == [2]
    kept = [0, 1, 3]
    assert [again.results[k] for k in kept] == [first.results[k] for k in kept]  # the same bags
    rerun, before = again.results[2], first.results[2]  # its plan times are measured anew
    assert (rerun.outcome, rerun.ticks, rerun.path_lengths, rerun.final_errors) == (
        before.outcome,
        before.ticks,
        before.path_lengths,
        before.final_errors,
    )
    assert again.mismatches == []
    # other settings are other episodes: nothing is reused
    ran.clear()
    other = BatchConfig(setup=SETUP, out_dir=tmp_path, backend="vm")
    run_rows(other, ["naive"], scenarios, workers=1, progress=False, resume=True)
    assert ran == [0, 1, 2, 3]


def test_a_pair_build_names_a_bad_cluster(tmp_path: Path) -> None:
    with pytest.raises(InvalidValueError, match="--cluster"):
        PairBuild("ur5", "ur5", models=tmp_path, work=tmp_path / "w", cluster="dask")


@pytest.fixture
def local_ray() -> Iterator[cluster_module.RayExecutor]:
    """A Ray instance of this machine (two CPUs) for the tests that need no several hosts."""
    import ray

    os.environ.setdefault("RAY_USAGE_STATS_ENABLED", "0")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="WARNING")
    try:
        yield cluster_module.RayExecutor()
    finally:
        ray.shutdown()


def test_verify_rollouts_on_ray_are_the_local_ones(local_ray: cluster_module.RayExecutor) -> None:
    """Chunks of a certificate's rollouts run by Ray workers that load the model themselves:
    the same margins and worst adversaries as in this process, and the generator ends where
    a local run leaves it."""
    value = load_value_function("ur5_ur5")
    settings = VerifySettings(tau=0.3, chunk=8)
    x = np.random.default_rng(5).uniform(value.system.lower, value.system.upper, (24, 12))
    margin = exact_margin(value.system)
    try:
        rng_here, rng_there = np.random.default_rng(9), np.random.default_rng(9)
        here = worst_margins(value, margin, x, settings, rng_here, "local")
        remote = RemoteRollouts(local_ray, "ur5_ur5")
        there = worst_margins(value, margin, x, settings, rng_there, "ray", remote)
    finally:
        margin.close()
    np.testing.assert_allclose(there[0], here[0], atol=1e-6)
    assert there[1] == here[1]
    assert rng_there.random() == rng_here.random()
    assert (here[0] < 0.05).any()  # some rollouts come near contact: the comparison means something


def test_distance_labels_on_ray_are_the_local_ones(local_ray: cluster_module.RayExecutor) -> None:
    """Exact-distance labels in chunks on Ray workers (each keeps its own PyBullet world): the
    same values, in the same order, as in this process; a conditioned pair included."""
    for pair in ("ur5_ur5", "ur5_panda_any"):
        q = uniform_samples(pair, 4100, np.random.default_rng(3))  # three chunks
        here = labelled(pair, q, np.random.default_rng(4), workers=1)
        there = labelled(pair, q, np.random.default_rng(4), executor=local_ray)
        np.testing.assert_array_equal(there, here)
        assert (here < 0).any() and (here > 0).any()


# -- on a cluster --------------------------------------------------------------------------------
@dataclass
class ClusterRun:
    code: int
    output: str
    summary: dict[str, Any]
    killed: list[str]  # what was killed: "pid process-title"
    namespaces_after: list[str]


def _evaluate_argv(out: Path, *extra: str) -> list[str]:
    return [
        sys.executable, "-m", "nehmo_core.cli", "evaluate", "--setup", SETUP, "--planners", ROW,
        "--episodes", str(EPISODES), "--seed", str(SEED), "--out", str(out), "--no-progress",
        # no wall-clock solve deadline: a solve slowed by the loaded machine would turn into a
        # fail-safe step in one run and not the other, and the runs must agree exactly
        "--planner-setting", "opt.deadline=3600",
        *extra,
    ]  # fmt: skip


TOKEN = secrets.token_hex(32)  # the cluster's token: every node and the driver present it


def _env() -> dict[str, str]:
    return {
        **os.environ,
        "RAY_AUTH_MODE": "token",
        "RAY_AUTH_TOKEN": TOKEN,
        "RAY_USAGE_STATS_ENABLED": "0",
        "PYTHONUNBUFFERED": "1",
    }


def _episodes(summary: dict[str, Any]) -> list[tuple[Any, ...]]:
    (row,) = summary["rows"]
    return [(e["scenario"], e["outcome"], e["collision"], e["end_time"]) for e in row["episodes"]]


def _task_processes(title: str) -> list[int]:
    """Processes whose title (Ray sets it to ``ray::<task>``) starts with ``title``."""
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                cmdline = (entry / "cmdline").read_bytes().split(b"\0")[0].decode()
            except OSError:
                continue
            if cmdline.startswith(title):
                found.append(int(entry.name))
    return found


def _wait_for_nodes(head: Host, count: int, timeout: float = 120.0) -> None:
    probe = (
        "import ray, sys; ray.init(address=sys.argv[1], logging_level='ERROR'); "
        "print(sum(1 for n in ray.nodes() if n['Alive']))"
    )
    deadline = time.monotonic() + timeout
    seen = ""
    while time.monotonic() < deadline:
        done = subprocess.run(
            head.command([sys.executable, "-c", probe, f"{head.address}:{PORT}"]),
            capture_output=True,
            text=True,
            env=_env(),
            timeout=120,
            check=False,
        )
        seen = done.stdout.strip() or done.stderr.strip()[-300:]
        if done.returncode == 0 and seen.isdigit() and int(seen) >= count:
            return
        time.sleep(2.0)
    raise AssertionError(f"the Ray cluster did not reach {count} nodes: {seen}")


def _stop(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in reversed(procs):
        if p.poll() is None:
            os.killpg(p.pid, signal.SIGTERM)
    for p in reversed(procs):
        try:
            p.wait(timeout=30)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait(timeout=30)


@pytest.fixture(scope="module")
def local_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    require_netns("Ray cluster test")
    out = tmp_path_factory.mktemp("local")
    done = subprocess.run(
        _evaluate_argv(out, "--workers", "2"),
        capture_output=True,
        text=True,
        env=_env(),
        timeout=RUN_TIMEOUT,
        check=False,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    summary: dict[str, Any] = json.loads((out / "summary.json").read_text())
    return summary


@pytest.fixture(scope="module")
def cluster_run(tmp_path_factory: pytest.TempPathFactory, local_run: dict) -> Iterator[ClusterRun]:
    out = tmp_path_factory.mktemp("cluster")
    # Ray's socket paths must stay short: its session files go to a short folder of /tmp
    temp = Path(tempfile.mkdtemp(prefix="nray", dir="/tmp"))
    procs: list[subprocess.Popen[bytes]] = []
    killed: list[str] = []
    try:
        with hosts(PREFIX, SUBNET, ["head", "w1", "w2"]) as net:
            head = net["head"]
            gcs = f"{head.address}:{PORT}"

            def start(argv: list[str], log: str) -> None:
                with open(out / log, "wb") as sink:
                    procs.append(
                        subprocess.Popen(
                            argv, stdout=sink, stderr=subprocess.STDOUT, env=_env(),
                            start_new_session=True,
                        )
                    )  # fmt: skip

            start(
                head.command([
                    RAY, "start", "--head", "--block", f"--node-ip-address={head.address}",
                    f"--port={PORT}", "--num-cpus=0", f"--temp-dir={temp}", STORE,
                    "--include-dashboard=false", "--disable-usage-stats",
                ]),
                "head.log",
            )  # fmt: skip
            for name in ("w1", "w2"):
                node = net[name]
                ray_start = (
                    f"mount -t tmpfs tmpfs {temp} && exec {RAY} start --block --address={gcs} "
                    f"--node-ip-address={node.address} --num-cpus=1 {STORE}"
                )
                unshare = ["unshare", "--mount", "--propagation", "private", "sh", "-c"]
                start(node.command([*unshare, ray_start]), f"{name}.log")
            _wait_for_nodes(head, 3)
            with open(out / "driver.log", "wb") as sink:
                driver = subprocess.Popen(
                    head.command(_evaluate_argv(out / "eval", "--cluster", f"ray:{gcs}")),
                    stdout=sink,
                    stderr=subprocess.STDOUT,
                    env=_env(),
                    start_new_session=True,
                )
            procs.append(driver)
            deadline = time.monotonic() + RUN_TIMEOUT
            records = out / "eval" / "logs" / ROW
            while driver.poll() is None and time.monotonic() < deadline:
                finished = len(list(records.glob("*.done.json"))) if records.is_dir() else 0
                if not killed and finished >= 4:
                    running = _task_processes("ray::_run_job_shipped")
                    if running:
                        os.kill(running[0], signal.SIGKILL)
                        killed.append(f"{running[0]} ray::_run_job_shipped")
                time.sleep(0.2)
            if driver.poll() is None:
                pytest.fail(f"the cluster run did not end within {RUN_TIMEOUT} s")
            output = (out / "driver.log").read_text(errors="replace")
            summary_path = out / "eval" / "summary.json"
            summary = json.loads(summary_path.read_text()) if summary_path.exists() else {}
            code = driver.returncode
            _stop(procs)
        yield ClusterRun(code, output, summary, killed, own_namespaces(PREFIX))
    finally:
        _stop(procs)
        subprocess.run(["rm", "-rf", str(temp)], check=False)


def test_the_cluster_run_ends_cleanly(cluster_run: ClusterRun) -> None:
    assert cluster_run.code == 0, cluster_run.output[-3000:]
    assert cluster_run.summary["cluster"].startswith("ray (10.232.0.1")
    assert cluster_run.namespaces_after == []


def test_a_worker_was_killed_during_the_run(cluster_run: ClusterRun) -> None:
    assert len(cluster_run.killed) == 1, "no episode task was running to be killed"
    assert "worker died or was killed while executing a task" in cluster_run.output  # Ray saw it


def test_the_cluster_gives_the_local_runs_episodes_each_once(
    cluster_run: ClusterRun, local_run: dict
) -> None:
    ours = _episodes(cluster_run.summary)
    assert [e[0] for e in ours] == sorted({e[0] for e in ours})  # each scenario once
    assert len(ours) == EPISODES
    assert ours == _episodes(local_run)
    (row,) = cluster_run.summary["rows"]
    assert row["ours"]["episodes"] == EPISODES and row["ours"]["errors"] == 0
