"""The exception hierarchy of NeHMO.

Every error raised on bad user input derives from :class:`NehmoError`, so callers (and the
ROS nodes) can catch one class and print one clear line instead of a traceback.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager


class NehmoError(Exception):
    """Root of every error NeHMO raises on purpose."""


class UnknownNameError(NehmoError, KeyError):
    """A name (robot, cell, model, planner, ...) that NeHMO does not know."""

    def __init__(self, kind: str, name: object, valid: Iterable[str]) -> None:
        self.kind = kind
        self.name = name
        self.valid = sorted(valid)
        super().__init__(f"unknown {kind} {name!r}. Valid {kind} names: {self.valid}")

    def __str__(self) -> str:  # KeyError would quote the message otherwise
        return str(self.args[0])


class InvalidValueError(NehmoError, ValueError):
    """A parameter that breaks a rule: the message names the parameter, the rule, the value."""

    def __init__(self, parameter: str, rule: str, value: object) -> None:
        self.parameter = parameter
        self.rule = rule
        self.value = value
        super().__init__(f"`{parameter}` {rule}; got {value!r}")


class ModelFileError(NehmoError):
    """A robot description or trained model file that is missing, corrupted or mismatched."""


@contextmanager
def as_options(options: Mapping[str, str]) -> Iterator[None]:
    """Re-raise an :class:`InvalidValueError` about a settings field under the command-line
    option that set it (``options`` maps field names to option names, e.g. ``learning_rate``
    to ``--lr``), so the message names what the user typed."""
    try:
        yield
    except InvalidValueError as exc:
        if exc.parameter not in options:
            raise
        raise InvalidValueError(options[exc.parameter], exc.rule, exc.value) from None


def one_line(err: BaseException, limit: int = 600) -> str:
    """``err`` as one line (multi-line messages joined, very long ones shortened): what a
    console entry point prints, and what a summary records as an episode's error."""
    text = " ".join(part.strip() for part in str(err).splitlines() if part.strip())
    text = text or type(err).__name__
    return text if len(text) <= limit else text[: limit - 4] + " ..."
