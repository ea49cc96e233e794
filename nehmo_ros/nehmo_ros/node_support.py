"""What the NeHMO nodes share: declared parameters, one-line start-up errors, a clean stop.

Every node's ``main()`` goes through :func:`run_main`: bad parameters, a malformed
``--ros-args`` section, a bad ``ROS_DOMAIN_ID`` (or a bad cell file, model, scenario ...) print
``<node>: error: <one line naming the parameter, rule and value>`` and exit with status 2.
The node spins in a :class:`rclpy.executors.SingleThreadedExecutor`. SIGINT/SIGTERM stop the spin
loop and call the node's ``on_stop`` while the middleware is still up (so a last command or the
log's summary still goes out), then the node is destroyed and the context shut down.
"""

from __future__ import annotations

import contextlib
import gc
import os
import signal
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import rclpy
import rclpy.exceptions
from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.signals import SignalHandlerOptions

from nehmo_core.errors import InvalidValueError, NehmoError
from nehmo_core.robots import load_cell
from nehmo_core.robots.model import Cell
from nehmo_ros.oneline import one_line

__all__ = [
    "NODE_ERRORS",
    "Param",
    "declare_parameters",
    "load_cell_parameter",
    "one_line",
    "run_main",
]

#: Errors that mean "bad input at start-up": printed as one line, exit status 2.
NODE_ERRORS: tuple[type[BaseException], ...] = (
    rclpy.exceptions.ParameterException,
    rclpy.exceptions.InvalidParameterException,
    rclpy.exceptions.InvalidParameterValueException,
    rclpy.exceptions.InvalidParameterTypeException,
    rclpy.exceptions.ParameterUninitializedException,
    NehmoError,
    OSError,
    ValueError,
)
#: What ``rclpy.init`` raises for a bad ``--ros-args`` section (rcl's RCLError and
#: UnknownROSArgsError derive from RuntimeError).
INIT_ERRORS: tuple[type[BaseException], ...] = (ValueError, RuntimeError)

#: The largest ROS_DOMAIN_ID whose DDS ports exist (ROS 2's documented limit).
MAX_DOMAIN_ID = 232


@dataclass(frozen=True)
class Param:
    """One node parameter: default, description and (for numbers) the inclusive range.

    Parameters are read once at start, so they are declared read-only: a value comes from
    ``--ros-args -p`` or ``--params-file`` and ``ros2 param set`` is refused.
    """

    default: Any
    description: str
    low: float | None = None
    high: float | None = None

    def descriptor(self) -> ParameterDescriptor:
        d = ParameterDescriptor(description=self.description, read_only=True)
        if self.low is None or self.high is None:
            return d
        if isinstance(self.default, bool):
            return d
        if isinstance(self.default, int):
            d.integer_range = [IntegerRange(from_value=int(self.low), to_value=int(self.high))]
        elif isinstance(self.default, float):
            d.floating_point_range = [
                FloatingPointRange(from_value=float(self.low), to_value=float(self.high))
            ]
        return d


def declare_parameters(node: Node, params: Mapping[str, Param]) -> dict[str, Any]:
    """Declare every parameter with its descriptor and return the values in force.

    A value of the wrong type or out of its range stops the node with an error naming the
    parameter, the rule and the value (rclpy's own check, worded as ours).
    """
    values = {}
    for name, p in params.items():
        try:
            values[name] = node.declare_parameter(name, p.default, p.descriptor()).value
        except rclpy.exceptions.InvalidParameterTypeException:
            raise InvalidValueError(
                name, f"must be of type {type(p.default).__name__}", _override(node, name, "?")
            ) from None
        except rclpy.exceptions.InvalidParameterValueException:
            raise InvalidValueError(
                name, f"must lie in [{p.low:g}, {p.high:g}]", _override(node, name, None)
            ) from None
    return values


def _override(node: Node, name: str, fallback: Any) -> Any:
    """The value given for ``name`` on the command line or in a params file."""
    overrides = getattr(node, "_parameter_overrides", {})
    return overrides[name].value if name in overrides else fallback


def refuse_renamed(node: Node, rules: Mapping[str, str]) -> None:
    """An error for a parameter given under a name that was replaced or removed (``hold_bound``
    is now ``hold.bound``): rclpy would ignore it silently, as it ignores any undeclared name.
    ``rules`` maps each such name to what is said about it."""
    given = sorted(set(getattr(node, "_parameter_overrides", {})) & set(rules))
    if given:
        old = given[0]
        raise InvalidValueError(old, rules[old], _override(node, old, None))


def require_text(name: str, value: str, hint: str) -> str:
    """``value`` if it is a non-empty string, else an error naming ``name`` and ``hint``."""
    if not isinstance(value, str) or not value.strip():
        raise InvalidValueError(name, f"is required ({hint})", value)
    return value.strip()


def load_cell_parameter(value: str) -> Cell:
    """The cell of parameter ``cell``: a shipped name (dual_ur5, ...) or a YAML path."""
    return load_cell(require_text("cell", value, "a shipped cell name or a cell YAML path"))


def check_ros_arguments(args: Sequence[str]) -> None:
    """Reject what rcl would reject with a multi-line report, as one line.

    Checks the ``-p``/``--param`` rules of the ``--ros-args`` sections and ``ROS_DOMAIN_ID``;
    rcl checks the rest at ``rclpy.init``.
    """
    domain = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if domain and not (domain.isdigit() and int(domain) <= MAX_DOMAIN_ID):
        raise ValueError(f"ROS_DOMAIN_ID must be an integer in 0..{MAX_DOMAIN_ID}; got {domain!r}")
    ros_section = False
    items = list(args)
    for i, arg in enumerate(items):
        if arg == "--ros-args":
            ros_section = True
        elif arg == "--":
            ros_section = False
        elif ros_section and arg in ("-p", "--param"):
            if i + 1 >= len(items) or items[i + 1].startswith("-"):
                raise ValueError(f"{arg} needs an argument NAME:=VALUE")
            if ":=" not in items[i + 1]:
                raise ValueError(f"{arg} expects NAME:=VALUE; got {items[i + 1]!r}")


def settle_heap() -> None:
    """Collect once, then move every object alive now out of the collector's reach.

    A node holds a few hundred thousand long-lived objects (torch, CasADi, PyBullet bindings,
    the models); a full collection walks all of them, ~50 ms, stalling every thread of the node
    at an arbitrary tick. After ``gc.freeze()`` collections only walk what was allocated since.
    """
    gc.collect()
    gc.freeze()


def run_main(
    program: str,
    build: Callable[[], Node | Sequence[Node]],
    argv: Sequence[str] | None,
    drain_s: float = 0.0,
    usage: str | None = None,
) -> int:
    """Init rclpy, build the node (or nodes), spin until SIGINT/SIGTERM, stop cleanly.

    ``build`` returns an :class:`rclpy.node.Node` subclass with an ``on_stop()`` method, or a
    sequence of them spun by one executor (several nodes in one process). After the stop
    request the nodes spin ``drain_s`` more seconds (taking what is queued), then each node's
    ``on_stop`` runs while the middleware is still up. ``-h``/``--help`` among the arguments
    before ``--ros-args`` prints ``usage`` (the node module's docstring) instead.
    """
    args = [program, *(sys.argv[1:] if argv is None else argv)]
    own = args[: args.index("--ros-args")] if "--ros-args" in args else args
    if usage is not None and ("-h" in own or "--help" in own):
        print(usage.strip(), flush=True)
        return 0
    try:
        try:
            check_ros_arguments(args)
            with _rcl_parse_report_dropped():
                rclpy.init(args=args, signal_handler_options=SignalHandlerOptions.NO)
            executor = make_executor()
        except INIT_ERRORS as err:
            print(f"{program}: error: {_describe(err)}", file=sys.stderr, flush=True)
            return 2
        try:
            built = build()
            nodes = [built] if isinstance(built, Node) else list(built)
        except NODE_ERRORS as err:
            print(f"{program}: error: {_describe(err)}", file=sys.stderr, flush=True)
            return 2
        stop = threading.Event()

        def on_signal(signum: int, frame: object) -> None:
            del signum, frame
            stop.set()

        if threading.current_thread() is threading.main_thread():
            for signum in (signal.SIGINT, signal.SIGTERM):
                signal.signal(signum, on_signal)
        for node in nodes:
            executor.add_node(node)
        settle_heap()
        try:
            while (
                not stop.is_set()
                and rclpy.ok()
                and not all(getattr(n, "finished", False) for n in nodes)
            ):
                executor.spin_once(timeout_sec=0.05)
            end = time.monotonic() + drain_s
            while rclpy.ok() and time.monotonic() < end:
                executor.spin_once(timeout_sec=0.02)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            for node in nodes:
                node.on_stop()  # type: ignore[attr-defined]
                executor.remove_node(node)
            executor.shutdown(timeout_sec=1.0)
            for node in nodes:
                node.destroy_node()
        return 0
    finally:
        rclpy.try_shutdown()


EXECUTOR_ENV = "NEHMO_EXECUTOR"
"""``events`` (default: rclpy's C++ EventsExecutor, ``rclpy.experimental``) or ``single``
(rclpy's SingleThreadedExecutor): how the nodes spin. With five planners, the bridge and the
recorder on two cores the events executor used 1.18 cores against 1.98 and kept the bridge at
real time (``bench/results/ros_load_events.md`` against ``ros_load_after.md``)."""


def make_executor() -> Any:
    """The executor ``NEHMO_EXECUTOR`` names (``events`` when unset)."""
    kind = os.environ.get(EXECUTOR_ENV, "events").strip() or "events"
    if kind == "single":
        return SingleThreadedExecutor()
    if kind == "events":
        from rclpy.experimental import EventsExecutor

        return EventsExecutor()
    raise ValueError(f"{EXECUTOR_ENV} must be 'single' or 'events'; got {kind!r}")


@contextlib.contextmanager
def _rcl_parse_report_dropped() -> Iterator[None]:
    """rcl logs "Failed to parse global arguments" to stderr before raising; the exception
    says more, so that line is dropped (anything else rcl writes passes through)."""
    sys.stderr.flush()
    saved = os.dup(2)
    with tempfile.TemporaryFile() as captured:
        os.dup2(captured.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            captured.seek(0)
            for line in captured.read().decode(errors="replace").splitlines():
                if "Failed to parse global arguments" not in line:
                    print(line, file=sys.stderr)


def _describe(err: BaseException) -> str:
    """One line for a start-up error (rcl's messages carry a source location: cut it)."""
    text = one_line(err)
    if type(err).__name__ == "UnknownROSArgsError":
        return f"unknown ROS argument {text.strip('[]')}"
    if ", at /" in text:
        text = text.split(", at /", 1)[0]
    return text
