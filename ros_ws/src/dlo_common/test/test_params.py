"""dlo_common.params: a declared parameter's type, range and choices are checked, and rendered, exactly."""

import re

import pytest

import yaml

from dlo_common.params import (Param, UnknownParameterError, as_param, check_value, coerce, example, format_default,
                               help_requested, help_text, unexpected_arguments, unknown_parameter)

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


@pytest.mark.parametrize("param,value,expected", [
    (FLAG, True, True), (FLAG, False, False),
    (INT, 3, 3), (ABOVE, 2, 2.0), (ABOVE, 0.5, 0.5),
    (TEXT, "b", "b"), (TEXT, 5, "5"), (TEXT, 1.5, "1.5"),
    (TOPICS, "/x, /y,", ["/x", "/y"]), (TOPICS, ["/x"], ["/x"]), (TOPICS, ("/x", "/y"), ["/x", "/y"]),
])
def test_values_of_the_declared_type_are_read(param, value, expected):
    got = coerce(param, value)
    assert got == expected and type(got) is type(expected)


@pytest.mark.parametrize("param,value,expected", [
    (FLAG, 1, "a bool"), (FLAG, "true", "a bool"),
    (INT, True, "an integer"), (INT, 1.5, "an integer"), (INT, "3", "an integer"),
    (ABOVE, True, "a number"), (ABOVE, "fast", "a number"),
    (TEXT, True, "a string"), (TEXT, ["a"], "a string"),
    (TOPICS, 3, "a list of strings"), (TOPICS, ["/a", 3], "a list of strings"), (TOPICS, [1, 2], "a list of strings"),
])
def test_values_of_another_type_are_one_line_errors(param, value, expected):
    with pytest.raises(ValueError, match=re.escape(f"parameter '{param.name}': expected {expected}")):
        coerce(param, value)


@pytest.mark.parametrize("param,good,bad,message", [
    (INT, [1, 5], [0, -1], "must be >= 1"),
    (BOUNDED, [0, 20, 7], [-1, 21], "must be in 0..20"),
    (UPPER, [2.0, -5.0], [2.5], "must be <= 2"),
    (ABOVE, [1e-9, 3.0], [0.0, -1.0, float("nan")], ""),
    (MODE, ["x", "y"], ["z", "X"], "expected one of ('x', 'y')"),
])
def test_ranges_and_choices(param, good, bad, message):
    for value in good:
        assert check_value(param, value) == value
    for value in bad:
        with pytest.raises(ValueError, match=re.escape(f"parameter '{param.name}': {message}")):
            check_value(param, value)


def test_range_text():
    assert [p.range_text for p in (INT, BOUNDED, UPPER, ABOVE, MODE, FLAG)] == [
        ">= 1", "0..20", "<= 2", "> 0", "x | y", ""]
    assert Param("q", 1.0, "", at_least=0.5, above=0.0).range_text == ">= 0.5, > 0"
    assert Param("q", 1.0, "", above=0.25, at_most=3.0).range_text == "> 0.25, <= 3"


def test_type_names_and_defaults():
    assert [p.type_name for p in (FLAG, INT, ABOVE, TEXT, TOPICS)] == ["bool", "integer", "double", "string",
                                                                         "string_array"]
    assert [format_default(p.default) for p in (FLAG, INT, ABOVE, TEXT, TOPICS)] == ["false", "1", "1.0", '"a"',
                                                                                    '["/a"]']
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
    assert "\n  mode (string, default \"x\", range x | y)\n      mode\n" in text
    assert text.endswith("Exit codes: 0 ok.\n")


def test_a_list_of_numbers_is_a_double_array_of_fixed_length():
    assert POSITION.type_name == "double_array" and POSITION.range_text == "length 3"
    assert format_default(POSITION.default) == "[0.0, 0.0, 1.0]"
    for value in ([0.5, 0.0, 2.0], [1, 0, 2], (1, 0, 2.0), "0.5, 0, 2", ["0.5", "0", "2"]):
        got = check_value(POSITION, value)
        assert type(got) is list and all(type(v) is float for v in got) and len(got) == 3, value
    for value, shown in [([0.0, 1.0], "[0.0, 1.0] (double_array)"), ("up", "'up' (string)"),
                         ([True, 0.0, 1.0], "[True, 0.0, 1.0] (array)"), (1.0, "1.0 (double)")]:
        with pytest.raises(ValueError, match=re.escape(
                f"parameter 'position': expected 3 numbers, e.g. -p position:=[0.0,0.0,1.0], got {shown}")):
            check_value(POSITION, value)
    with pytest.raises(ValueError, match="expected finite numbers"):
        check_value(POSITION, [0.0, float("nan"), 1.0])


@pytest.mark.parametrize("param,shown", [
    (FLAG, "-p flag:=true"), (INT, "-p n:=1"), (ABOVE, "-p rate:=1.0"), (TEXT, "-p name:=a"),
    (TOPICS, "-p topics:=/a"), (EMPTY_TOPICS, "-p extra:=/dlo/a,/dlo/b"), (MODE, "-p mode:=x"),
    (POSITION, "-p position:=[0.0,0.0,1.0]"), (Param("path", "", "a file"), "-p path:=text"),
])
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
    assert str(unknown_parameter("horizn", ["seed", "horizon"])) == \
        "unknown parameter 'horizn'; did you mean 'horizon'?"
    assert str(unknown_parameter("x", [])) == "unknown parameter 'x'"
