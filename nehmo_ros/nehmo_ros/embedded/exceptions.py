"""Exceptions of the embedded runtime, named as in ``rclpy.exceptions``."""

from __future__ import annotations


class RosArgsError(ValueError):
    """A malformed ``--ros-args`` section or an unreadable ``--params-file``."""


class ParameterException(Exception):
    """Base of the parameter errors (as in rclpy)."""


class ParameterNotDeclaredException(ParameterException):
    """A parameter was read or set before being declared."""

    def __init__(self, name: str) -> None:
        super().__init__(f"parameter `{name}` has not been declared")


class ParameterAlreadyDeclaredException(ParameterException):
    """A parameter was declared twice."""

    def __init__(self, name: str) -> None:
        super().__init__(f"parameter `{name}` has already been declared")


class ParameterUninitializedException(ParameterException):
    """A parameter declared with a type but no value was read before any value was given."""

    def __init__(self, name: str) -> None:
        super().__init__(
            f"parameter `{name}` is required and has no value; "
            f"pass it with `--ros-args -p {name}:=<value>` or a --params-file"
        )


class InvalidParameterValueException(ParameterException):
    """A value of the wrong type (or rejected otherwise) for a declared parameter."""

    def __init__(self, name: str, value: object, reason: str) -> None:
        self.parameter_name = name
        self.value = value
        self.reason = reason
        super().__init__(f"parameter `{name}` {reason}; got {value!r}")


class InvalidParameterTypeException(InvalidParameterValueException):
    """Alias kept for code written against older rclpy releases."""


class ExternalShutdownException(Exception):
    """The context was shut down (Ctrl-C, SIGTERM or ``shutdown()``) while spinning."""
