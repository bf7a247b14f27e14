"""dlo_common.params: a declared parameter's type, range and choices are checked, and rendered, exactly."""

import re

import pytest
import yaml
from dlo_common.params import (
    Param,
    ParameterError,
    UnknownParameterError,
    YamlProblem,
    as_param,
    check_value,
    coerce,
    example,
    format_default,
    help_requested,
    help_text,
    markdown_table,
    params_yaml,
    unexpected_arguments,
    unknown_parameter,
    yaml_problem,
)

INT = Param("n", 1, "count", at_least=1)
BOUNDED = Param("port", 10, "port", at_least=0, at_most=20)
UPPER = Param("k", 1.0, "at most 2", at_most=2.0)
ABOVE = Param("rate", 1.0, "rate", above=0.0)
FLAG = Param("flag", False, "flag")
TEXT = Param("name", "a", "name")
TOPICS = Param("topics", ["/a"], "topics")
MODE = Param("mode", "x", "mode", choices=("x", "y"))
POSITION = Param("position", (0.0, 0.0, 1.0), "x, y, z [m]", length=3)
EMPTY_TOPICS = Param("extra", [], "more topics")


@pytest.mark.parametrize(
    "param,value,expected",
    [
        (FLAG, True, True),
        (FLAG, False, False),
        (INT, 3, 3),
        (ABOVE, 2, 2.0),
        (ABOVE, 0.5, 0.5),
        (TEXT, "b", "b"),
        (TEXT, 5, "5"),
        (TEXT, 1.5, "1.5"),
        (TOPICS, "/x, /y,", ["/x", "/y"]),
        (TOPICS, ["/x"], ["/x"]),
        (TOPICS, ("/x", "/y"), ["/x", "/y"]),
    ],
)
def test_values_of_the_declared_type_are_read(param, value, expected):
    got = coerce(param, value)
    assert got == expected and type(got) is type(expected)


@pytest.mark.parametrize(
    "param,value,expected",
    [
        (FLAG, 1, "a bool"),
        (FLAG, "true", "a bool"),
        (INT, True, "an integer"),
        (INT, 1.5, "an integer"),
        (INT, "3", "an integer"),
        (ABOVE, True, "a number"),
        (ABOVE, "fast", "a number"),
        (TEXT, True, "a string"),
        (TEXT, ["a"], "a string"),
        (TOPICS, 3, "a list of strings"),
        (TOPICS, ["/a", 3], "a list of strings"),
        (TOPICS, [1, 2], "a list of strings"),
    ],
)
def test_values_of_another_type_are_one_line_errors(param, value, expected):
    with pytest.raises(ValueError, match=re.escape(f"parameter '{param.name}': expected {expected}")):
        coerce(param, value)


@pytest.mark.parametrize(
    "param,good,bad,message",
    [
        (INT, [1, 5], [0, -1], "must be >= 1"),
        (BOUNDED, [0, 20, 7], [-1, 21], "must be in 0..20"),
        (UPPER, [2.0, -5.0], [2.5], "must be <= 2"),
        (ABOVE, [1e-9, 3.0], [0.0, -1.0, float("nan")], ""),
        (MODE, ["x", "y"], ["z", "X"], "expected one of ('x', 'y')"),
    ],
)
def test_ranges_and_choices(param, good, bad, message):
    for value in good:
        assert check_value(param, value) == value
    for value in bad:
        with pytest.raises(ValueError, match=re.escape(f"parameter '{param.name}': {message}")):
            check_value(param, value)


def test_range_text():
    assert [p.range_text for p in (INT, BOUNDED, UPPER, ABOVE, MODE, FLAG)] == [">= 1", "0..20", "<= 2", "> 0", "x | y", ""]
    assert Param("q", 1.0, "", at_least=0.5, above=0.0).range_text == ">= 0.5, > 0"
    assert Param("q", 1.0, "", above=0.25, at_most=3.0).range_text == "> 0.25, <= 3"


def test_type_names_and_defaults():
    assert [p.type_name for p in (FLAG, INT, ABOVE, TEXT, TOPICS)] == ["bool", "integer", "double", "string", "string_array"]
    assert [format_default(p.default) for p in (FLAG, INT, ABOVE, TEXT, TOPICS)] == ["false", "1", "1.0", '"a"', '["/a"]']
    assert as_param(("x", 2, "two")) == Param("x", 2, "two") and as_param(INT) is INT


def test_node_arguments_before_ros_args():
    assert help_requested(["--help"]) and help_requested(["-h", "--ros-args", "-p", "a:=1"])
    assert not help_requested([]) and not help_requested(["--ros-args", "--help"])
    assert unexpected_arguments(["-h", "x", "--ros-args", "-p", "a:=1"]) == ["x"]
    assert unexpected_arguments(["--ros-args", "-p", "a:=1"]) == [] and unexpected_arguments(["--help"]) == []
    assert unexpected_arguments(["y"]) == ["y"]


def test_help_text_lists_each_parameter_once():
    text = help_text("pkg", "exe", [INT, MODE], "exe: does one thing.\n\nDetails that stay out.", "0 ok")
    assert text.splitlines()[0] == ("usage: ros2run pkg exe [--ros-args (-p NAME:=VALUE | --params-file FILE) ...]")
    assert "exe: does one thing." in text and "Details" not in text
    assert "\n  n (integer, default 1, range >= 1)\n      count\n" in text
    assert '\n  mode (string, default "x", range x | y)\n      mode\n' in text
    assert text.endswith("Exit codes: 0 ok.\n")


def test_a_list_of_numbers_is_a_double_array_of_fixed_length():
    assert POSITION.type_name == "double_array" and POSITION.range_text == "length 3"
    assert format_default(POSITION.default) == "[0.0, 0.0, 1.0]"
    for value in ([0.5, 0.0, 2.0], [1, 0, 2], (1, 0, 2.0), "0.5, 0, 2", ["0.5", "0", "2"]):
        got = check_value(POSITION, value)
        assert type(got) is list and all(type(v) is float for v in got) and len(got) == 3, value
    for value, shown in [
        ([0.0, 1.0], "[0.0, 1.0] (double_array)"),
        ("up", "'up' (string)"),
        ([True, 0.0, 1.0], "[True, 0.0, 1.0] (array)"),
        (1.0, "1.0 (double)"),
    ]:
        with pytest.raises(
            ValueError, match=re.escape(f"parameter 'position': expected 3 numbers, e.g. -p position:=[0.0,0.0,1.0], got {shown}")
        ):
            check_value(POSITION, value)
    with pytest.raises(ValueError, match="expected finite numbers"):
        check_value(POSITION, [0.0, float("nan"), 1.0])


@pytest.mark.parametrize(
    "param,shown",
    [
        (FLAG, "-p flag:=true"),
        (INT, "-p n:=1"),
        (ABOVE, "-p rate:=1.0"),
        (TEXT, "-p name:=a"),
        (TOPICS, "-p topics:=/a"),
        (EMPTY_TOPICS, "-p extra:=/dlo/a,/dlo/b"),
        (MODE, "-p mode:=x"),
        (POSITION, "-p position:=[0.0,0.0,1.0]"),
        (Param("path", "", "a file"), "-p path:=text"),
        (Param("without", "", "test-time ablation: zero these modalities, e.g. 'T' or 'V'"), "-p without:=T"),
    ],
)
def test_each_type_error_shows_an_example_that_fits_the_parameter(param, shown):
    assert example(param) == shown
    check_value(param, yaml.safe_load(shown.split(":=", 1)[1]))  # rcl reads a -p value as YAML
    wrong = {"bool": 1, "integer": "x", "double": "x", "string": [1], "string_array": 3, "double_array": "x"}
    with pytest.raises(ValueError, match=re.escape(f", e.g. {shown}, got ")):
        coerce(param, wrong[param.type_name])


def test_an_unknown_name_suggests_the_closest_declared_one():
    error = unknown_parameter("sead", ["mode", "seed", "horizon"])
    assert isinstance(error, UnknownParameterError) and isinstance(error, ValueError)
    assert str(error) == "unknown parameter 'sead'; did you mean 'seed'?"
    assert str(unknown_parameter("horizn", ["seed", "horizon"])) == "unknown parameter 'horizn'; did you mean 'horizon'?"
    assert str(unknown_parameter("x", [])) == "unknown parameter 'x'"


def test_did_you_mean_names_the_closest_known_name_for_any_unknown_one():
    """params.did_you_mean: the end of every "unknown name" message (node parameters, dlo-train's config keys)."""
    from dlo_common.params import did_you_mean

    assert did_you_mean("sac.batch_sise", ["sac.batch_size", "train.eval_every"]) == "; did you mean 'sac.batch_size'?"
    assert did_you_mean("x", []) == ""


def level(value):
    """A check as dlo_perception.tactile.noise_setting is one: a name or a pair of numbers."""
    if value in ("low", "high"):
        return value
    low, high = (float(v) for v in value)  # TypeError / ValueError for anything else
    if low < 0:
        raise ValueError(f"expected low, high or a pair >= 0, got {value!r}")
    return low, high


LEVEL = Param(
    "level",
    "low",
    "how loud",
    check=level,
    types="string or double_array",
    accepts="low | high | [a,b]",
    choices=("never",),
    at_least=5.0,
)  # a check replaces choices and bounds


def test_a_parameter_with_its_own_check():
    assert LEVEL.type_name == "string or double_array" and LEVEL.range_text == "low | high | [a,b]"
    assert check_value(LEVEL, "high") == "high" and check_value(LEVEL, [1, 2]) == (1.0, 2.0)
    for value, message in [
        ("loud", "could not convert string to float: 'l'"),
        (3, "'int' object is not iterable"),
        ([-1.0, 2.0], "expected low, high or a pair >= 0, got [-1.0, 2.0]"),
    ]:
        with pytest.raises(ParameterError) as error:
            check_value(LEVEL, value)
        assert str(error.value) == f"parameter 'level': {message}", value
    assert '\n  level (string or double_array, default "low", range low | high | [a,b])\n' in help_text("p", "e", [LEVEL])
    assert '    # type string or double_array, range low | high | [a,b]\n    level: "low"\n' in params_yaml([LEVEL])
    assert (
        markdown_table([LEVEL]).splitlines()[2]
        == '| `level` | string or double_array | `"low"` | `low \\| high \\| [a,b]` | how loud |'
    )


def _problem(text: str):
    with pytest.raises(yaml.YAMLError) as raised:
        list(yaml.safe_load_all(text))
    return yaml_problem(raised.value, text)


@pytest.mark.parametrize(
    "text, line, column, problem",
    [
        ("a: 1\nb: [1\nc: 2\n", 3, 2, "expected ',' or ']', but got ':'"),  # a parser error: its mark
        ("a: b: c\n", 1, 5, "mapping values are not allowed here"),  # a scanner error
        ("a: 1\nb: x\x07y\n", 2, 5, "unacceptable character #x0007: special characters are not allowed"),  # reader
        ("\x07", 1, 1, "unacceptable character #x0007: special characters are not allowed"),  # the first character
        ("a: 1\n\nb: \x1b\n", 3, 4, "unacceptable character #x001b: special characters are not allowed"),
        ("\nb: \x07\n", 2, 4, "unacceptable character #x0007: special characters are not allowed"),  # text[0] a break
    ],
)
def test_a_yaml_problem_names_its_line_and_column_in_one_line(text, line, column, problem):
    """Every kind of PyYAML error, a reader error (a character YAML does not allow) too, gives the 1-based
    line and column of the text and a one-line reason without PyYAML's 'in "<unicode string>"' part."""
    assert _problem(text) == YamlProblem(line, column, problem)


def test_a_yaml_error_without_a_place_has_none():
    assert yaml_problem(yaml.YAMLError("broken\n  somewhere"), "x") == YamlProblem(None, None, "broken somewhere")
