"""The dlo-vitac graph as a ROS 2 launch file (a real Jazzy install, the Docker image under docker/):

    ros2 launch dlo_bringup graph.launch.py episodes:=5 seed:=1000 record:=bags/run1
    ros2 launch dlo_bringup graph.launch.py --show-args      # every argument: the launcher's options

Its nodes, parameters and remappings are those ``scripts/launch_graph.sh`` starts for the same options
(``task_rules:=paper_text`` is ``--task-rules paper_text``): both are built from dlo_bringup.graph.graph_nodes.
As with the launcher, the other nodes start once the sim has found itself alone on the domain, and the graph stops
when any node ends (the sim after its episodes). ROS_DOMAIN_ID comes from the environment; the launcher's own
features (a free domain of its own, the episode and status lines, the outcome table, its exit codes) are not here:
``logs:=DIR`` keeps the sim's outcome lines in DIR/outcomes.jsonl.
"""

from pathlib import Path

from dlo_bringup.graph import STOP_LIMIT, graph_nodes
from dlo_bringup.options import UsageError, argv_from_launch_arguments, launch_arguments, parse_args, resolve
from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, OpaqueFunction, RegisterEventHandler, Shutdown
from launch.event_handlers import OnProcessIO
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def node_action(spec) -> Node:
    """A NodeSpec as a launch_ros Node: its parameters, its remappings, its output on the screen; the whole launch
    ends with it, and stopping it waits as long as the launcher does before SIGTERM."""
    return Node(
        package=spec.package,
        executable=spec.executable,
        parameters=[dict(spec.parameters)],
        remappings=list(spec.remappings),
        output="screen",
        sigterm_timeout=str(STOP_LIMIT),
        on_exit=[Shutdown(reason=f"{spec.name} ended")],
    )


def graph_actions(context):
    """The graph's nodes for the launch arguments: the sim, and the rest once it prints its ready line."""
    values = {name: LaunchConfiguration(name).perform(context) for name, _, _ in launch_arguments()}
    try:
        options = resolve(parse_args(argv_from_launch_arguments(values)))
    except UsageError as error:
        raise RuntimeError(f"graph.launch.py: {error}") from None
    for note in options.notes:
        print(f"[graph.launch.py] note: {note}", flush=True)
    logs = Path(values["logs"]) if values["logs"] else None
    if logs is not None:
        logs.mkdir(parents=True, exist_ok=True)
    first, *rest = graph_nodes(options, logs)
    sim = node_action(first)
    started = []

    def start_the_rest(event):
        if started or first.ready_line not in event.text.decode(errors="replace"):
            return None
        started.append(True)
        return [node_action(spec) for spec in rest]

    return [sim, RegisterEventHandler(OnProcessIO(target_action=sim, on_stdout=start_the_rest, on_stderr=start_the_rest))]


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription(
        [DeclareLaunchArgument(name, default_value=default, description=text) for name, default, text in launch_arguments()]
        + [OpaqueFunction(function=graph_actions)]
    )
