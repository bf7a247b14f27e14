"""One description of the graph (dlo_bringup.graph), two ways to start it: the launcher (scripts/launch_graph.sh)
and the ROS 2 launch file (launch/graph.launch.py, read here with stand-ins for launch and launch_ros, which only a
real ROS 2 install has). For the same options both start the same nodes, in the same order, with the same
parameters (as each node reads them) and remappings. The launcher's real start: tests/test_launch_graph_exit_codes.py
(which also compares what its stand-in nodes were given with this launch file)."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import yaml
from dlo_bringup.graph import STOP_LIMIT, graph_nodes, ros_value
from dlo_bringup.launcher import Launcher
from dlo_bringup.options import GraphOptions, UsageError, launch_arguments, parse_args, resolve
from dlo_common.topics import names

sys.path.insert(0, str(Path(__file__).parent))
from launch_file_stubs import launched_nodes, node_command  # noqa: E402

# the launcher's command line and the launch arguments that ask for the same graph (written out, not derived)
CASES = {
    "defaults": ([], {}),
    "everything": (
        [
            "--episodes",
            "3",
            "--seed",
            "7",
            "--mode",
            "real_time",
            "--rate-factor",
            "2",
            "--policy",
            "random",
            "--without",
            "V",
            "--tactile-noise",
            "0.1,0.001",
            "--perturbations",
            "observation_delay=1,friction=0.6,camera_yaw=2",
            "--task-rules",
            "paper_text",
            "--single-particle-grip",
            "--carry-law",
            "authors",
            "--contact-radius",
            ".005",
            "--vision-source",
            "particles",
            "--start-pose",
            "authors",
            "--move-spacing",
            ".004",
            "--record",
            "BAG",
            "--foxglove",
            "0",
            "--namespace",
            "/lab/robot1/",
        ],
        {
            "episodes": "3",
            "seed": "7",
            "mode": "real_time",
            "rate_factor": "2",
            "policy": "random",
            "without": "V",
            "tactile_noise": "0.1,0.001",
            "perturbations": "observation_delay=1,friction=0.6,camera_yaw=2",
            "task_rules": "paper_text",
            "single_particle_grip": "true",
            "carry_law": "authors",
            "contact_radius": ".005",
            "vision_source": "particles",
            "start_pose": "authors",
            "move_spacing": ".004",
            "record": "BAG",
            "foxglove": "0",
            "namespace": "/lab/robot1/",
        },
    ),
    "learning_online": (
        ["--policy", "sac", "--train-out", "RUN", "--train-config", "my.yaml", "--foxglove"],
        {"policy": "sac", "train_out": "RUN", "train_config": "my.yaml", "foxglove": "8765"},
    ),
    "a_checkpoint_and_its_training": (
        ["--checkpoint", "SHIPPED", "--tactile-noise", "partial"],
        {"checkpoint": "SHIPPED", "tactile_noise": "partial"},
    ),
}


def launcher_command(options, spec) -> tuple[str, str, list, list]:
    """What the launcher's command line for ``spec`` gives the node: (package, executable, parameters as the node
    reads ``-p name:=value`` (YAML), remappings)."""
    command = Launcher(options).command(spec)
    start = command.index(spec.package)
    package, executable, ros_args, *args = command[start:]
    assert ros_args == "--ros-args" and len(args) % 2 == 0
    parameters = [
        (a.split(":=", 1)[0], yaml.safe_load(a.split(":=", 1)[1])) for flag, a in zip(args[::2], args[1::2]) if flag == "-p"
    ]
    remappings = [tuple(a.split(":=", 1)) for flag, a in zip(args[::2], args[1::2]) if flag == "-r"]
    assert len(parameters) + len(remappings) == len(args) // 2
    return package, executable, parameters, remappings


def fill(values, tmp_path):
    from dlo_policy.rundir import shipped_policy_path

    paths = {"BAG": str(tmp_path / "bag"), "RUN": str(tmp_path / "run"), "SHIPPED": str(shipped_policy_path())}
    return [paths.get(v, v) for v in values] if isinstance(values, list) else {k: paths.get(v, v) for k, v in values.items()}


@pytest.mark.parametrize("case", sorted(CASES))
def test_the_launch_file_starts_what_the_launcher_starts(case, tmp_path, monkeypatch):
    argv, arguments = (fill(x, tmp_path) for x in CASES[case])
    logs = tmp_path / "logs"
    options = resolve(parse_args([*argv, "--logs", str(logs)]))
    specs = graph_nodes(options, logs)
    nodes, _ = launched_nodes(monkeypatch, {**arguments, "logs": str(logs)})
    assert [node_command(node) for node in nodes] == [launcher_command(options, spec) for spec in specs]
    for node in nodes:  # the launch ends with any node, and waits for one as long as the launcher does
        assert [type(action).__name__ for action in node.kwargs["on_exit"]] == ["Shutdown"]
        assert float(node.kwargs["sigterm_timeout"]) == STOP_LIMIT
    assert logs.is_dir()  # the sim's outcome lines go there


def test_every_option_is_a_launch_argument_but_the_launchers_own_with_its_default():
    given = GraphOptions()
    arguments = {name: default for name, default, _ in launch_arguments()}
    launchers_own = ("help", "notes", "composed", "status_period", "domain_id")  # (ros2 launch: a process per node)
    assert set(arguments) == {f for f in vars(given) if f not in launchers_own}
    for name, default in arguments.items():
        assert default == getattr(given, name), name


def test_a_bad_launch_argument_is_one_line(monkeypatch):
    with pytest.raises(RuntimeError) as error:
        launched_nodes(monkeypatch, {"mode": "fast"})
    assert str(error.value) == "graph.launch.py: --mode must be step_locked or real_time"


def test_the_sim_starts_first_and_a_namespace_moves_every_topic_and_service(tmp_path):
    options = resolve(parse_args(["--policy", "random", "--namespace", "robot1", "--record", str(tmp_path / "b"), "--foxglove"]))
    specs = graph_nodes(options)
    assert [s.name for s in specs] == ["sim", "recorder", "foxglove", "tactile", "vision", "policy"]
    assert specs[0].ready_line == "alone on ROS_DOMAIN_ID"
    for spec in specs:
        if spec.name == "foxglove":  # it serves what the graph publishes, from where it is
            assert spec.remappings == () and ("topics", "/robot1/dlo,/robot1/clock") in spec.parameters
        else:
            assert spec.remappings == tuple((name, "/robot1" + name) for name in names()), spec.name
    assert ("namespace", "/robot1") in specs[1].parameters  # the recorder records what is under it


def test_one_perturbations_option_gives_each_node_the_families_it_owns():
    """--perturbations: the sim node gets the physics and camera families, the policy node the observation and
    action families (each node's perturbations parameter, dlo_interface.perturbations.OWNERS); a node that owns none
    of them gets no parameter; a bad setting is one line naming the option."""
    from dlo_interface.perturbations import owned

    def given(argv):
        return {
            s.name: dict(s.parameters).get("perturbations")
            for s in graph_nodes(resolve(parse_args(["--policy", "random", *argv])))
        }

    both = given(["--perturbations", "camera_yaw=2,action_delay=1,friction=0.6,observation_delay=1"])
    assert both["sim"] == "friction=0.6,camera_yaw=2" and both["policy"] == "observation_delay=1,action_delay=1"
    assert both["tactile"] is None and both["vision"] is None
    assert owned(both["sim"], "simulator") and owned(both["policy"], "policy node")  # what each node's check takes
    assert given(["--perturbations", "friction=0.6"])["policy"] is None
    assert given(["--perturbations", "velocity_gain=0.9"])["sim"] is None
    assert set(given([]).values()) == {None}
    with pytest.raises(UsageError) as error:
        parse_args(["--perturbations", "frction=0.6"])
    assert str(error.value).startswith("--perturbations: unknown perturbation 'frction'; did you mean 'friction'?")


def test_parameter_values_are_written_as_the_nodes_read_them():
    """-p name:=value is YAML: a float keeps a decimal point and never has an exponent (YAML 1.1 reads 1e-05 as
    text), a bool is true/false, a pair of floats a list."""
    for value in (0.004, 1e-05, 2.0, 0.0, 1e20, True, False, 3, [0.1, 0.001], [1e-05, 2.0], "paper_text"):
        assert yaml.safe_load(ros_value(value)) == value, value
    assert ros_value(1e-05) == "0.00001" and ros_value([1e-05, 2.0]) == "[0.00001,2.0]"


def test_the_sim_gets_the_move_spacing_the_checkpoint_was_trained_with_unless_asked(tmp_path):
    """--move-spacing (docs/FIDELITY.md): with --policy sac the sim's move_spacing is the checkpoint's training
    env_options.move_spacing (0, the cable's own spacing, for a run without it: the shipped one); asked otherwise,
    it runs as asked, with a note; a scripted policy runs 0 unless asked."""
    from dlo_policy.rundir import shipped_policy_path

    def sim_spacing(argv):
        options = resolve(parse_args(["--episodes", "1", *argv]))
        return dict(graph_nodes(options)[0].parameters)["move_spacing"], options.notes

    shipped = shipped_policy_path()
    run = tmp_path / "spaced"
    run.mkdir()
    (run / "policy.pt").write_bytes(shipped.read_bytes())
    config = yaml.safe_load((shipped.parent / "config.yaml").read_text())
    config["env_options"]["move_spacing"] = 0.004
    (run / "config.yaml").write_text(yaml.safe_dump(config))
    assert sim_spacing([]) == (0.0, [])
    assert sim_spacing(["--checkpoint", str(run / "policy.pt")]) == (0.004, [])
    assert sim_spacing(["--checkpoint", str(run / "policy.pt"), "--move-spacing", "0.0040"]) == (0.004, [])
    spacing, notes = sim_spacing(["--checkpoint", str(run / "policy.pt"), "--move-spacing", "0"])
    assert spacing == 0.0 and len(notes) == 1 and "move_spacing=0.004; this graph runs" in notes[0], notes
    assert notes[0].endswith("move_spacing=0 (as asked)"), notes
    assert sim_spacing(["--policy", "oracle", "--move-spacing", ".004"]) == (0.004, [])
    with pytest.raises(UsageError, match=r"^--move-spacing must be a number in \[0, 0\.01\] m"):
        parse_args(["--move-spacing", "nan"])
