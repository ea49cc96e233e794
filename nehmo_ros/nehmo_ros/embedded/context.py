"""The process-wide context of the embedded runtime: arguments, DDS participant, shutdown."""

from __future__ import annotations

import contextlib
import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any

from nehmo_ros.embedded.arguments import RosArgs, parse_ros_args
from nehmo_ros.embedded.config import DdsConfig, dds_config

# Cyclone keeps one domain per id and process: its configuration is fixed by the first user.
_DOMAINS: dict[int, tuple[Any, DdsConfig]] = {}
_DOMAINS_LOCK = threading.Lock()


def _domain_participant(config: DdsConfig) -> Any:
    from cyclonedds.domain import Domain, DomainParticipant

    with _DOMAINS_LOCK:
        known = _DOMAINS.get(config.domain_id)
        if known is None:
            _DOMAINS[config.domain_id] = (Domain(config.domain_id, config.xml), config)
        elif known[1].xml != config.xml:
            raise RuntimeError(
                f"DDS domain {config.domain_id} is already configured ({known[1].scope}) in "
                f"this process; cannot reconfigure it as {config.scope}"
            )
    return DomainParticipant(config.domain_id)


class Context:
    """What ``rclpy.init`` sets up: parsed ROS arguments and, lazily, the DDS participant."""

    def __init__(self) -> None:
        self._lock = threading.RLock()
        self._ok = False
        self.args = RosArgs()
        self.argv: list[str] = []
        self._domain_id: int | None = None
        self._participant: Any = None
        self._topics: dict[str, Any] = {}
        self._shutdown_callbacks: list[Callable[[], None]] = []
        self.config: DdsConfig | None = None

    def init(self, args: list[str] | None, domain_id: int | None) -> None:
        """Parse `args` (default: sys.argv) and mark the context usable."""
        with self._lock:
            if self._ok:
                raise RuntimeError("the context is already initialized; call shutdown() first")
            self.argv = list(sys.argv if args is None else args)
            self.args = parse_ros_args(self.argv)
            self._domain_id = domain_id
            self.config = dds_config(domain_id)
            self._topics = {}
            self._ok = True

    def ok(self) -> bool:
        """True between init() and shutdown()."""
        return self._ok

    @property
    def participant(self) -> Any:
        """The DDS participant shared by every node of the process (created on first use)."""
        with self._lock:
            if not self._ok:
                raise RuntimeError("the context is not initialized; call init() first")
            if self._participant is None:
                assert self.config is not None
                self._participant = _domain_participant(self.config)
            return self._participant

    def topic(self, name: str, idl_type: type) -> Any:
        """The DDS topic `name` of `idl_type` (one Topic object per name)."""
        from cyclonedds.topic import Topic

        with self._lock:
            known = self._topics.get(name)
            if known is None:
                known = Topic(self.participant, name, idl_type)
                self._topics[name] = known
            elif known.data_type is not idl_type:
                raise TypeError(
                    f"topic {name!r} is already used with type {known.data_type.__name__}; "
                    f"cannot also use it with {idl_type.__name__}"
                )
            return known

    def on_shutdown(self, callback: Callable[[], None]) -> None:
        """Call `callback` when the context shuts down (executors use it to wake up)."""
        with self._lock:
            self._shutdown_callbacks.append(callback)

    def remove_on_shutdown(self, callback: Callable[[], None]) -> None:
        """Forget a callback given to on_shutdown."""
        with self._lock, contextlib.suppress(ValueError):
            self._shutdown_callbacks.remove(callback)

    def shutdown(self) -> None:
        """Mark the context shut down, wake every executor, drop the DDS entities."""
        with self._lock:
            if not self._ok:
                raise RuntimeError("the context is not initialized or already shut down")
            self._ok = False
            callbacks = list(self._shutdown_callbacks)
            self._shutdown_callbacks.clear()
        for callback in callbacks:
            with contextlib.suppress(Exception):
                callback()
        with self._lock:
            self._topics = {}
            self._participant = None  # cyclonedds deletes the entities with their objects

    def try_shutdown(self) -> None:
        """shutdown() unless already shut down."""
        if self._ok:
            self.shutdown()


default_context = Context()
_installed_handlers: dict[int, Any] = {}


def _on_signal(signum: int, frame: FrameType | None) -> None:
    del frame
    default_context.try_shutdown()
    if signum == signal.SIGINT:
        previous = _installed_handlers.get(signum)
        if previous is signal.default_int_handler:
            raise KeyboardInterrupt


def install_signal_handlers() -> None:
    """SIGINT and SIGTERM shut the default context down (main thread only, as rclpy)."""
    if threading.current_thread() is not threading.main_thread():
        return
    for signum in (signal.SIGINT, signal.SIGTERM):
        if signum not in _installed_handlers:
            _installed_handlers[signum] = signal.getsignal(signum)
            signal.signal(signum, _on_signal)
