"""Parameters of the embedded runtime, as rclpy's ``Parameter`` and its declared-type rules.

A parameter declared with a default takes the default's type; an override of another type is
refused (``InvalidParameterValueException``), as rclpy does: ``-p rate:=25`` does not set a
double parameter, ``-p rate:=25.0`` does. Declaring with ``Parameter.Type.X`` instead of a value
makes a required parameter: reading it before a value was given raises
``ParameterUninitializedException``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any


class _Type(IntEnum):
    NOT_SET = 0
    BOOL = 1
    INTEGER = 2
    DOUBLE = 3
    STRING = 4
    BYTE_ARRAY = 5
    BOOL_ARRAY = 6
    INTEGER_ARRAY = 7
    DOUBLE_ARRAY = 8
    STRING_ARRAY = 9

    @classmethod
    def from_parameter_value(cls, value: Any) -> _Type:
        """The parameter type of a Python value; raises TypeError for anything else."""
        if value is None:
            return cls.NOT_SET
        if isinstance(value, bool):
            return cls.BOOL
        if isinstance(value, int):
            return cls.INTEGER
        if isinstance(value, float):
            return cls.DOUBLE
        if isinstance(value, str):
            return cls.STRING
        if isinstance(value, bytes):
            return cls.BYTE_ARRAY
        if isinstance(value, list | tuple):
            for kind, member in ((bool, cls.BOOL_ARRAY), (str, cls.STRING_ARRAY)):
                if value and all(isinstance(v, kind) for v in value):
                    return member
            if value and all(isinstance(v, int) and not isinstance(v, bool) for v in value):
                return cls.INTEGER_ARRAY
            if value and all(isinstance(v, float) for v in value):
                return cls.DOUBLE_ARRAY
            if not value:
                return cls.BYTE_ARRAY  # rclpy's reading of an empty list
        raise TypeError(f"{value!r} is not a valid parameter value")

    def is_array(self) -> bool:
        """True for the *_ARRAY types."""
        return self.value >= _Type.BYTE_ARRAY.value


@dataclass
class ParameterValue:
    """The typed fields of rcl_interfaces/ParameterValue, for ``get_parameter_value()``."""

    type: int = 0
    bool_value: bool = False
    integer_value: int = 0
    double_value: float = 0.0
    string_value: str = ""
    byte_array_value: list[bytes] = field(default_factory=list)
    bool_array_value: list[bool] = field(default_factory=list)
    integer_array_value: list[int] = field(default_factory=list)
    double_array_value: list[float] = field(default_factory=list)
    string_array_value: list[str] = field(default_factory=list)


@dataclass
class ParameterDescriptor:
    """The subset of rcl_interfaces/ParameterDescriptor the runtime honours."""

    name: str = ""
    type: int = 0
    description: str = ""
    additional_constraints: str = ""
    read_only: bool = False
    dynamic_typing: bool = False


_VALUE_FIELD = {
    _Type.BOOL: "bool_value",
    _Type.INTEGER: "integer_value",
    _Type.DOUBLE: "double_value",
    _Type.STRING: "string_value",
    _Type.BYTE_ARRAY: "byte_array_value",
    _Type.BOOL_ARRAY: "bool_array_value",
    _Type.INTEGER_ARRAY: "integer_array_value",
    _Type.DOUBLE_ARRAY: "double_array_value",
    _Type.STRING_ARRAY: "string_array_value",
}


class Parameter:
    """A named, typed parameter value (as ``rclpy.parameter.Parameter``)."""

    Type = _Type

    def __init__(self, name: str, type_: _Type | None = None, value: Any = None) -> None:
        if type_ is None:
            type_ = _Type.from_parameter_value(value)
        self._name = name
        self._type = _Type(type_)
        self._value = list(value) if isinstance(value, tuple) else value

    @property
    def name(self) -> str:
        """Parameter name."""
        return self._name

    @property
    def type_(self) -> _Type:
        """Parameter type."""
        return self._type

    @property
    def value(self) -> Any:
        """Parameter value (None when not set)."""
        return self._value

    def get_parameter_value(self) -> ParameterValue:
        """The value in rcl_interfaces/ParameterValue form."""
        result = ParameterValue(type=int(self._type))
        if self._type in _VALUE_FIELD:
            setattr(result, _VALUE_FIELD[self._type], self._value)
        return result

    def __repr__(self) -> str:
        return f"Parameter({self._name!r}, {self._type.name}, {self._value!r})"


def type_matches(declared: _Type, value: Any) -> bool:
    """Whether `value` may be given to a parameter declared with type `declared`."""
    if declared == _Type.NOT_SET:
        return True
    try:
        actual = _Type.from_parameter_value(value)
    except TypeError:
        return False
    if isinstance(value, list | tuple) and not value:
        return declared.is_array()
    return actual == declared


def type_rule(name: str, declared: _Type, default: Any) -> str:
    """The sentence of an InvalidParameterValueException for a wrong type."""
    rule = f"must be of type {declared.name}"
    if default is not None:
        rule += f" (its default is {default!r})"
    if declared in (_Type.DOUBLE, _Type.DOUBLE_ARRAY):
        rule += "; write doubles with a decimal point, e.g. 25.0"
    return rule
