"""What the NeHMO nodes share: parameter reading, one-line start-up errors, a clean stop.

Every node's ``main()`` goes through :func:`run_main`: bad parameters, a malformed
``--ros-args`` section, a bad ``ROS_DOMAIN_ID`` (or a bad cell file, model, scenario ...) print
``<node>: error: <one line naming the parameter, rule and value>`` and exit with status 2;
SIGINT/SIGTERM stop the spin loop and call the node's ``on_stop`` while the middleware is still
up (so a last command or the log's summary still goes out), then the node is destroyed and the
context shut down.
"""

from __future__ import annotations

import gc
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from typing import Any, Protocol

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.robots import load_cell
from nehmo_core.robots.model import Cell
from nehmo_ros import ros
from nehmo_ros.oneline import one_line

__all__ = [
    "NODE_ERRORS",
    "StoppableNode",
    "declare_parameters",
    "load_cell_parameter",
    "one_line",
    "run_main",
]

#: Errors that mean "bad input at start-up": printed as one line, exit status 2.
NODE_ERRORS: tuple[type[BaseException], ...] = (*ros.PARAMETER_ERRORS, NehmoError, OSError)


class StoppableNode(Protocol):
    """A node object with the hooks :func:`run_main` uses (an optional ``finished`` property
    ends the spin loop as a signal does)."""

    node: Any

    def on_stop(self) -> None: ...


def declare_parameters(node: Any, defaults: Mapping[str, Any]) -> dict[str, Any]:
    """Declare every parameter with its default and return the values in force."""
    return {name: node.declare_parameter(name, value).value for name, value in defaults.items()}


def require_text(name: str, value: str, hint: str) -> str:
    """``value`` if it is a non-empty string, else an error naming ``name`` and ``hint``."""
    if not isinstance(value, str) or not value.strip():
        raise InvalidValueError(name, f"is required ({hint})", value)
    return value.strip()


def load_cell_parameter(value: str) -> Cell:
    """The cell of parameter ``cell``: a shipped name (dual_ur5, ...) or a YAML path."""
    return load_cell(require_text("cell", value, "a shipped cell name or a cell YAML path"))


def settle_heap() -> None:
    """Collect once, then move every object alive now out of the collector's reach.

    A node holds a few hundred thousand long-lived objects (torch, CasADi, PyBullet bindings,
    the models); a full collection walks all of them, ~50 ms here, stalling every thread of
    the node at an arbitrary tick. After ``gc.freeze()`` collections only walk what was
    allocated since (messages, telemetry), a fraction of a millisecond.
    """
    gc.collect()
    gc.freeze()


def run_main(
    program: str,
    build: Callable[[], StoppableNode],
    argv: Sequence[str] | None,
    executor: Any | None = None,
    drain_s: float = 0.0,
    usage: str | None = None,
) -> int:
    """Init the middleware, build the node, spin until SIGINT/SIGTERM, stop cleanly.

    After the stop request the node spins ``drain_s`` more seconds (taking what is queued),
    then ``on_stop`` runs while the middleware is still up. ``-h``/``--help`` among the
    arguments before ``--ros-args`` prints ``usage`` (the node module's docstring) instead.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    own = args[: args.index("--ros-args")] if "--ros-args" in args else args
    if usage is not None and ("-h" in own or "--help" in own):
        print(usage.strip(), flush=True)
        return 0
    try:
        try:
            ros.init(args=None if argv is None else [program, *argv])  # --ros-args, domain id
            wrapper = build()
        except NODE_ERRORS as err:
            print(f"{program}: error: {one_line(err)}", file=sys.stderr, flush=True)
            return 2
        stop = threading.Event()

        def on_signal(signum: int, frame: object) -> None:
            del signum, frame
            stop.set()

        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                signal.signal(signum, on_signal)
        spinner = executor or ros.SingleThreadedExecutor()
        spinner.add_node(wrapper.node)
        settle_heap()
        try:
            while not stop.is_set() and ros.ok() and not getattr(wrapper, "finished", False):
                spinner.spin_once(timeout_sec=0.05)
            end = time.monotonic() + drain_s
            while ros.ok() and time.monotonic() < end:
                spinner.spin_once(timeout_sec=0.02)
        except (KeyboardInterrupt, ros.ExternalShutdownException):
            pass
        finally:
            wrapper.on_stop()
            spinner.remove_node(wrapper.node)
            wrapper.node.destroy_node()
        return 0
    finally:
        ros.try_shutdown()
