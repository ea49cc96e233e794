"""Executors of the embedded runtime and the module-level init/spin/shutdown functions.

An executor waits on a DDS WaitSet holding one read condition per subscription and a guard
condition (woken on shutdown or new entities), with a timeout up to the next wall-clock timer;
waits are capped at 50 ms so Python signal handlers (Ctrl-C, SIGTERM) run promptly. Exceptions
raised by callbacks propagate out of ``spin``/``spin_once``, as in rclpy.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from nehmo_ros.embedded.clock import ClockType
from nehmo_ros.embedded.context import Context, default_context, install_signal_handlers
from nehmo_ros.embedded.exceptions import ExternalShutdownException
from nehmo_ros.embedded.node import CallbackGroup, Node, Subscription, Timer

_MAX_WAIT_S = 0.05


class _Work:
    """One unit of work: a due timer or a batch of messages of one subscription."""

    def __init__(self, entity: Timer | Subscription, group: CallbackGroup, run: Callable[[], None]):
        self.entity = entity
        self.group = group
        self.run = run


class Executor:
    """Base executor: collects ready work for its nodes; subclasses decide how to run it."""

    def __init__(self, *, context: Context | None = None) -> None:
        self._context = context or default_context
        self._nodes: list[Node] = []
        self._lock = threading.RLock()
        self._waitset: Any = None
        self._guard: Any = None
        self._attached: dict[int, Any] = {}
        self._waitset_owner: Any = None
        self._is_shutdown = False
        self._context.on_shutdown(self.wake)

    @property
    def context(self) -> Context:
        """The context this executor belongs to."""
        return self._context

    def add_node(self, node: Node) -> bool:
        """Spin `node` with this executor; False if it was already added."""
        with self._lock:
            if node in self._nodes:
                return False
            self._nodes.append(node)
        node._add_waker(self.wake)
        self.wake()
        return True

    def remove_node(self, node: Node) -> None:
        """Stop spinning `node`."""
        with self._lock:
            if node in self._nodes:
                self._nodes.remove(node)
        node._remove_waker(self.wake)
        self.wake()

    def get_nodes(self) -> list[Node]:
        """The nodes of this executor."""
        with self._lock:
            return list(self._nodes)

    def wake(self) -> None:
        """Interrupt a wait (thread-safe)."""
        guard = self._guard
        if guard is not None:
            with contextlib.suppress(Exception):  # the participant is gone at shutdown
                guard.set(True)

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """Stop spinning; returns True (callbacks in flight are awaited by subclasses)."""
        del timeout_sec
        self._is_shutdown = True
        self._context.remove_on_shutdown(self.wake)
        self.wake()
        return True

    # ------------------------------------------------------------------ waiting
    def _sync_waitset(self, subscriptions: list[Subscription]) -> None:
        from cyclonedds.core import GuardCondition, WaitSet

        participant = self._context.participant
        if self._waitset is None or self._waitset_owner is not participant:
            self._attached = {}
            self._waitset_owner = participant
            self._waitset = WaitSet(participant)
            self._guard = GuardCondition(participant)
            self._waitset.attach(self._guard)
        elif len(subscriptions) == len(self._attached) and all(
            id(s.condition) in self._attached and s._reader is not None for s in subscriptions
        ):
            return  # attached as wanted already
        wanted = {id(s.condition): s.condition for s in subscriptions if s._reader is not None}
        for key in [k for k in self._attached if k not in wanted]:
            self._waitset.detach(self._attached.pop(key))
        for key, condition in wanted.items():
            if key not in self._attached:
                self._waitset.attach(condition)
                self._attached[key] = condition

    def _entities(self) -> tuple[list[Subscription], list[Timer]]:
        subscriptions: list[Subscription] = []
        timers: list[Timer] = []
        for node in self.get_nodes():
            with node._lock:
                subscriptions += node.subscriptions
                timers += node.timers
        return subscriptions, timers

    def _collect(
        self, timeout_sec: float | None, can_start: Callable[[Any, CallbackGroup], bool]
    ) -> tuple[list[_Work], bool]:
        """Ready work (waiting up to `timeout_sec`; None = until some), and whether work was
        held back because its callback group was busy."""
        deadline = None if timeout_sec is None else time.monotonic() + max(timeout_sec, 0.0)
        while True:
            if not self._context.ok() or self._is_shutdown:
                return [], False
            subscriptions, timers = self._entities()
            work: list[_Work] = []
            blocked = False
            next_wall: float | None = None
            for timer in timers:
                remaining = timer.time_until_next_call()
                if remaining is None:
                    continue
                if remaining <= 0:
                    if can_start(timer, timer.callback_group):
                        work.append(_Work(timer, timer.callback_group, self._timer_run(timer)))
                    else:
                        blocked = True
                elif timer.clock.clock_type != ClockType.ROS_TIME or not (
                    timer.clock.ros_time_is_active
                ):
                    wait_s = remaining / 1e9
                    next_wall = wait_s if next_wall is None else min(next_wall, wait_s)
            for sub in subscriptions:
                if not can_start(sub, sub.callback_group):
                    blocked = True
                    continue
                try:
                    messages = sub.take()
                except Exception:
                    if self._context.ok() and not self._is_shutdown:
                        raise
                    return [], False  # shut down meanwhile: the DDS entities are gone
                if messages:
                    work.append(_Work(sub, sub.callback_group, self._sub_run(sub, messages)))
            if work:
                return work, blocked
            now = time.monotonic()
            if deadline is not None and now >= deadline:
                return [], blocked
            wait_s = _MAX_WAIT_S
            if next_wall is not None:
                wait_s = min(wait_s, next_wall)
            if deadline is not None:
                wait_s = min(wait_s, deadline - now)
            if blocked:
                return [], True
            try:
                self._sync_waitset(subscriptions)
                self._waitset.wait(max(int(wait_s * 1e9), 0))
                self._guard.set(False)
            except Exception:
                if self._context.ok() and not self._is_shutdown:
                    raise
                return [], False  # shut down meanwhile: the DDS entities are gone

    @staticmethod
    def _timer_run(timer: Timer) -> Callable[[], None]:
        def run() -> None:
            timer._advance()
            timer.callback()

        return run

    @staticmethod
    def _sub_run(sub: Subscription, messages: list[Any]) -> Callable[[], None]:
        def run() -> None:
            for message in messages:
                sub.callback(message)

        return run

    # ------------------------------------------------------------------ spinning
    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Run the work that is ready, waiting up to `timeout_sec` for some."""
        raise NotImplementedError

    def spin(self) -> None:
        """Run callbacks until the context or this executor is shut down."""
        while self._context.ok() and not self._is_shutdown:
            self.spin_once(_MAX_WAIT_S * 4)
        if not self._context.ok():
            raise ExternalShutdownException()

    def spin_until_future_complete(
        self, future: Future[Any], timeout_sec: float | None = None
    ) -> None:
        """Spin until `future` is done or `timeout_sec` passed."""
        end = None if timeout_sec is None else time.monotonic() + timeout_sec
        while self._context.ok() and not future.done():
            left = None if end is None else end - time.monotonic()
            if left is not None and left <= 0:
                return
            self.spin_once(_MAX_WAIT_S if left is None else min(left, _MAX_WAIT_S))


class SingleThreadedExecutor(Executor):
    """Runs every callback in the thread that spins."""

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Run the ready work in this thread."""
        if not self._context.ok():
            raise ExternalShutdownException()
        work, _ = self._collect(timeout_sec, lambda entity, group: True)
        for item in work:
            item.run()


class MultiThreadedExecutor(Executor):
    """Runs callbacks on a thread pool; callback groups decide what may overlap."""

    def __init__(self, num_threads: int | None = None, *, context: Context | None = None) -> None:
        super().__init__(context=context)
        self._pool = ThreadPoolExecutor(max_workers=num_threads or 2, thread_name_prefix="exec")
        self._done = threading.Condition()
        self._futures: list[Future[None]] = []

    def spin_once(self, timeout_sec: float | None = None) -> None:
        """Start the ready work on the pool (re-raising errors of finished callbacks)."""
        if not self._context.ok():
            raise ExternalShutdownException()
        self._reap()
        work, blocked = self._collect(timeout_sec, lambda entity, group: group.can_execute(entity))
        for item in work:
            if not item.group.beginning_execution(item.entity):
                continue  # lost a race with another item of the same group: data stays taken
            self._futures.append(self._pool.submit(self._run, item))
        if not work and blocked:
            with self._done:
                self._done.wait(timeout=0.005 if timeout_sec is None else min(timeout_sec, 0.005))

    def _run(self, item: _Work) -> None:
        try:
            item.run()
        finally:
            item.group.ending_execution(item.entity)
            with self._done:
                self._done.notify_all()
            self.wake()

    def _reap(self) -> None:
        done = [f for f in self._futures if f.done()]
        self._futures = [f for f in self._futures if not f.done()]
        for future in done:
            future.result()  # re-raise a callback's exception in the spinning thread

    def shutdown(self, timeout_sec: float | None = None) -> bool:
        """Stop spinning and wait for the callbacks in flight."""
        super().shutdown(timeout_sec)
        self._pool.shutdown(wait=True)
        return True


# ------------------------------------------------------------------------- module functions
_global_executor: SingleThreadedExecutor | None = None


def init(
    *, args: list[str] | None = None, context: Context | None = None, domain_id: int | None = None
) -> None:
    """Parse the ROS arguments (default: sys.argv) and install SIGINT/SIGTERM handlers."""
    (context or default_context).init(args, domain_id)
    if context is None or context is default_context:
        install_signal_handlers()


def ok(*, context: Context | None = None) -> bool:
    """True between init() and shutdown()."""
    return (context or default_context).ok()


def shutdown(*, context: Context | None = None) -> None:
    """Shut the context down (raises if it is not initialized)."""
    global _global_executor
    (context or default_context).shutdown()
    if context is None or context is default_context:
        _global_executor = None


def try_shutdown(*, context: Context | None = None) -> None:
    """shutdown() unless already shut down."""
    if (context or default_context).ok():
        shutdown(context=context)


def get_global_executor() -> SingleThreadedExecutor:
    """The executor used by spin()/spin_once() without an explicit one."""
    global _global_executor
    if _global_executor is None or _global_executor._is_shutdown:
        _global_executor = SingleThreadedExecutor()
    return _global_executor


def spin(node: Node, executor: Executor | None = None) -> None:
    """Spin `node` until shutdown (raises ExternalShutdownException on Ctrl-C/SIGTERM)."""
    executor = executor or get_global_executor()
    executor.add_node(node)
    try:
        executor.spin()
    finally:
        executor.remove_node(node)


def spin_once(
    node: Node, *, executor: Executor | None = None, timeout_sec: float | None = None
) -> None:
    """Run the work of `node` that is ready, waiting up to `timeout_sec`."""
    executor = executor or get_global_executor()
    executor.add_node(node)
    try:
        executor.spin_once(timeout_sec)
    finally:
        executor.remove_node(node)
