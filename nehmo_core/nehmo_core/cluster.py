"""Where batch work runs: in this process, a local process pool, or a Ray cluster.

``--cluster`` takes ``local`` (the default: ``--workers`` processes on this machine), ``ray``
(the Ray cluster named by ``RAY_ADDRESS``, else the one started on this machine with
``ray start``, else a fresh Ray instance on this machine) or ``ray://HOST:PORT`` (a Ray Client
address). Ray is an optional extra (``pip install 'nehmo-core[ray]'``), imported only here and
only when asked for.

On Ray every unit of work (an episode) is a Ray task of one CPU. Ray does the scheduling, the
transport and the retries: a task whose worker process or node dies is run again, up to
:data:`MAX_RETRIES` times, and the driver keeps the one result it gets per task. A task that
raises is not retried (the runners turn exceptions into ``error`` results themselves). Episode
logs are written on the worker to a folder of its own and sent back with the result
(:func:`pack_folder`), so the workers need no shared filesystem for the output; they do need
the same ``nehmo-core`` installed, and any ``--value-model`` path, ``NEHMO_MODELS`` or
``NEHMO_ROBOTS`` folder at the same path (those two variables are passed to the workers).
"""

from __future__ import annotations

import contextlib
import os
import shutil
from collections.abc import Callable
from concurrent.futures import Executor, Future, ProcessPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nehmo_core.errors import InvalidValueError, NehmoError

__all__ = [
    "CLUSTER_HELP",
    "MAX_RETRIES",
    "ClusterSpec",
    "RayExecutor",
    "make_executor",
    "pack_folder",
    "parse_cluster",
    "unpack_folder",
]

MAX_RETRIES = 3
"""How often Ray runs a task again after its worker process or node died."""
FORWARDED_ENV = ("NEHMO_MODELS", "NEHMO_ROBOTS")
"""Variables the driver passes to every Ray worker (user model and robot folders)."""
CLUSTER_HELP = (
    "where episodes run: 'local' (--workers processes here), 'ray' (the Ray cluster of "
    "RAY_ADDRESS or of this machine, else a new local one) or 'ray://HOST:PORT' (Ray Client); "
    "Ray needs pip install 'nehmo-core[ray]'"
)


@dataclass(frozen=True)
class ClusterSpec:
    """A parsed ``--cluster``: ``kind`` is ``local`` or ``ray``; ``address`` is Ray's (None:
    ``RAY_ADDRESS``, a cluster started on this machine, or a new one)."""

    kind: str
    address: str | None = None

    @property
    def is_ray(self) -> bool:
        return self.kind == "ray"

    def describe(self) -> str:
        if not self.is_ray:
            return "local"
        return f"ray ({self.address or os.environ.get('RAY_ADDRESS') or 'this machine'})"


def parse_cluster(spec: str | None) -> ClusterSpec:
    """``local``, ``ray`` or ``ray://HOST:PORT`` (also ``ray:HOST:PORT``, a cluster's GCS
    address as ``ray start`` prints it); anything else is one clear error."""
    text = (spec or "local").strip()
    if text == "local":
        return ClusterSpec("local")
    if text == "ray":
        return ClusterSpec("ray")
    if text.startswith("ray://"):
        if len(text) > len("ray://"):
            return ClusterSpec("ray", text)
    elif text.startswith("ray:") and len(text) > len("ray:"):
        return ClusterSpec("ray", text[len("ray:") :])
    raise InvalidValueError(
        "--cluster", "must be 'local', 'ray', 'ray://HOST:PORT' or 'ray:HOST:PORT'", spec
    )


def _import_ray() -> Any:
    try:
        import ray
    except ImportError as exc:
        raise NehmoError(
            f"--cluster ray needs Ray, which is not installed ({exc}): "
            "pip install 'nehmo-core[ray]'"
        ) from None
    return ray


class RayExecutor(Executor):
    """A :class:`concurrent.futures.Executor` whose calls are Ray tasks (one CPU each, retried
    when their worker dies). Connects on creation; :meth:`shutdown` disconnects when it
    connected."""

    def __init__(self, address: str | None = None, initializer: Callable[[], None] | None = None):
        self._ray = _import_ray()
        self._initializer = initializer
        self._owns = not self._ray.is_initialized()
        self._refs: list[Any] = []
        self._remotes: dict[Callable[..., Any], Any] = {}
        if self._owns:
            env = {k: os.environ[k] for k in FORWARDED_ENV if os.environ.get(k)}
            try:
                self._ray.init(
                    address=address,
                    runtime_env={"env_vars": env} if env else None,
                    log_to_driver=False,
                    logging_level="WARNING",
                    include_dashboard=False if address is None else None,
                )
            except (ConnectionError, RuntimeError, ValueError) as exc:
                raise NehmoError(
                    f"--cluster ray: cannot connect to Ray at {address or 'RAY_ADDRESS/local'}: "
                    f"{exc}"
                ) from None

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Future[Any]:
        remote = self._remotes.get(fn)
        if remote is None:
            remote = self._ray.remote(_call).options(
                num_cpus=1, max_retries=MAX_RETRIES, retry_exceptions=False, name=fn.__name__
            )
            self._remotes[fn] = remote
        ref = remote.remote(self._initializer, fn, args, kwargs)
        self._refs.append(ref)
        future: Future[Any] = ref.future()
        return future

    def shutdown(self, wait: bool = True, *, cancel_futures: bool = False) -> None:
        if cancel_futures:
            for ref in self._refs:
                with contextlib.suppress(Exception):  # finished or gone already
                    self._ray.cancel(ref, force=True)
        self._refs.clear()
        if self._owns and self._ray.is_initialized():
            self._ray.shutdown()

    def nodes(self) -> int:
        """Live nodes of the cluster."""
        return sum(1 for n in self._ray.nodes() if n.get("Alive"))


def _call(
    initializer: Callable[[], None] | None,
    fn: Callable[..., Any],
    args: tuple[Any, ...],
    kwargs: dict[str, Any],
) -> Any:
    """A Ray task's body: the worker's initializer, then the call."""
    if initializer is not None:
        initializer()
    return fn(*args, **kwargs)


def make_executor(
    workers: int, cluster: ClusterSpec, initializer: Callable[[], None] | None = None
) -> Executor | None:
    """Ray's executor for a Ray cluster; else a spawn process pool of ``workers`` (None: one
    worker, run in this process)."""
    if cluster.is_ray:
        return RayExecutor(cluster.address, initializer)
    if workers <= 1:
        return None
    import multiprocessing

    return ProcessPoolExecutor(workers, multiprocessing.get_context("spawn"), initializer)


def pack_folder(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` by its relative path (empty when there is none)."""
    if not folder.is_dir():
        return {}
    return {
        str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()
    }


def unpack_folder(files: dict[str, bytes], folder: Path) -> None:
    """Write ``files`` (from :func:`pack_folder`) as ``folder``, replacing what was there."""
    if folder.exists():
        shutil.rmtree(folder)
    for name, data in files.items():
        path = folder / name
        if folder.resolve() not in path.resolve().parents:
            raise NehmoError(f"refusing to write {name!r} outside {folder}")
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
