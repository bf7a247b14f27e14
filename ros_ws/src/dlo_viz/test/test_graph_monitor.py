"""dlo_viz.graph_monitor without a graph: a node's health from its log (issue 20: what a node waits for holds
until the node logs anything after it or the graph steps). The launcher's lines made of it: dlo_bringup
test_graph_monitor.py; their texts: dlo_bag test_outcome_text.py."""

import time

SIM_WAITS = (
    "[INFO] [100.0] [sim_node]: waiting for 4 subscribers of /dlo/gripper/state (have 0)\n"
    "[WARN] [104.2] [sim_node]: waiting for the recorder 'recorder' to subscribe to /dlo/gripper/cmd\n"
)
RECORDER_WAIT = "sim: waiting for the recorder 'recorder' to subscribe to /dlo/gripper/cmd"


def test_a_wait_is_over_once_the_graph_steps_after_it(tmp_path):
    """The other end of a wait: a control step counted on /clock after the line was logged (its rclpy time
    stamp, or when it was read for a line without one); later warnings are still counted."""
    from dlo_viz.graph_monitor import LogTail, NodeHealth

    log = tmp_path / "sim.log"
    log.write_text(SIM_WAITS)
    sim = NodeHealth("sim", LogTail(str(log)))
    assert sim.notes(last_step_wall=None) == [RECORDER_WAIT]  # no step rate known
    assert sim.notes(last_step_wall=104.0) == [RECORDER_WAIT]  # the last step came before the wait
    assert sim.notes(last_step_wall=104.3) == []  # a step after it: the sim runs
    with open(log, "a") as f:
        f.write("[WARN] [sim_node]: waiting for something, logged without a time\n")
    before = time.time()
    assert sim.notes(last_step_wall=before - 1.0) == ["sim: waiting for something, logged without a time"]
    assert sim.notes(last_step_wall=time.time() + 1.0) == []
    with open(log, "a") as f:
        f.write(SIM_WAITS.splitlines(keepends=True)[1] + "[WARN] [105.0] [sim_node]: no command for 3 s\n")
    assert sim.notes() == ["sim: 1 warning (last: no command for 3 s)"]  # a line after the wait ends it
