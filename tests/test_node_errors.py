"""A user's mistake in a node's parameters is one line on stderr and exit code 2, never a traceback
(issue 20), for every node: they share one error path (dlo_common.node_main.handle_help for the
command line and params files before ``rclpy.init``, dlo_common.node_util.declare_parameters for the
names and values a node receives).

- a params file that is missing, not YAML or laid out wrongly: the file and the problem;
- a malformed ``-p`` or an unknown ROS flag;
- a parameter the node does not have (``-p`` or params file): ``unknown parameter 'x'; did you mean 'y'?``;
- a value of the wrong type or shape: the expected type with an example that fits that parameter.

Each case runs the real executable through scripts/ros2run.
"""

from __future__ import annotations

import importlib
import importlib.util
import pathlib
import subprocess

import pytest
import yaml
from dlo_common.params import as_params, check_value

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROS2RUN = str(ROOT / "scripts" / "ros2run")
_spec = importlib.util.spec_from_file_location("gen_node_configs", ROOT / "tools" / "gen_node_configs.py")
gen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gen)
NODES = gen.node_executables()
LAYOUT = "expected '/**:' (or the node's name), then '  ros__parameters:', then '    NAME: VALUE'"


def run(package: str, executable: str, *ros_args: str, cwd: pathlib.Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [ROS2RUN, package, executable, "--ros-args", *ros_args], cwd=cwd, capture_output=True, text=True, timeout=300
    )


def one_line(result: subprocess.CompletedProcess) -> str:
    """The single stderr line of a refused start (exit 2, nothing on stdout, no traceback)."""
    assert "Traceback" not in result.stdout + result.stderr, result.stderr
    assert result.returncode == 2, result.stdout + result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert "[Taichi]" not in result.stdout
    return lines[0]


def first_param(module: str):
    return as_params(importlib.import_module(module).PARAMETERS)[0]


@pytest.mark.parametrize("package,executable,module", NODES, ids=[exe for _, exe, _ in NODES])
def test_a_missing_params_file_is_one_line_for_every_node(package, executable, module, tmp_path):
    missing = tmp_path / "missing.yaml"
    result = run(package, executable, "--params-file", str(missing), cwd=tmp_path)
    assert one_line(result) == f"{executable}: params file {missing}: not found"
    assert list(tmp_path.iterdir()) == []  # nothing started, nothing written


@pytest.mark.parametrize(
    "text,problem",
    [
        (
            "/**:\n  ros__parameters:\n    horizon: [1,\n",
            "YAML syntax error at line 4: expected the node content, but found '<stream end>'",
        ),
        (
            "/**:\n  ros__parameters:\n\thorizon: 3\n",
            "YAML syntax error at line 3: found character '\\t' that cannot start any token",
        ),
        ("horizon: 3\n", f"wrong layout at line 1 (a value outside 'ros__parameters:'); {LAYOUT}"),
        ("sim_node:\n  horizon: 3\n", f"wrong layout at line 2 (a value outside 'ros__parameters:'); {LAYOUT}"),
        (
            "ros__parameters:\n  horizon: 3\n",
            f"wrong layout at line 1 ('ros__parameters:' without a node name above it); {LAYOUT}",
        ),
        ("- horizon: 3\n", f"wrong layout (the file holds a list); {LAYOUT}"),
        ("horizon = 3\n", f"wrong layout (the file holds a single value); {LAYOUT}"),
        (
            "/**:\n  ros__parameters:\n",
            "wrong layout ('/**: ros__parameters:' holds no parameters: add '    NAME: VALUE' under it or leave the section out)",
        ),
        (
            '/**:\n  ros__parameters:\n    horizon: [1, "a"]\n',
            "rcl cannot read it at line 3: Sequence should be of same type. Value type 'string' do not belong",
        ),
    ],
    ids=[
        "unclosed-list",
        "tab",
        "no-section",
        "no-ros__parameters",
        "no-node-name",
        "a-list",
        "plain-text",
        "empty-section",
        "mixed-list",
    ],
)
def test_a_malformed_params_file_names_the_file_and_the_problem(text, problem, tmp_path):
    params = tmp_path / "sim.yaml"
    params.write_text(text)
    result = run("dlo_sim", "sim_node", "--params-file", str(params), cwd=tmp_path)
    assert one_line(result) == f"sim_node: params file {params}: {problem}"


def test_a_directory_as_params_file(tmp_path):
    assert (
        one_line(run("dlo_sim", "sim_node", "--params-file", str(tmp_path), cwd=tmp_path))
        == f"sim_node: params file {tmp_path}: is a directory"
    )


@pytest.mark.parametrize(
    "ros_args,line",
    [
        (
            ["-p", "horizon"],
            "sim_node: cannot read '-p horizon': expected -p NAME:=VALUE (VALUE in YAML, e.g. 3, 0.5, true, text, [1.0,2.0])",
        ),
        (
            ["--bogus"],
            "sim_node: unknown ROS argument --bogus after --ros-args (there: -p NAME:=VALUE, "
            "--params-file FILE, -r FROM:=TO, --log-level LEVEL)",
        ),
    ],
)
def test_malformed_ros_arguments_are_one_line(ros_args, line, tmp_path):
    assert one_line(run("dlo_sim", "sim_node", *ros_args, cwd=tmp_path)) == line


@pytest.mark.parametrize("package,executable,module", NODES, ids=[exe for _, exe, _ in NODES])
def test_a_misspelt_parameter_names_the_closest_one_for_every_node(package, executable, module, tmp_path):
    name = first_param(module).name
    result = run(package, executable, "-p", f"{name[:-1]}:=1", cwd=tmp_path)
    message = f"unknown parameter '{name[:-1]}'; did you mean '{name}'?"
    assert one_line(result) in (
        f"[{executable}] {message}",  # run_node: the node was not built, so no node name
        f"{executable}: error: {message}",
    )  # recorder_node, playback_node: their own main()


def test_an_unknown_name_in_a_params_file_and_a_far_one_on_the_command_line(tmp_path):
    params = tmp_path / "sim.yaml"
    params.write_text(gen.config_path("dlo_sim", "sim_node").read_text().replace("horizon: 150", "horizn: 150"))
    assert (
        one_line(run("dlo_sim", "sim_node", "--params-file", str(params), cwd=tmp_path))
        == "[sim_node] unknown parameter 'horizn'; did you mean 'horizon'?"
    )
    assert (
        one_line(run("dlo_perception", "tactile_node", "-p", "nosuch:=1", cwd=tmp_path))
        == "[tactile_node] unknown parameter 'nosuch'; did you mean 'tactile_noise'?"
    )  # never an old name


@pytest.mark.parametrize(
    "package,executable,setting,line",
    [
        (
            "dlo_perception",
            "vision_node",
            "camera_position:=[0.0,1.0]",
            "[vision_node] bad parameter: parameter 'camera_position': expected 3 numbers, e.g. "
            "-p camera_position:=[0.0,0.0,1.0], got [0.0, 1.0] (double_array)",
        ),
        (
            "dlo_perception",
            "vision_node",
            "camera_position:=up",
            "[vision_node] bad parameter: parameter 'camera_position': expected 3 numbers, e.g. "
            "-p camera_position:=[0.0,0.0,1.0], got 'up' (string)",
        ),
        (
            "dlo_sim",
            "sim_node",
            "horizon:=[150]",
            "[sim_node] bad parameter: parameter 'horizon': expected an integer, e.g. -p horizon:=150, got [150] (integer_array)",
        ),
        (
            "dlo_sim",
            "sim_node",
            "publish_markers:=1",
            "[sim_node] bad parameter: parameter 'publish_markers': expected a bool (true/false), e.g. "
            "-p publish_markers:=true, got 1 (integer)",
        ),
        (
            "dlo_viz",
            "foxglove_bridge",
            "topics:=[1,2]",
            "[foxglove_bridge] bad parameter: parameter 'topics': expected a list of strings, e.g. -p topics:=/dlo,/clock, "
            "got [1, 2] (integer_array)",
        ),
    ],
)
def test_a_wrong_type_or_shape_gives_an_example_of_that_parameter(package, executable, setting, line, tmp_path):
    assert one_line(run(package, executable, "-p", setting, cwd=tmp_path)) == line
    name, value = line.split(", e.g. -p ")[1].split(", got ")[0].split(":=", 1)  # the example fits:
    module = next(m for _, e, m in NODES if e == executable)
    param = next(p for p in as_params(importlib.import_module(module).PARAMETERS) if p.name == name)
    check_value(param, yaml.safe_load(value))  # rcl reads a -p value as YAML


def test_camera_position_takes_three_numbers_in_each_ros_form():
    """[0.0,0.0,1.0] (double array), [0,0,1] (integer array), '0,0,1' (string) and a string array all
    give the same three numbers; a name the node lacks, given to the constructor, is refused too."""
    import rclpy
    from dlo_common.node_util import UnknownParameterError, declare_parameters
    from dlo_perception.vision_node import PARAMETERS
    from rclpy.parameter import Parameter

    context = rclpy.Context()
    rclpy.init(context=context, domain_id=231)
    try:
        for value in ([0.5, 0.0, 2.0], [1, 0, 2], "0.5, 0, 2", ["0.5", "0", "2"]):
            node = rclpy.create_node(
                "camera_probe", context=context, parameter_overrides=[Parameter("camera_position", value=value)]
            )
            try:
                got = declare_parameters(node, PARAMETERS)["camera_position"]
                assert got == [float(v) for v in (value.split(",") if isinstance(value, str) else value)], value
            finally:
                node.destroy_node()
        node = rclpy.create_node(
            "camera_probe", context=context, parameter_overrides=[Parameter("camera_positon", value=[0.0, 0.0, 1.0])]
        )
        try:
            with pytest.raises(
                UnknownParameterError, match="^unknown parameter 'camera_positon'; did you mean 'camera_position'\\?$"
            ):
                declare_parameters(node, PARAMETERS)
        finally:
            node.destroy_node()
    finally:
        rclpy.shutdown(context=context)


def test_a_bad_without_names_the_parameter_and_its_values(tmp_path):
    """policy_node's test-time ablation: the message is about 'without', not about 'modalities'."""
    assert one_line(run("dlo_policy", "policy_node", "-p", "without:=X", cwd=tmp_path)) == (
        "[policy_node] bad parameter: parameter 'without': expected '' (none) or the modalities to zero: K, T, V "
        "or several joined by '+', e.g. T or T+V, got 'X'"
    )
    modalities = run("dlo_policy", "policy_node", "-p", "policy:=random", "-p", "modalities:=X+K", cwd=tmp_path)
    assert one_line(modalities) == (
        "[policy_node] bad parameter: parameter 'modalities': expected All or a '+'-joined subset of K, T, V, e.g. V+K, got 'X+K'"
    )
