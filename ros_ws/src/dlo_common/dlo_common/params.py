"""Node parameter declarations and what is rendered from them (no ROS imports).

A node module lists its parameters once, as a module-level ``PARAMETERS`` sequence of
:class:`Param` records (or plain ``(name, default, description)`` tuples). From that one list come:

- the checks when the node starts (:func:`check_value`, called by
  ``dlo_common.node_util.declare_parameters``): type of the default, range, choices, or the
  parameter's own ``check`` (a value that is a name or a pair of numbers, say);
- the node's ``--help`` text (:func:`help_text`);
- its parameters file ``config/<executable>.yaml`` (:func:`params_yaml`, ROS 2 ``--params-file``
  format, each description as a comment);
- the parameter tables of the docs (:func:`markdown_table`).

And :func:`yaml_problem`: where a YAML file breaks and why, in one line, for every reader of YAML files.

Units are part of each description (e.g. ``[s]``, ``[m]``).
"""

from __future__ import annotations

import difflib
import inspect
import json
import math
import re
import textwrap
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any

USAGE = "ros2run {package} {executable} [--ros-args (-p NAME:=VALUE | --params-file FILE) ...]"


class ParameterError(ValueError):
    """A parameter has a wrong type or value (the message names it and what is expected)."""


class UnknownParameterError(ParameterError):
    """A parameter set on the command line or in a params file that the node does not declare."""


@dataclass(frozen=True)
class Param:
    """One declared node parameter: its default fixes its type.

    Optional range: ``at_least`` (value >= bound), ``above`` (value > bound), ``at_most``
    (value <= bound), ``choices`` (value is one of these strings), ``length`` (a list parameter
    has exactly this many entries).
    A list default of numbers makes a ``double_array`` parameter, any other list a ``string_array``.

    ``check``: for a parameter whose values one ROS type cannot hold (a preset name or a pair of
    numbers, e.g. ``tactile_noise``): a function from the value as it arrives to the value to use,
    raising ValueError ("expected ..., got ...") for a bad one; it replaces the type and range checks.
    Then ``types`` names the ROS types it takes (e.g. ``string or double_array``) and ``accepts`` its
    range in words, for the help, the parameters file and the docs.
    """

    name: str
    default: Any
    description: str
    at_least: float | None = None
    above: float | None = None
    at_most: float | None = None
    choices: tuple[str, ...] = ()
    length: int | None = None
    check: Callable[[Any], Any] | None = None
    types: str = ""
    accepts: str = ""

    @property
    def type_name(self) -> str:
        """The ROS 2 parameter type of the default: bool, integer, double, string, string_array, double_array
        (``types`` when given)."""
        if self.types:
            return self.types
        default = self.default
        if isinstance(default, (list, tuple)):
            return "double_array" if default and all(_is_number(v) for v in default) else "string_array"
        return ros_type_name(default)

    @property
    def range_text(self) -> str:
        """The range in words, e.g. ``>= 1``, ``0..19``, ``> 0``, ``step_locked | real_time``,
        ``length 3``, ``accepts`` when given; '' if none."""
        if self.accepts:
            return self.accepts
        if self.choices:
            return " | ".join(self.choices)
        if self.length is not None:
            return f"length {self.length}"
        if self.at_least is not None and self.at_most is not None:
            return f"{_number(self.at_least)}..{_number(self.at_most)}"
        parts = []
        if self.at_least is not None:
            parts.append(f">= {_number(self.at_least)}")
        if self.above is not None:
            parts.append(f"> {_number(self.above)}")
        if self.at_most is not None:
            parts.append(f"<= {_number(self.at_most)}")
        return ", ".join(parts)


@dataclass(frozen=True)
class YamlProblem:
    """Where a YAML text breaks (1-based line and column; None when the error does not say) and why (one line)."""

    line: int | None
    column: int | None
    problem: str


def yaml_problem(error: Exception, text: str) -> YamlProblem:
    """The :class:`YamlProblem` of a PyYAML error raised on ``text``: a scanner or parser error has a mark; a
    reader error (a character YAML does not allow, a control character say) has a position in ``text``,
    which is turned into the line and column; its message's ' in "<unicode string>", position N' and line
    breaks are dropped."""
    mark, position = getattr(error, "problem_mark", None), getattr(error, "position", None)
    if mark is not None:
        line, column = mark.line + 1, mark.column + 1
    elif isinstance(position, int):
        line = text.count("\n", 0, position) + 1
        column = position - (text.rfind("\n", 0, position) + 1) + 1
    else:
        line = column = None
    problem = str(getattr(error, "problem", None) or error)
    problem = re.sub(r'\s+in "<unicode string>", position \d+', "", problem)
    return YamlProblem(line, column, " ".join(problem.split()))


def _number(value: float) -> str:
    return str(int(value)) if float(value).is_integer() else repr(float(value))


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def ros_type_name(value: Any) -> str:
    """The ROS 2 parameter type a value arrives as: bool, integer, double, string, ``<type>_array``."""
    if isinstance(value, bool):
        return "bool"
    if isinstance(value, int):
        return "integer"
    if isinstance(value, float):
        return "double"
    if isinstance(value, (bytes, bytearray)):
        return "byte_array"
    if isinstance(value, (list, tuple)):
        kinds = {ros_type_name(v) for v in value}
        return f"{kinds.pop()}_array" if len(kinds) == 1 else "array"
    return "string"


def example(param: Param) -> str:
    """A value that fits ``param``, as set on the command line: ``-p horizon:=150``,
    ``-p mode:=step_locked``, ``-p camera_position:=[0.0,0.0,1.0]``, ``-p topics:=/dlo/a,/dlo/b``;
    a string whose default is empty: the description's ``e.g. 'T'`` (``-p without:=T``), else ``text``."""
    default = param.default
    if param.choices:
        value = param.choices[0]
    elif isinstance(default, bool):
        value = "true"
    elif _is_number(default):
        value = format_default(default)
    elif param.type_name == "double_array":
        value = "[" + ",".join(repr(float(v)) for v in default) + "]"
    elif isinstance(default, (list, tuple)):
        items = [str(v) for v in default] or ["/dlo/a", "/dlo/b"][: param.length or 2]
        value = ",".join(items)
    else:  # an empty default: the description's own example ("..., e.g. 'T' or 'V'"), else a word
        shown = re.search(r"e\.g\. '([^'\s]+)'", param.description)
        value = str(default) or (shown.group(1) if shown else "text")
    return f"-p {param.name}:={value}"


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """``; did you mean 'noise'?`` (the closest of ``known`` to ``name``, by difflib), or '' when ``known`` is
    empty: the end of an "unknown name" message (node parameters, dlo-train's config keys)."""
    closest = difflib.get_close_matches(name, list(known), n=1, cutoff=0.0)
    return f"; did you mean {closest[0]!r}?" if closest else ""


def unknown_parameter(name: str, known: Iterable[str]) -> UnknownParameterError:
    """``unknown parameter 'nosuch'; did you mean 'noise'?`` (:func:`did_you_mean`)."""
    return UnknownParameterError(f"unknown parameter {name!r}" + did_you_mean(name, known))


def as_param(spec: Param | Sequence[Any]) -> Param:
    """A :class:`Param` from a Param or a ``(name, default, description)`` tuple."""
    return spec if isinstance(spec, Param) else Param(*spec)


def as_params(specs: Iterable[Param | Sequence[Any]]) -> list[Param]:
    return [as_param(spec) for spec in specs]


def _coerce_scalar(default: Any, value: Any, bad: Callable[[str], ParameterError]) -> Any:
    """``value`` read as the scalar type of ``default`` (bool, int, float, str; anything else: as it is)."""
    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        raise bad("a bool (true/false)")
    if isinstance(default, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise bad("an integer")
    if isinstance(default, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise bad("a number")
    if isinstance(default, str):
        if isinstance(value, (str, int, float)) and not isinstance(value, bool):
            return str(value)
        raise bad("a string")
    return value


def _numbers(value: Any, expected: str, bad: Callable[[str], ParameterError]) -> list[float]:
    """A ``double_array`` value: a list of numbers (or of number strings), or 'x,y,z'."""
    items = value.split(",") if isinstance(value, str) else value  # also 'x,y,z'
    try:
        if not isinstance(items, (list, tuple)) or not all(_is_number(v) or isinstance(v, str) for v in items):
            raise ValueError
        return [float(v) for v in items]
    except ValueError:
        raise bad(expected) from None


def _strings(value: Any, expected: str, bad: Callable[[str], ParameterError]) -> list[str]:
    """A ``string_array`` value: a list of strings, or one string of comma-separated items."""
    if isinstance(value, str):  # one topic, or a comma-separated list
        return [v.strip() for v in value.split(",") if v.strip()]
    if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
        return list(value)
    raise bad(expected)


def coerce(param: Param, value: Any) -> Any:
    """``value`` read as the type of ``param.default``, or :class:`ParameterError` naming the parameter."""
    name, default = param.name, param.default

    def bad(expected: str) -> ParameterError:
        return ParameterError(
            f"parameter '{name}': expected {expected}, e.g. {example(param)}, got {value!r} ({ros_type_name(value)})"
        )

    if not isinstance(default, (list, tuple)):
        return _coerce_scalar(default, value, bad)
    count = f"{param.length} " if param.length is not None else "a list of "
    if param.type_name == "double_array":
        expected = f"{count}numbers"
        got = _numbers(value, expected, bad)
    else:
        expected = f"{count}strings"
        got = _strings(value, expected, bad)
    if param.length is not None and len(got) != param.length:
        raise bad(expected)
    return got


def check_value(param: Param, value: Any) -> Any:
    """:func:`coerce`, then the range (or the parameter's own ``check``): the checked value, or
    :class:`ParameterError` in one line."""
    name = param.name
    if param.check is not None:
        try:
            return param.check(value)
        except (TypeError, ValueError) as error:
            raise ParameterError(f"parameter '{name}': {error}") from None
    value = coerce(param, value)
    if param.type_name == "double_array" and not all(math.isfinite(v) for v in value):
        raise ParameterError(f"parameter '{name}': expected finite numbers, e.g. {example(param)}, got {value}")
    if param.choices and value not in param.choices:
        raise ParameterError(f"parameter '{name}': expected one of {tuple(param.choices)}, got {value!r}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        if math.isnan(value):
            raise ParameterError(f"parameter '{name}': must be a number, got nan")
        if param.at_least is not None and param.at_most is not None:
            if not param.at_least <= value <= param.at_most:
                raise ParameterError(f"parameter '{name}': must be in {param.range_text}, got {value}")
        elif param.at_least is not None and value < param.at_least:
            raise ParameterError(f"parameter '{name}': must be >= {_number(param.at_least)}, got {value}")
        elif param.at_most is not None and value > param.at_most:
            raise ParameterError(f"parameter '{name}': must be <= {_number(param.at_most)}, got {value}")
        if param.above is not None and not value > param.above:
            raise ParameterError(f"parameter '{name}': must be > {_number(param.above)}, got {value}")
    return value


def format_default(value: Any) -> str:
    """A default as written on the command line / in YAML: ``true``, ``0.5``, ``"/dlo"``, ``["a", "b"]``."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value)
    if isinstance(value, int):
        return str(value)
    if isinstance(value, (list, tuple)):
        if value and all(_is_number(v) for v in value):
            return "[" + ", ".join(repr(float(v)) for v in value) + "]"
        return "[" + ", ".join(json.dumps(str(v)) for v in value) + "]"
    return json.dumps(str(value))


def help_requested(argv: Sequence[str]) -> bool:
    """True when ``-h`` or ``--help`` comes before ``--ros-args`` (the node's own arguments)."""
    own = list(argv)[: list(argv).index("--ros-args")] if "--ros-args" in argv else list(argv)
    return "-h" in own or "--help" in own


def unexpected_arguments(argv: Sequence[str]) -> list[str]:
    """Arguments before ``--ros-args`` that are not ``-h``/``--help`` (a node takes none)."""
    own = list(argv)[: list(argv).index("--ros-args")] if "--ros-args" in argv else list(argv)
    return [a for a in own if a not in ("-h", "--help")]


def help_text(
    package: str,
    executable: str,
    parameters: Iterable[Param | Sequence[Any]],
    summary: str = "",
    exit_codes: str = "",
    params_file: str = "",
    width: int = 100,
) -> str:
    """The ``--help`` text of a node executable: usage line, what it does (the first paragraph of
    ``summary``), every parameter with type, default, range and description, exit codes.
    ``params_file``: where the installed parameters file is (default: its path under the prefix)."""
    params = as_params(parameters)
    lines = [
        "usage: " + USAGE.format(package=package, executable=executable),
        f"       (with a ROS 2 install: ros2 run {package} {executable} ...)",
        "",
    ]
    summary = inspect.cleandoc(summary or "").split("\n\n")[0]  # the first paragraph of the module docstring
    if summary:
        lines += [textwrap.fill(" ".join(summary.replace("``", "`").split()), width), ""]
    params_file = params_file or f"share/{package}/config/{executable}.yaml"
    lines.append(f"parameters (a params file with every default: {params_file}):")
    if not params:
        lines.append("  (none)")
    for p in params:
        head = f"  {p.name} ({p.type_name}, default {format_default(p.default)}"
        head += f", range {p.range_text})" if p.range_text else ")"
        lines.append(head)
        lines += textwrap.wrap(" ".join(p.description.split()), width, initial_indent=" " * 6, subsequent_indent=" " * 6)
    lines += ["", "Set one with '--ros-args -p NAME:=VALUE', several with '--ros-args --params-file FILE'."]
    if exit_codes:
        lines.append(f"Exit codes: {exit_codes}.")
    return "\n".join(lines) + "\n"


def params_yaml(parameters: Iterable[Param | Sequence[Any]], header: str = "") -> str:
    """A ROS 2 parameters file (``--ros-args --params-file``) setting every parameter to its default.

    ``/**`` applies it to any node name. Each parameter is preceded by its description, then its
    type and range, as comments. A list parameter whose default is empty is written commented out (a ROS 2
    parameters file cannot hold an empty array).
    """
    lines = [f"# {line}".rstrip() for line in header.strip().splitlines()] if header.strip() else []
    lines += ["/**:", "  ros__parameters:"]
    for p in as_params(parameters):
        for text in textwrap.wrap(" ".join(p.description.split()), 92):
            lines.append(f"    # {text}")
        lines.append(f"    # type {p.type_name}" + (f", range {p.range_text}" if p.range_text else ""))
        entry = f"{p.name}: {format_default(p.default)}"
        if isinstance(p.default, (list, tuple)) and not p.default:
            lines.append(f"    # {entry}  (empty list: the default; a params file cannot hold an empty array)")
        else:
            lines.append(f"    {entry}")
    return "\n".join(lines) + "\n"


def markdown_table(parameters: Iterable[Param | Sequence[Any]]) -> str:
    """The parameters as a Markdown table: name | type | default | range | description."""

    def cell(text: str) -> str:
        return " ".join(str(text).split()).replace("|", "\\|")

    rows = ["| name | type | default | range | description |", "|---|---|---|---|---|"]
    for p in as_params(parameters):
        rng = f"`{cell(p.range_text)}`" if p.range_text else ""
        rows.append(f"| `{p.name}` | {p.type_name} | `{cell(format_default(p.default))}` | {rng} | {cell(p.description)} |")
    return "\n".join(rows) + "\n"
