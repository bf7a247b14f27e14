"""Every node executable explains itself: ``--help``/``-h`` lists its declared parameters and starts
nothing; its parameters file (``config/<executable>.yaml``) is generated from the same declarations
and works with ``--ros-args --params-file``."""

from __future__ import annotations

import importlib
import importlib.util
import os
import pathlib
import re
import subprocess
import sys
import time

import pytest
from dlo_common.params import Param, as_params, check_value, help_requested, markdown_table, params_yaml

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROS2RUN = str(ROOT / "scripts" / "ros2run")
_spec = importlib.util.spec_from_file_location("gen_node_configs", ROOT / "tools" / "gen_node_configs.py")
gen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gen)
NODES = gen.node_executables()
EXPECTED = {
    "sim_node",
    "tactile_node",
    "vision_node",
    "policy_node",
    "recorder_node",
    "playback_node",
    "mock_driver_node",
    "foxglove_bridge",
}


def test_every_node_executable_is_found():
    assert {exe for _, exe, _ in NODES} >= EXPECTED


@pytest.mark.parametrize("package,executable,module", NODES, ids=[exe for _, exe, _ in NODES])
def test_committed_params_file_equals_the_declarations(package, executable, module):
    path = gen.config_path(package, executable)
    assert path.exists(), f"{path} missing: run python tools/gen_node_configs.py"
    assert path.read_text() == gen.render(package, executable, module), (
        f"{path} differs from {module}.PARAMETERS: run python tools/gen_node_configs.py"
    )
    installed = ROOT / "ros_ws" / "install" / package / "share" / package / "config" / f"{executable}.yaml"
    assert installed.read_text() == path.read_text(), f"{installed} is stale: run scripts/setup.sh"


def test_gen_check_reports_a_drifted_file(tmp_path, monkeypatch, capsys):
    """--check fails when a declaration changed after the file was written (here: a default)."""
    package, executable, module = next(n for n in NODES if n[1] == "tactile_node")
    monkeypatch.setattr(gen, "config_path", lambda p, e, src=None: tmp_path / f"{e}.yaml")
    monkeypatch.setattr(gen, "sac_defaults_path", lambda src=None: tmp_path / "sac_default.yaml")
    assert gen.main([]) == 0 and gen.main(["--check"]) == 0
    stale = tmp_path / f"{executable}.yaml"
    stale.write_text(stale.read_text().replace('tactile_noise: "none"', 'tactile_noise: "full"'))
    assert gen.main(["--check"]) == 1
    assert f"{executable}.yaml differs from the declarations" in capsys.readouterr().err


@pytest.mark.parametrize("flag", ["--help", "-h"])
@pytest.mark.parametrize("package,executable,module", NODES, ids=[exe for _, exe, _ in NODES])
def test_help_lists_every_parameter_and_starts_nothing(package, executable, module, flag, tmp_path):
    result = subprocess.run([ROS2RUN, package, executable, flag], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    out = result.stdout
    assert out.startswith(f"usage: ros2run {package} {executable} [--ros-args"), out[:200]
    parameters = importlib.import_module(module).PARAMETERS
    for param in as_params(parameters):
        assert f"\n  {param.name} ({param.type_name}, default " in out, param.name
        if param.range_text:
            assert f"range {param.range_text})" in out, param.name
    listed = re.search(r"a params file with every default: (\S+)\):", out).group(1)  # the installed one
    assert listed.endswith(f"share/{package}/config/{executable}.yaml") and pathlib.Path(listed).is_file(), listed
    assert "[Taichi]" not in out + result.stderr  # no banner before the text
    assert result.stderr == ""  # no node started: no log lines
    assert list(tmp_path.iterdir()) == []  # no bag, no summary, nothing


def test_a_stray_argument_is_a_one_line_error(tmp_path):
    result = subprocess.run([ROS2RUN, "dlo_sim", "sim_node", "bogus"], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        "sim_node: unexpected argument 'bogus' (parameters go after --ros-args: -p NAME:=VALUE; see 'sim_node --help')"
    ]
    assert "[Taichi]" not in result.stdout and list(tmp_path.iterdir()) == []


def test_a_bad_value_in_a_params_file_is_a_one_line_error(tmp_path):
    """The shipped file, with one value out of its range: the node reads the file and refuses."""
    params = tmp_path / "sim.yaml"
    params.write_text(gen.config_path("dlo_sim", "sim_node").read_text().replace("horizon: 150", "horizon: 0"))
    result = subprocess.run(
        [ROS2RUN, "dlo_sim", "sim_node", "--ros-args", "--params-file", str(params)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2, result.stdout + result.stderr
    assert "[sim_node] bad parameter: parameter 'horizon': must be >= 1, got 0" in result.stderr
    assert "Traceback" not in result.stderr and "[Taichi]" not in result.stdout


def test_params_file_values_take_effect(tmp_path, own_groups):
    """tactile_node started with its shipped file, two values changed (the noise to a pair, as YAML writes
    it): its parameter service reports them."""
    import rclpy
    from rcl_interfaces.srv import GetParameters

    params = tmp_path / "tactile.yaml"
    text = gen.config_path("dlo_perception", "tactile_node").read_text()
    assert 'tactile_noise: "none"' in text and "seed: 0" in text
    params.write_text(text.replace('tactile_noise: "none"', "tactile_noise: [0.1, 0.001]").replace("seed: 0", "seed: 7"))
    node = subprocess.Popen(
        [ROS2RUN, "dlo_perception", "tactile_node", "--ros-args", "--params-file", str(params)],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    own_groups(node.pid)
    rclpy.init()
    try:
        client_node = rclpy.create_node("params_file_probe")
        client = client_node.create_client(GetParameters, "/tactile_node/get_parameters")
        deadline = time.monotonic() + 60
        while not client.wait_for_service(timeout_sec=0.5):
            assert node.poll() is None, node.stdout.read()
            assert time.monotonic() < deadline, "tactile_node's parameter service did not appear"
        future = client.call_async(GetParameters.Request(names=["tactile_noise", "seed"]))
        rclpy.spin_until_future_complete(client_node, future, timeout_sec=30)
        values = future.result().values
        assert [list(values[0].double_array_value), values[1].integer_value] == [[0.1, 0.001], 7]
        client_node.destroy_node()
    finally:
        rclpy.try_shutdown()


def test_param_ranges_and_rendering():
    """The one declaration gives the check, the help line, the YAML entry and the Markdown row."""
    port = Param("port", 8765, "TCP port [-]", at_least=0, at_most=65535)
    rate = Param("rate", 1.0, "rate factor", above=0.0)
    mode = Param("mode", "a", "clock mode", choices=("a", "b"))
    topics = ("topics", [], "topics to play")
    assert check_value(port, 0) == 0 and check_value(rate, 2) == 2.0 and check_value(mode, "b") == "b"
    for param, value, message in [
        (port, 70000, "must be in 0..65535, got 70000"),
        (rate, 0.0, "must be > 0"),
        (mode, "c", "expected one of ('a', 'b'), got 'c'"),
        (port, "x", "expected an integer"),
        (rate, float("nan"), "must be a number"),
    ]:
        with pytest.raises(ValueError, match=re.escape(f"parameter '{param.name}': {message}")):
            check_value(param, value)
    yaml = params_yaml([port, rate, mode, topics])
    assert yaml.startswith("/**:\n  ros__parameters:\n")
    assert "    # TCP port [-]\n    # type integer, range 0..65535\n    port: 8765\n" in yaml
    assert "    rate: 1.0\n" in yaml and '    mode: "a"\n' in yaml
    assert "    # topics: []" in yaml  # an empty list cannot be written in a params file
    table = markdown_table([port, mode]).splitlines()
    assert table[0] == "| name | type | default | range | description |"
    assert table[2] == "| `port` | integer | `8765` | `0..65535` | TCP port [-] |"
    assert table[3] == '| `mode` | string | `"a"` | `a \\| b` | clock mode |'
    assert help_requested(["-h"]) and help_requested(["--help", "--ros-args"])
    assert not help_requested(["--ros-args", "-p", "x:=1", "--help"])  # after --ros-args: ROS's


def test_banner_does_not_precede_one_line_errors(tmp_path):
    """dlo-train / dlo-evaluate import Taichi before they check their arguments: no banner first."""
    env = {**os.environ, "PATH": f"{ROOT / 'ros_ws' / 'install' / 'dlo_policy' / 'lib' / 'dlo_policy'}:{os.environ['PATH']}"}
    train = subprocess.run(
        ["dlo-train", "--out", str(tmp_path / "run"), "sac.bogus=1"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert train.returncode == 2 and train.stdout == "", train.stdout
    assert train.stderr.startswith("dlo-train: error: unknown key 'sac.bogus'; did you mean"), train.stderr
    evaluate = subprocess.run(
        ["dlo-evaluate", "--checkpoint", str(tmp_path / "missing.pt")],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    assert evaluate.returncode == 2 and evaluate.stdout == ""
    assert evaluate.stderr.strip().splitlines() == [f"dlo-evaluate: error: checkpoint {tmp_path / 'missing.pt'} not found"]
    banner = subprocess.run(
        [
            sys.executable,
            "-c",
            "from dlo_interface.simulator import simulator_factory; simulator_factory(); import dlo_perception.vision",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert banner.returncode == 0 and "[Taichi]" not in banner.stdout + banner.stderr
