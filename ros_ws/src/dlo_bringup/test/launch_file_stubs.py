"""launch/graph.launch.py read without ROS 2's launch packages (not installed with the wheels): stand-ins for
the few ``launch`` and ``launch_ros`` names it uses record how they were called, and :func:`launched_nodes` plays
what ``ros2 launch`` does with them: the arguments' defaults overridden by the ones given, the OpaqueFunction run,
the sim's output fed to the handler that starts the rest."""

from __future__ import annotations

import importlib.util
import sys
import types
from pathlib import Path

LAUNCH_FILE = Path(__file__).resolve().parents[1] / "launch" / "graph.launch.py"


class Entity:
    """A stand-in: keeps its call's arguments."""

    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class LaunchConfiguration(Entity):
    def perform(self, context) -> str:
        return context.launch_configurations[self.args[0]]


def stub_modules() -> dict[str, types.ModuleType]:
    """``launch``, ``launch.actions``, ``launch.event_handlers``, ``launch.substitutions``, ``launch_ros``,
    ``launch_ros.actions`` with the names graph.launch.py imports."""
    modules = {
        name: types.ModuleType(name)
        for name in (
            "launch",
            "launch.actions",
            "launch.event_handlers",
            "launch.substitutions",
            "launch_ros",
            "launch_ros.actions",
        )
    }
    modules["launch"].LaunchDescription = type("LaunchDescription", (Entity,), {})
    for name in ("DeclareLaunchArgument", "OpaqueFunction", "RegisterEventHandler", "Shutdown"):
        setattr(modules["launch.actions"], name, type(name, (Entity,), {}))
    modules["launch.event_handlers"].OnProcessIO = type("OnProcessIO", (Entity,), {})
    modules["launch.substitutions"].LaunchConfiguration = LaunchConfiguration
    modules["launch_ros.actions"].Node = type("Node", (Entity,), {})
    modules["launch"].actions = modules["launch.actions"]
    modules["launch_ros"].actions = modules["launch_ros.actions"]
    return modules


def load_launch_file(monkeypatch) -> types.ModuleType:
    """graph.launch.py imported with the stand-ins in sys.modules (for the test only: ``monkeypatch``)."""
    for name, module in stub_modules().items():
        monkeypatch.setitem(sys.modules, name, module)
    spec = importlib.util.spec_from_file_location("graph_launch", LAUNCH_FILE)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


class Output:
    """A process's output event (launch.events.process.ProcessIO): ``text`` in bytes."""

    def __init__(self, text: str):
        self.text = text.encode()


def launched_nodes(monkeypatch, arguments: dict) -> tuple[list, dict]:
    """The Node entries ``ros2 launch dlo_bringup graph.launch.py`` starts with ``arguments`` (name: value), in
    the order they start, and the declared arguments' defaults."""
    launch_file = load_launch_file(monkeypatch)
    description = launch_file.generate_launch_description()
    entities = description.args[0]
    defaults = {e.args[0]: e.kwargs["default_value"] for e in entities if type(e).__name__ == "DeclareLaunchArgument"}
    assert set(arguments) <= set(defaults), set(arguments) - set(defaults)
    (opaque,) = [e for e in entities if type(e).__name__ == "OpaqueFunction"]
    context = types.SimpleNamespace(launch_configurations={**defaults, **arguments})
    sim, handler = opaque.kwargs["function"](context)
    watch = handler.args[0]
    assert watch.kwargs["target_action"] is sim
    assert watch.kwargs["on_stdout"](Output("[INFO] [1.0] [sim_node]: waiting for 3 subscribers")) is None
    rest = watch.kwargs["on_stderr"](Output("[INFO] [1.2] [sim_node]: alone on ROS_DOMAIN_ID=42; starting"))
    assert watch.kwargs["on_stdout"](Output("alone on ROS_DOMAIN_ID=42")) is None  # the rest starts once
    return [sim, *rest], defaults


def node_command(node) -> tuple[str, str, list[tuple[str, object]], list[tuple[str, str]]]:
    """(package, executable, parameters, remappings) of a Node entry."""
    (parameters,) = node.kwargs["parameters"]
    return (
        node.kwargs["package"],
        node.kwargs["executable"],
        list(parameters.items()),
        [tuple(r) for r in node.kwargs["remappings"]],
    )
