"""One name and one reading for the tactile noise (issue 18): ``tactile_noise`` takes the same values
(none, partial, full or a pair sigma_theta [rad], sigma_y [m]) as the gym env's option, the tactile
node's parameter and ``launch_graph.sh --tactile-noise``, all read by
``dlo_perception.tactile.noise_setting``; a bad value is one line and exit 2 (the launcher's before
anything starts); the names the node's noise had before (``noise``, ``sigma_theta``, ``sigma_y``; never
released) are unknown parameters like any other. (The launcher's custom pair reaching the node and the
run header: tests/test_launch_feedback.py.)"""

from __future__ import annotations

import os
import pathlib
import signal
import subprocess
import threading

import pytest
import yaml
from dlo_bringup.graph import graph_nodes
from dlo_bringup.options import UsageError, parse_args, resolve
from dlo_common.params import ParameterError, check_value
from dlo_perception.tactile import NOISE_FORMS, noise_sigma
from dlo_perception.tactile_node import PARAMETERS
from dlo_policy.env import check_options

ROOT = pathlib.Path(__file__).resolve().parents[1]
ROS2RUN = str(ROOT / "scripts" / "ros2run")
PARAM = next(p for p in PARAMETERS if p.name == "tactile_noise")

# as given on the launcher's command line | its -p / YAML form (what the launcher passes on) | the sigmas
VALUES = [
    ("none", "none", (0.0, 0.0)),
    ("partial", "partial", (0.25, 0.001)),
    ("full", "full", (0.5, 0.002)),
    ("0.1,0.001", "[0.1,0.001]", (0.1, 0.001)),
    ("[0.1,0.001]", "[0.1,0.001]", (0.1, 0.001)),
    (" 0.3 , 0 ", "[0.3,0.0]", (0.3, 0.0)),
    ("1e-5,2", "[0.00001,2.0]", (1e-5, 2.0)),
]
BAD = [
    "loud",
    "custom",
    "Partial",
    "",
    "0.1",
    "0.1,0.001,0.2",
    "-0.1,0.001",
    "0.1,-1",
    "nan,0.001",
    "0,inf",
    "[0.1 0.001]",
    "a,b",
]


def launcher_noise(value: str) -> str:
    """The ``-p tactile_noise:=`` value the launcher gives the tactile node for ``--tactile-noise value``."""
    tactile_node = next(
        spec
        for spec in graph_nodes(resolve(parse_args(["--policy", "random", "--tactile-noise", value])))
        if spec.name == "tactile"
    )
    return next(arg for arg in tactile_node.ros_args() if arg.startswith("tactile_noise:="))[len("tactile_noise:=") :]


@pytest.mark.parametrize("given,ros,pair", VALUES, ids=[v[0].strip() or "empty" for v in VALUES])
def test_the_same_value_is_accepted_in_all_three_places(given, ros, pair):
    # the launcher's check (what launch_graph.sh does first): the -p form it passes on
    assert launcher_noise(given) == ros
    # the tactile node's parameter, as rcl reads `-p tactile_noise:=<ros>` or a params file (YAML), and as text
    for value in (yaml.safe_load(ros), given):
        assert noise_sigma(check_value(PARAM, value)) == pytest.approx(pair, abs=0)
    # the env option (dlo-train env_options.tactile_noise=... is read as YAML too)
    for value in (given, yaml.safe_load(ros)):
        check_options({"tactile_noise": value})
        assert noise_sigma(value) == pytest.approx(pair, abs=0)


@pytest.mark.parametrize("value", BAD)
def test_a_bad_value_is_refused_in_one_line_in_all_three_places(value):
    expected = f"expected {NOISE_FORMS}, got {value!r}"
    with pytest.raises(UsageError) as error:
        launcher_noise(value)
    assert str(error.value) == f"--tactile-noise: {expected}"
    with pytest.raises(ParameterError) as error:
        check_value(PARAM, value)
    assert str(error.value) == f"parameter 'tactile_noise': {expected}"
    with pytest.raises(ValueError) as error:
        check_options({"tactile_noise": value})
    assert str(error.value) == f"tactile_noise: {expected}"


@pytest.mark.parametrize("value", ["loud", "-0.1,0.001", "0.1", "custom"])
def test_the_launcher_refuses_a_bad_value_before_anything_starts(value, tmp_path):
    logs = tmp_path / "logs"
    launch = subprocess.Popen(
        ["bash", str(ROOT / "scripts" / "launch_graph.sh"), "--tactile-noise", value, "--logs", str(logs), "--episodes", "1"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
        env={**os.environ, "DLO_USE_ROS2RUN": "1"},
    )
    try:
        out, err = launch.communicate(timeout=120)
    finally:
        try:
            os.killpg(launch.pid, signal.SIGKILL)  # had it started a graph (it must not): nothing left behind
        except ProcessLookupError:
            pass
    assert launch.returncode == 2, out + err
    assert err.splitlines() == [f"launch_graph: --tactile-noise: expected {NOISE_FORMS}, got {value!r}"]
    assert out == ""  # no domain chosen, no node started
    assert not logs.exists()


def start_tactile_node(own_groups, *settings: str) -> tuple[int, list[str]]:
    """Run tactile_node with ``-p`` settings until it has said what noise it uses (or exited); its exit
    status (-SIGINT when it was stopped here) and output lines."""
    args = [arg for setting in settings for arg in ("-p", setting)]
    node = subprocess.Popen(
        [ROS2RUN, "dlo_perception", "tactile_node", "--ros-args", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        start_new_session=True,
    )
    own_groups(node.pid)
    watchdog = threading.Timer(120, lambda: os.killpg(node.pid, signal.SIGKILL))
    watchdog.start()
    lines = []
    try:
        for line in node.stdout:
            lines.append(line.rstrip("\n"))
            if "tactile noise: " in line:
                os.killpg(node.pid, signal.SIGINT)
                break
        node.stdout.read()
        return node.wait(timeout=60), lines
    finally:
        watchdog.cancel()


@pytest.mark.parametrize(
    "setting,noise",
    [
        ("tactile_noise:=[0.1,0.001]", "sigma_theta 0.1 rad, sigma_y 0.001 m"),
        ("tactile_noise:=0.1,0.001", "sigma_theta 0.1 rad, sigma_y 0.001 m"),
        ("tactile_noise:=partial", "partial (sigma_theta 0.25 rad, sigma_y 0.001 m)"),
    ],
    ids=["pair", "pair-as-text", "preset"],
)
def test_the_node_says_its_noise(setting, noise, own_groups):
    rc, lines = start_tactile_node(own_groups, setting)
    assert rc in (0, -signal.SIGINT), lines
    assert any(line.endswith(f"[tactile_node]: tactile noise: {noise}; seed 0") for line in lines), lines
    assert not [line for line in lines if line.startswith("[WARN]")], lines


@pytest.mark.parametrize(
    "setting,line",
    [
        ("tactile_noise:=loud", f"parameter 'tactile_noise': expected {NOISE_FORMS}, got 'loud'"),
        ("tactile_noise:=[-0.1,0.001]", f"parameter 'tactile_noise': expected {NOISE_FORMS}, got [-0.1, 0.001]"),
        ("tactile_noise:=custom", f"parameter 'tactile_noise': expected {NOISE_FORMS}, got 'custom'"),
    ],
)
def test_the_node_refuses_a_bad_value_in_one_line(setting, line, own_groups):
    rc, lines = start_tactile_node(own_groups, setting)
    assert rc == 2 and lines == [f"[tactile_node] bad parameter: {line}"], lines


@pytest.mark.parametrize(
    "settings,line",
    [
        (["noise:=full"], "unknown parameter 'noise'; did you mean 'tactile_noise'?"),
        (["noise:=custom", "sigma_theta:=0.1", "sigma_y:=0.001"], "unknown parameter 'noise'; did you mean 'tactile_noise'?"),
        (["tactile_noise:=full", "sigma_y:=0.001"], "unknown parameter 'sigma_y'; did you mean 'tactile_noise'?"),
    ],
    ids=["noise", "noise-custom-pair", "sigma-next-to-tactile-noise"],
)
def test_the_names_before_tactile_noise_are_unknown_parameters(settings, line, own_groups):
    """The names of the unreleased version (noise, sigma_theta, sigma_y) are answered like any unknown
    parameter: one line, exit 2, the closest declared name; the node does not start."""
    rc, lines = start_tactile_node(own_groups, *settings)
    assert rc == 2 and lines == [f"[tactile_node] {line}"], lines
