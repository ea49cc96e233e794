"""``--ros-args`` parsing for the embedded runtime, following rcl's rules.

Supported inside ``--ros-args ... [--]``: ``-p/--param [node:]name:=value``,
``-r/--remap [node:]from:=to`` (topics, ``__node``, ``__ns``), ``--params-file FILE``,
``--log-level [name:=]LEVEL``; ``-e/--enclave`` and the ``--(enable|disable)-*-logs`` flags are
accepted and ignored. Values are typed as rcl does: unquoted ``true``/``false`` (and yes/no/on/off)
are bools, then integers, then floats, else strings; quoted values are strings; a YAML list
becomes an array of one element type.

Parameter files have the ROS 2 layout::

    /**:                      # every node (also /*, /ns/*, node_name, /ns/node_name)
      ros__parameters:
        rate: 25.0
        nested: {a: 1}        # → parameter "nested.a"

Overrides are applied in command-line order (files and ``-p`` alike); inside one file, entries
for the node's exact name win over wildcard entries.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from nehmo_ros.embedded.exceptions import RosArgsError

LOG_LEVELS = ("debug", "info", "warn", "error", "fatal")
_TRUE = {"y", "Y", "yes", "Yes", "YES", "true", "True", "TRUE", "on", "On", "ON"}
_FALSE = {"n", "N", "no", "No", "NO", "false", "False", "FALSE", "off", "Off", "OFF"}
_INT = re.compile(r"^[+-]?(0[xX][0-9a-fA-F]+|[0-9]+)$")
_FLOAT = re.compile(
    r"^[+-]?((\d+\.?\d*|\.\d+)([eE][+-]?\d+)?|\.?inf|\.?Inf|\.?INF|\.?nan|\.?NaN|\.?NAN)$"
)
_IGNORED_FLAGS = {
    "--enable-rosout-logs",
    "--disable-rosout-logs",
    "--enable-stdout-logs",
    "--disable-stdout-logs",
    "--enable-external-lib-logs",
    "--disable-external-lib-logs",
}


@dataclass(frozen=True)
class Override:
    """One parameter value from the command line; `node` limits it to one node name."""

    name: str
    value: Any
    source: str
    node: str | None = None


@dataclass
class RosArgs:
    """Everything read from the ``--ros-args`` sections of a command line."""

    overrides: list[Override | ParamFile] = field(default_factory=list)
    remaps: list[tuple[str | None, str, str]] = field(default_factory=list)  # (node, from, to)
    log_level: str | None = None


@dataclass(frozen=True)
class ParamFile:
    """A parsed ``--params-file``: node-name pattern → {parameter: value}."""

    path: str
    entries: tuple[tuple[str, dict[str, Any]], ...]


def scalar_value(text: str, quoted: bool = False) -> Any:
    """Type one YAML scalar as rcl does (bool, int, float, then string)."""
    if quoted:
        return text
    if text in _TRUE:
        return True
    if text in _FALSE:
        return False
    if _INT.match(text):
        return int(text, 16) if text.lower().lstrip("+-").startswith("0x") else int(text, 10)
    if _FLOAT.match(text):
        return float(text.replace(".inf", "inf").replace(".Inf", "inf").replace(".nan", "nan"))
    return text


def _node_value(node: yaml.Node, where: str) -> Any:
    if isinstance(node, yaml.ScalarNode):
        return scalar_value(node.value, quoted=node.style in ("'", '"', "|", ">"))
    if isinstance(node, yaml.SequenceNode):
        items = [_node_value(item, where) for item in node.value]
        if any(isinstance(item, list | dict) for item in items):
            raise RosArgsError(f"{where}: arrays of arrays or of maps are not parameter values")
        kinds = {_array_kind(item) for item in items}
        if kinds == {int, float}:  # rcl would reject; promoting is the friendlier reading
            return [float(item) for item in items]
        if len(kinds) > 1:
            raise RosArgsError(f"{where}: array elements must all have one type; got {items!r}")
        return items
    if isinstance(node, yaml.MappingNode):
        return {str(_node_value(k, where)): _node_value(v, where) for k, v in node.value}
    raise RosArgsError(f"{where}: unsupported YAML node {node!r}")


def _array_kind(item: Any) -> type:
    return bool if isinstance(item, bool) else type(item)


def parse_value(text: str, where: str) -> Any:
    """Type the value of ``-p name:=value`` (YAML flow syntax allowed: ``[1.0, 2.0]``)."""
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as err:
        raise RosArgsError(f"{where}: cannot parse value {text!r}: {err}") from None
    if node is None:
        return ""
    value = _node_value(node, where)
    if isinstance(value, dict):
        raise RosArgsError(f"{where}: a map is not a parameter value; got {text!r}")
    return value


def _flatten(prefix: str, value: Any, out: dict[str, Any]) -> None:
    if isinstance(value, dict):
        for key, sub in value.items():
            _flatten(f"{prefix}.{key}" if prefix else str(key), sub, out)
    else:
        out[prefix] = value


def load_params_file(path: str) -> ParamFile:
    """Read a ROS 2 parameter file; raises RosArgsError naming the file and the problem."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as err:
        raise RosArgsError(f"--params-file {path!r}: cannot read it: {err.strerror}") from None
    try:
        root = yaml.compose(text, Loader=yaml.SafeLoader)
    except yaml.YAMLError as err:
        raise RosArgsError(f"--params-file {path!r}: invalid YAML: {err}") from None
    if root is None:
        return ParamFile(path, ())
    tree = _node_value(root, f"--params-file {path!r}")
    if not isinstance(tree, dict):
        raise RosArgsError(f"--params-file {path!r}: the top level must be a map of node names")
    entries: list[tuple[str, dict[str, Any]]] = []

    def walk(prefix: str, sub: dict[str, Any]) -> None:
        for key, value in sub.items():
            if key == "ros__parameters":
                if not isinstance(value, dict):
                    raise RosArgsError(
                        f"--params-file {path!r}: `ros__parameters` of {prefix!r} must be a map"
                    )
                params: dict[str, Any] = {}
                _flatten("", value, params)
                entries.append(("/" + prefix.strip("/"), params))
            elif isinstance(value, dict):
                walk(f"{prefix}/{key.strip('/')}", value)
            else:
                raise RosArgsError(
                    f"--params-file {path!r}: expected `ros__parameters` under "
                    f"{(prefix + '/' + key)!r}; got a value {value!r}"
                )

    walk("", tree)
    return ParamFile(path, tuple(entries))


def node_matches(pattern: str, fq_name: str) -> bool:
    """rcl's node-name matching: ``/**`` any, ``*`` one segment; a bare name matches it."""
    if pattern in ("/**", "/*", "**", "*"):
        return pattern.endswith("**") or fq_name.count("/") == 1
    if "*" not in pattern:
        if pattern.count("/") == 1:  # "/name" also matches the node name in any namespace
            return fq_name == pattern or fq_name.rsplit("/", 1)[-1] == pattern[1:]
        return fq_name == pattern
    regex = re.escape(pattern).replace(r"/\*\*", "(/[^/]+)*").replace(r"\*", "[^/]+")
    return re.fullmatch(regex, fq_name) is not None


def resolve_overrides(ros_args: RosArgs, fq_name: str) -> dict[str, tuple[Any, str]]:
    """Parameter name → (value, source) for node `fq_name` (``/ns/name``)."""
    resolved: dict[str, tuple[Any, str]] = {}
    node_name = fq_name.rsplit("/", 1)[-1]
    for item in ros_args.overrides:
        if isinstance(item, ParamFile):
            wildcard = [e for e in item.entries if "*" in e[0]]
            exact = [e for e in item.entries if "*" not in e[0]]
            for pattern, params in (*wildcard, *exact):
                if node_matches(pattern, fq_name):
                    for name, value in params.items():
                        resolved[name] = (value, f"--params-file {item.path}")
        elif item.node is None or item.node in (node_name, fq_name):
            resolved[item.name] = (item.value, item.source)
    return resolved


def _split_rule(flag: str, text: str) -> tuple[str | None, str, str]:
    if ":=" not in text:
        raise RosArgsError(f"{flag} expects NAME:=VALUE; got {text!r}")
    lhs, rhs = text.split(":=", 1)
    node = None
    if ":" in lhs:
        node, lhs = lhs.split(":", 1)
    if not lhs:
        raise RosArgsError(f"{flag} expects NAME:=VALUE; got {text!r}")
    return node, lhs, rhs


def split_ros_args(argv: list[str]) -> tuple[list[str], list[str]]:
    """(arguments outside ``--ros-args`` sections, arguments inside them)."""
    plain: list[str] = []
    inside: list[str] = []
    in_ros = False
    for arg in argv:
        if arg == "--ros-args":
            in_ros = True
        elif arg == "--" and in_ros:
            in_ros = False
        elif in_ros:
            inside.append(arg)
        else:
            plain.append(arg)
    return plain, inside


def remove_ros_args(args: list[str]) -> list[str]:
    """The command line without its ``--ros-args`` sections (as ``rclpy.utilities``)."""
    return split_ros_args(list(args))[0]


def parse_ros_args(argv: list[str]) -> RosArgs:
    """Parse the ``--ros-args`` sections of `argv`; raises RosArgsError with one clear line."""
    _, tokens = split_ros_args(list(argv))
    result = RosArgs()
    i = 0

    def operand(flag: str) -> str:
        if i + 1 >= len(tokens):
            raise RosArgsError(f"{flag} needs an argument")
        return tokens[i + 1]

    while i < len(tokens):
        flag = tokens[i]
        if flag in ("-p", "--param"):
            node, name, text = _split_rule(flag, operand(flag))
            value = parse_value(text, f"-p {name}")
            result.overrides.append(Override(name, value, f"-p {name}:={text}", node))
            i += 2
        elif flag in ("-r", "--remap"):
            node, src, dst = _split_rule(flag, operand(flag))
            result.remaps.append((node, src, dst))
            i += 2
        elif flag == "--params-file":
            result.overrides.append(load_params_file(operand(flag)))
            i += 2
        elif flag == "--log-level":
            level = operand(flag).rsplit(":=", 1)[-1].lower()
            if level not in LOG_LEVELS:
                raise RosArgsError(f"--log-level must be one of {list(LOG_LEVELS)}; got {level!r}")
            result.log_level = level
            i += 2
        elif flag in ("-e", "--enclave"):
            operand(flag)
            i += 2
        elif flag in _IGNORED_FLAGS:
            i += 1
        else:
            raise RosArgsError(
                f"unknown ROS argument {flag!r}; supported: -p/--param, -r/--remap, "
                "--params-file, --log-level, -e/--enclave"
            )
    return result
