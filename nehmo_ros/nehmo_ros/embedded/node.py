"""``Node`` of the embedded runtime: parameters, publishers, subscriptions, timers, clock, logs.

The API is the subset of ``rclpy.node.Node`` the NeHMO nodes use, with rclpy's names and
semantics, so node code runs unchanged on either runtime.
"""

from __future__ import annotations

import re
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from nehmo_core.logs.cdr import CDR_LE_HEADER
from nehmo_core.logs.messages import Clock as ClockMsg
from nehmo_core.logs.messages import msgtype_of
from nehmo_ros.embedded.arguments import LOG_LEVELS, parse_ros_args, resolve_overrides
from nehmo_ros.embedded.clock import Clock, ClockType, ROSClock
from nehmo_ros.embedded.context import Context, default_context
from nehmo_ros.embedded.exceptions import (
    InvalidParameterValueException,
    ParameterAlreadyDeclaredException,
    ParameterNotDeclaredException,
    ParameterUninitializedException,
)
from nehmo_ros.embedded.fastcdr import decode
from nehmo_ros.embedded.parameters import (
    Parameter,
    ParameterDescriptor,
    type_matches,
    type_rule,
)
from nehmo_ros.embedded.qos import QoSProfile, as_profile, qos_profile_clock, to_cyclone

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_TOPIC_TOKEN = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


# ------------------------------------------------------------------------------------ logging
class RcutilsLogger:
    """Prints ``[LEVEL] [unix time] [name]: message`` to stderr, as rclpy's console output."""

    _lock = threading.Lock()

    def __init__(self, name: str, level: str = "info") -> None:
        self.name = name
        self._level = LOG_LEVELS.index(level)
        self._once: set[tuple[str, str]] = set()
        self._last: dict[tuple[str, str], float] = {}

    def set_level(self, level: str) -> None:
        """One of debug, info, warn, error, fatal."""
        self._level = LOG_LEVELS.index(level.lower())

    def get_child(self, name: str) -> RcutilsLogger:
        """A logger named ``<self>.<name>``."""
        return RcutilsLogger(f"{self.name}.{name}", LOG_LEVELS[self._level])

    def _log(
        self,
        level: str,
        message: str,
        once: bool = False,
        throttle_duration_sec: float | None = None,
        skip_first: bool = False,
    ) -> bool:
        if LOG_LEVELS.index(level) < self._level:
            return False
        # As in rclpy, `once` and throttling apply per call site (the caller of info(), ...),
        # so a message whose text changes (counts, values) is still throttled.
        caller = sys._getframe(2)
        site = (level, f"{caller.f_code.co_filename}:{caller.f_lineno}")
        if once:
            if site in self._once:
                return False
            self._once.add(site)
        if throttle_duration_sec is not None or skip_first:
            now = time.monotonic()
            last = self._last.get(site)
            if last is None:
                self._last[site] = now
                if skip_first:
                    return False
            elif throttle_duration_sec is not None and now - last < throttle_duration_sec:
                return False
            else:
                self._last[site] = now
        stamp = time.time_ns()
        line = f"[{level.upper()}] [{stamp // 1_000_000_000}.{stamp % 1_000_000_000:09d}] "
        with self._lock:
            print(f"{line}[{self.name}]: {message}", file=sys.stderr, flush=True)
        return True

    def debug(self, message: str, **kwargs: Any) -> bool:
        """Log at DEBUG."""
        return self._log("debug", message, **kwargs)

    def info(self, message: str, **kwargs: Any) -> bool:
        """Log at INFO."""
        return self._log("info", message, **kwargs)

    def warning(self, message: str, **kwargs: Any) -> bool:
        """Log at WARN."""
        return self._log("warn", message, **kwargs)

    warn = warning

    def error(self, message: str, **kwargs: Any) -> bool:
        """Log at ERROR."""
        return self._log("error", message, **kwargs)

    def fatal(self, message: str, **kwargs: Any) -> bool:
        """Log at FATAL."""
        return self._log("fatal", message, **kwargs)


# ---------------------------------------------------------------------------- callback groups
class CallbackGroup:
    """Decides which callbacks may run at the same time (MultiThreadedExecutor)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._running: set[int] = set()

    def can_execute(self, entity: object) -> bool:
        """Whether `entity`'s callback may start now."""
        with self._lock:
            return self._free(id(entity))

    def beginning_execution(self, entity: object) -> bool:
        """Claim the group for `entity`; False if that is not allowed now."""
        with self._lock:
            if not self._free(id(entity)):
                return False
            self._running.add(id(entity))
            return True

    def ending_execution(self, entity: object) -> None:
        """Release the claim of `entity`."""
        with self._lock:
            self._running.discard(id(entity))

    def _free(self, key: int) -> bool:
        raise NotImplementedError


class MutuallyExclusiveCallbackGroup(CallbackGroup):
    """One callback of the group at a time (the default group of a node)."""

    def _free(self, key: int) -> bool:
        return not self._running


class ReentrantCallbackGroup(CallbackGroup):
    """Callbacks run in parallel; one entity's callback never overlaps itself here."""

    def _free(self, key: int) -> bool:
        return key not in self._running


# ------------------------------------------------------------------------------- CDR on DDS
#: Every DDS sample is a whole number of 4-byte words; XCDR keeps the number of padding bytes
#: in the two low bits of the encapsulation options (the header's last byte).
_PAD_MASK = 0x03


def write_cdr(writer: Any, data: bytes) -> None:
    """Publish the CDR bytes ``data`` (header included) on the cyclonedds ``writer``.

    The suite's messages are CDR already (nehmo_core's codec, byte for byte what the IdlStruct
    mirrors serialize), so they go to the C layer directly, the call ``DataWriter.write`` makes
    after serializing a sample. The padding to 4 bytes is recorded in the options bits.
    """
    from cyclonedds._clayer import ddspy_write
    from cyclonedds.core import DDSException

    pad = -len(data) % 4
    if pad:
        data = data[:3] + bytes([(data[3] & ~_PAD_MASK) | pad]) + data[4:] + bytes(pad)
    ret = ddspy_write(writer._ref, data)
    if ret < 0:
        raise DDSException(ret, f"Occurred while writing sample in {writer!r}")


def take_cdr(reader: Any, limit: int) -> list[bytes]:
    """Take up to ``limit`` samples from the cyclonedds ``reader`` as CDR bytes (header
    included, without the padding the options bits announce); invalid samples (disposals)
    are dropped. The same C call as ``DataReader.take``, without its IdlStruct decoding."""
    from cyclonedds._clayer import ddspy_take
    from cyclonedds.core import DDSException, InstanceState, SampleState, ViewState

    mask = SampleState.Any | ViewState.Any | InstanceState.Any
    ret = ddspy_take(reader._ref, mask, limit)
    if isinstance(ret, int):
        raise DDSException(ret, f"Occurred while taking data in {reader!r}")
    out = []
    for data, info in ret:
        if not info.valid_data:
            continue
        pad = data[3] & _PAD_MASK if len(data) >= len(CDR_LE_HEADER) else 0
        if pad and len(data) - pad >= len(CDR_LE_HEADER):
            data = data[:3] + bytes([data[3] & ~_PAD_MASK]) + data[4:-pad]
        out.append(data)
    return out


# ---------------------------------------------------------------------------- entities
class Publisher:
    """Publishes one message type on one topic."""

    def __init__(self, node: Node, msg_type: type, topic: str, qos: QoSProfile) -> None:
        from cyclonedds.pub import DataWriter

        from nehmo_ros.embedded.idl import IDL_TYPES

        self.msg_type = msg_type
        self.topic_name = topic
        self.qos_profile = qos
        self._msgtype = _known_msgtype(msg_type)
        context = node.context
        dds_topic = context.topic("rt" + topic, IDL_TYPES[self._msgtype])
        self._writer: Any = DataWriter(context.participant, dds_topic, qos=to_cyclone(qos))

    @property
    def topic(self) -> str:
        """The resolved topic name."""
        return self.topic_name

    def publish(self, msg: Any) -> None:
        """Send `msg` (an instance of the publisher's type, or its CDR bytes).

        CDR bytes go out as they are (as rclpy sends serialized messages), padded as XCDR
        requires; they must start with the little-endian plain CDR header.
        """
        from nehmo_ros.embedded.idl import to_idl

        if isinstance(msg, bytes | bytearray | memoryview):
            data = bytes(msg)
            if data[:2] != CDR_LE_HEADER[:2] or len(data) < len(CDR_LE_HEADER):
                raise ValueError(
                    f"publisher of {self._msgtype} on {self.topic_name!r} was given bytes that "
                    f"are not little-endian plain CDR (header {data[:4].hex() or 'missing'})"
                )
        elif isinstance(msg, self.msg_type):
            data = to_idl(msg, self._msgtype).serialize()
        else:
            raise TypeError(
                f"publisher of {self._msgtype} on {self.topic_name!r} was given "
                f"{type(msg).__name__}"
            )
        write_cdr(self._writer, data)

    def get_subscription_count(self) -> int:
        """How many readers match this writer."""
        return len(self._writer.get_matched_subscriptions())

    def destroy(self) -> None:
        """Drop the DDS writer."""
        self._writer = None


class Subscription:
    """Calls `callback(msg)` for every message received on a topic."""

    def __init__(
        self,
        node: Node,
        msg_type: type,
        topic: str,
        callback: Callable[[Any], None],
        qos: QoSProfile,
        callback_group: CallbackGroup,
        raw: bool,
    ) -> None:
        from cyclonedds.core import InstanceState, ReadCondition, SampleState, ViewState
        from cyclonedds.sub import DataReader

        from nehmo_ros.embedded.idl import IDL_TYPES

        self.msg_type = msg_type
        self.topic_name = topic
        self.callback = callback
        self.qos_profile = qos
        self.callback_group = callback_group
        self.raw = raw
        self.dropped = 0  # samples that did not decode (little-endian XCDR1 expected)
        self._logger = node.get_logger()
        self._msgtype = _known_msgtype(msg_type)
        context = node.context
        dds_topic = context.topic("rt" + topic, IDL_TYPES[self._msgtype])
        self._reader: Any = DataReader(context.participant, dds_topic, qos=to_cyclone(qos))
        mask = SampleState.Any | ViewState.Any | InstanceState.Any
        self.condition: Any = ReadCondition(self._reader, mask)

    @property
    def topic(self) -> str:
        """The resolved topic name."""
        return self.topic_name

    def take(self, limit: int = 64) -> list[Any]:
        """Messages waiting in the reader (our dataclasses, or CDR bytes if `raw`)."""
        if self._reader is None or not self.condition.triggered:  # nothing waiting
            return []
        samples = take_cdr(self._reader, limit)
        if self.raw:
            return samples
        out = []
        for data in samples:  # one undecodable sample must not cost the others (already taken)
            try:
                out.append(decode(data, self._msgtype))
            except Exception as exc:
                self.dropped += 1
                if self.dropped == 1 or self.dropped % 100 == 0:
                    self._logger.warning(
                        f"{self.topic_name}: dropped {self.dropped} sample(s) that do not decode "
                        f"as {self._msgtype} (last: {exc})"
                    )
        return out

    def get_publisher_count(self) -> int:
        """How many writers match this reader."""
        return len(self._reader.get_matched_publications()) if self._reader is not None else 0

    def destroy(self) -> None:
        """Drop the DDS reader."""
        self._reader = None


class Timer:
    """Calls `callback()` every `period_ns` of its clock (missed periods are skipped)."""

    def __init__(
        self,
        callback: Callable[[], None],
        period_ns: int,
        clock: Clock,
        callback_group: CallbackGroup,
        autostart: bool = True,
    ) -> None:
        if period_ns <= 0:
            raise ValueError(f"timer period must be > 0; got {period_ns} ns")
        self.callback = callback
        self.timer_period_ns = int(period_ns)
        self.clock = clock
        self.callback_group = callback_group
        self._canceled = not autostart
        self._next = clock.now().nanoseconds + self.timer_period_ns

    def time_until_next_call(self) -> int | None:
        """[ns] until the timer is due (<= 0: due now); None when canceled."""
        if self._canceled:
            return None
        now = self.clock.now().nanoseconds
        if now < self._next - 2 * self.timer_period_ns:  # the clock jumped back (sim reset)
            self._next = now + self.timer_period_ns
        return self._next - now

    def is_ready(self) -> bool:
        """True when the timer is due."""
        remaining = self.time_until_next_call()
        return remaining is not None and remaining <= 0

    def _advance(self) -> None:
        now = self.clock.now().nanoseconds
        self._next += self.timer_period_ns
        if self._next <= now:  # late by more than a period: skip to the next period boundary
            missed = (now - self._next) // self.timer_period_ns + 1
            self._next += missed * self.timer_period_ns

    def cancel(self) -> None:
        """Stop firing until reset()."""
        self._canceled = True

    def is_canceled(self) -> bool:
        """True after cancel()."""
        return self._canceled

    def reset(self) -> None:
        """Restart the period from now."""
        self._canceled = False
        self._next = self.clock.now().nanoseconds + self.timer_period_ns

    def destroy(self) -> None:
        """Stop for good."""
        self._canceled = True


def _known_msgtype(msg_type: type) -> str:
    from nehmo_ros.embedded.idl import IDL_TYPES

    msgtype = msgtype_of(msg_type)
    if msgtype not in IDL_TYPES:
        raise TypeError(
            f"the embedded runtime has no DDS type for {msgtype}; known types: {sorted(IDL_TYPES)}"
        )
    return msgtype


# ------------------------------------------------------------------------------------- node
class Node:
    """A ROS 2 node on the embedded runtime (see the module docstring)."""

    def __init__(
        self,
        node_name: str,
        *,
        context: Context | None = None,
        cli_args: Sequence[str] | None = None,
        namespace: str | None = None,
        use_global_arguments: bool = True,
        parameter_overrides: Sequence[Parameter] | None = None,
        allow_undeclared_parameters: bool = False,
        automatically_declare_parameters_from_overrides: bool = False,
        **_ignored: Any,
    ) -> None:
        self.context = context or default_context
        if not self.context.ok():
            raise RuntimeError("create nodes after init() (the context is not initialized)")
        own_args = parse_ros_args(["--ros-args", *cli_args]) if cli_args else None
        remaps = list(self.context.args.remaps if use_global_arguments else [])
        remaps += own_args.remaps if own_args else []
        name, ns = node_name, namespace or ""
        for target, src, dst in remaps:
            if target not in (None, node_name):
                continue
            if src == "__node":
                name = dst
            elif src == "__ns":
                ns = dst
        if not _NAME.match(name):
            raise ValueError(
                f"node name must start with a letter or '_' and hold only letters, digits "
                f"and '_'; got {name!r}"
            )
        ns = "/" + ns.strip("/") if ns.strip("/") else "/"
        self._name, self._namespace = name, ns
        self._remaps = [(s, d) for t, s, d in remaps if t in (None, node_name) and "__" not in s]
        level = (own_args.log_level if own_args else None) or self.context.args.log_level
        self._logger = RcutilsLogger(name, level or "info")
        self._lock = threading.RLock()
        self.default_callback_group: CallbackGroup = MutuallyExclusiveCallbackGroup()
        self.publishers: list[Publisher] = []
        self.subscriptions: list[Subscription] = []
        self.timers: list[Timer] = []
        self._wakers: list[Callable[[], None]] = []
        self._clock = ROSClock()
        self._clock_sub: Subscription | None = None
        self._parameters: dict[str, Parameter] = {}
        self._descriptors: dict[str, ParameterDescriptor] = {}
        self._allow_undeclared = allow_undeclared_parameters
        overrides: dict[str, tuple[Any, str]] = {}
        fq_name = self.get_fully_qualified_name()
        if use_global_arguments:
            overrides.update(resolve_overrides(self.context.args, fq_name))
        if own_args is not None:
            overrides.update(resolve_overrides(own_args, fq_name))
        for parameter in parameter_overrides or ():
            overrides[parameter.name] = (parameter.value, "parameter_overrides")
        self._overrides = overrides
        if automatically_declare_parameters_from_overrides:
            for key, (value, _) in overrides.items():
                if key != "use_sim_time":
                    self.declare_parameter(key, value)
        self.declare_parameter("use_sim_time", False)
        if self.get_parameter("use_sim_time").value:
            self._enable_sim_time()

    # ---------------------------------------------------------------- names
    def get_name(self) -> str:
        """Node name (after ``-r __node:=...``)."""
        return self._name

    def get_namespace(self) -> str:
        """Node namespace ("/" for none)."""
        return self._namespace

    def get_fully_qualified_name(self) -> str:
        """``/ns/name``."""
        return ("" if self._namespace == "/" else self._namespace) + "/" + self._name

    def resolve_topic_name(self, topic: str) -> str:
        """Absolute topic name after namespace expansion and remapping."""
        resolved = self._expand(topic)
        for src, dst in self._remaps:
            if self._expand(src) == resolved:
                return self._expand(dst)
        return resolved

    def _expand(self, topic: str) -> str:
        if topic.startswith("~"):
            topic = self.get_fully_qualified_name() + topic[1:]
        elif not topic.startswith("/"):
            topic = ("" if self._namespace == "/" else self._namespace) + "/" + topic
        tokens = topic[1:].split("/")
        if not all(_TOPIC_TOKEN.match(t) for t in tokens):
            raise ValueError(
                f"invalid topic name {topic!r}: tokens must start with a letter or '_' and hold "
                "only letters, digits and '_'"
            )
        return topic

    # ---------------------------------------------------------------- logging and time
    def get_logger(self) -> RcutilsLogger:
        """The node's logger."""
        return self._logger

    def get_clock(self) -> ROSClock:
        """The node's ROS-time clock (follows ``/clock`` when ``use_sim_time`` is true)."""
        return self._clock

    def _enable_sim_time(self) -> None:
        self._clock._set_ros_time_is_active(True)

        def on_clock(msg: ClockMsg) -> None:
            self._clock._set_ros_time(msg.clock.sec * 1_000_000_000 + msg.clock.nanosec)

        self._clock_sub = self.create_subscription(ClockMsg, "/clock", on_clock, qos_profile_clock)

    # ---------------------------------------------------------------- parameters
    def declare_parameter(
        self,
        name: str,
        value: Any = None,
        descriptor: ParameterDescriptor | None = None,
        ignore_override: bool = False,
    ) -> Parameter:
        """Declare `name` with a default `value` (or a ``Parameter.Type`` for a required one)."""
        with self._lock:
            if name in self._parameters:
                raise ParameterAlreadyDeclaredException(name)
            descriptor = descriptor or ParameterDescriptor()
            if isinstance(value, Parameter.Type):
                declared, default = value, None
            else:
                declared, default = Parameter.Type.from_parameter_value(value), value
            if descriptor.dynamic_typing:
                declared = Parameter.Type.NOT_SET
            final = default
            if not ignore_override and name in self._overrides:
                final, source = self._overrides[name]
                if not type_matches(declared, final):
                    raise InvalidParameterValueException(
                        name, final, type_rule(name, declared, default) + f" (set by `{source}`)"
                    )
                if declared == Parameter.Type.DOUBLE_ARRAY and isinstance(final, list):
                    final = [float(v) for v in final]
            param_type = declared if final is None else Parameter.Type.from_parameter_value(final)
            parameter = Parameter(name, param_type, final)
            self._parameters[name] = parameter
            self._descriptors[name] = descriptor
            return parameter

    def declare_parameters(
        self, namespace: str, parameters: Sequence[tuple[Any, ...]]
    ) -> list[Parameter]:
        """Declare several ``(name, value[, descriptor])`` under ``namespace.``."""
        out = []
        for item in parameters:
            name = f"{namespace}.{item[0]}" if namespace else item[0]
            out.append(self.declare_parameter(name, *item[1:]))
        return out

    def has_parameter(self, name: str) -> bool:
        """Whether `name` is declared."""
        return name in self._parameters

    def get_parameter(self, name: str) -> Parameter:
        """The declared parameter `name`."""
        with self._lock:
            if name not in self._parameters:
                if self._allow_undeclared:
                    return Parameter(name, Parameter.Type.NOT_SET, None)
                raise ParameterNotDeclaredException(name)
            parameter = self._parameters[name]
            if parameter.value is None and parameter.type_ != Parameter.Type.NOT_SET:
                raise ParameterUninitializedException(name)
            return parameter

    def get_parameter_or(self, name: str, alternative_value: Parameter | None = None) -> Parameter:
        """The parameter, or `alternative_value` if undeclared."""
        if name not in self._parameters:
            return alternative_value or Parameter(name, Parameter.Type.NOT_SET, None)
        return self._parameters[name]

    def get_parameters(self, names: Sequence[str]) -> list[Parameter]:
        """Several declared parameters."""
        return [self.get_parameter(n) for n in names]

    def set_parameters(self, parameters: Sequence[Parameter]) -> list[bool]:
        """Set declared parameters (type-checked); raises on the first invalid one."""
        results = []
        with self._lock:
            for parameter in parameters:
                if parameter.name not in self._parameters:
                    raise ParameterNotDeclaredException(parameter.name)
                old = self._parameters[parameter.name]
                descriptor = self._descriptors[parameter.name]
                declared = Parameter.Type.NOT_SET if descriptor.dynamic_typing else old.type_
                if descriptor.read_only or not type_matches(declared, parameter.value):
                    reason = (
                        "is read-only"
                        if descriptor.read_only
                        else type_rule(parameter.name, declared, None)
                    )
                    raise InvalidParameterValueException(parameter.name, parameter.value, reason)
                self._parameters[parameter.name] = parameter
                results.append(True)
        return results

    # ---------------------------------------------------------------- entities
    def create_publisher(
        self,
        msg_type: type,
        topic: str,
        qos_profile: QoSProfile | int,
        *,
        callback_group: CallbackGroup | None = None,
        **_ignored: Any,
    ) -> Publisher:
        """A publisher of `msg_type` on `topic`."""
        del callback_group
        publisher = Publisher(
            self, msg_type, self.resolve_topic_name(topic), as_profile(qos_profile)
        )
        with self._lock:
            self.publishers.append(publisher)
        return publisher

    def create_subscription(
        self,
        msg_type: type,
        topic: str,
        callback: Callable[[Any], None],
        qos_profile: QoSProfile | int,
        *,
        callback_group: CallbackGroup | None = None,
        raw: bool = False,
        **_ignored: Any,
    ) -> Subscription:
        """A subscription calling `callback(msg)` from the executor that spins this node."""
        subscription = Subscription(
            self,
            msg_type,
            self.resolve_topic_name(topic),
            callback,
            as_profile(qos_profile),
            callback_group or self.default_callback_group,
            raw,
        )
        with self._lock:
            self.subscriptions.append(subscription)
        self._wake()
        return subscription

    def create_timer(
        self,
        timer_period_sec: float,
        callback: Callable[[], None],
        callback_group: CallbackGroup | None = None,
        clock: Clock | None = None,
        autostart: bool = True,
    ) -> Timer:
        """A timer on the node's clock (simulated time when ``use_sim_time``)."""
        timer = Timer(
            callback,
            round(timer_period_sec * 1e9),
            clock or self._clock,
            callback_group or self.default_callback_group,
            autostart,
        )
        with self._lock:
            self.timers.append(timer)
        self._wake()
        return timer

    def destroy_publisher(self, publisher: Publisher) -> bool:
        """Remove a publisher."""
        return self._remove(self.publishers, publisher)

    def destroy_subscription(self, subscription: Subscription) -> bool:
        """Remove a subscription."""
        return self._remove(self.subscriptions, subscription)

    def destroy_timer(self, timer: Timer) -> bool:
        """Remove a timer."""
        return self._remove(self.timers, timer)

    def _remove(self, items: list[Any], item: Any) -> bool:
        with self._lock:
            if item not in items:
                return False
            items.remove(item)
        item.destroy()
        self._wake()
        return True

    def count_subscribers(self, topic: str) -> int:
        """Matched readers of this node's publishers on `topic` (a lower bound of rclpy's)."""
        name = self.resolve_topic_name(topic)
        counts = [p.get_subscription_count() for p in self.publishers if p.topic_name == name]
        return max(counts, default=0)

    def count_publishers(self, topic: str) -> int:
        """Matched writers of this node's subscriptions on `topic` (a lower bound of rclpy's)."""
        name = self.resolve_topic_name(topic)
        counts = [s.get_publisher_count() for s in self.subscriptions if s.topic_name == name]
        return max(counts, default=0)

    def destroy_node(self) -> None:
        """Drop every entity of the node."""
        with self._lock:
            entities: list[Any] = [*self.publishers, *self.subscriptions, *self.timers]
            self.publishers, self.subscriptions, self.timers = [], [], []
        for entity in entities:
            entity.destroy()
        self._wake()

    def _add_waker(self, waker: Callable[[], None]) -> None:
        with self._lock:
            self._wakers.append(waker)

    def _remove_waker(self, waker: Callable[[], None]) -> None:
        with self._lock:
            if waker in self._wakers:
                self._wakers.remove(waker)

    def _wake(self) -> None:
        for waker in list(self._wakers):
            waker()


__all__ = [
    "CallbackGroup",
    "ClockType",
    "MutuallyExclusiveCallbackGroup",
    "Node",
    "Publisher",
    "RcutilsLogger",
    "ReentrantCallbackGroup",
    "Subscription",
    "Timer",
]
