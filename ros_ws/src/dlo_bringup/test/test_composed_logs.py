"""The --composed process's output split into each node's log (dlo_bringup.composed_logs.LogSplitter)."""

from __future__ import annotations

from dlo_bringup.composed_logs import LogSplitter

OUTPUT = """\
[Taichi] version 1.7.4, llvm 15.0.4
[composed] building sim
[INFO] [1796631431.031] [sim_node]: alone on ROS_DOMAIN_ID=81: no other publisher of /dlo/gripper/state
[composed] built sim as sim_node
[composed] building recorder
[INFO] [1796631431.2] [recorder]: recording '/dlo' + /clock to bags/run1
[composed] built recorder as recorder
[composed] building policy
[policy_node] bad parameter: parameter 'checkpoint': not a dlo-vitac policy file
Traceback (most recent call last):
  File "x.py", line 1, in <module>
[composed] built policy failed
[WARN] [1796631432.5] [sim_node]: no command for episode 0 step 3
[INFO] [1796631432.6] [recorder]: stopping (policy ended): draining and closing the bag
  /dlo/clock: received 3, written 3
[ERROR] [1796631432.7] [sim_node.rclpy]: a child logger of the sim
[composed] ended after 3.0 s (status 2)
"""


def split(tmp_path, text: str, chunks: int = 1) -> dict:
    source = tmp_path / "composed.log"
    source.write_text("")
    logs = {name: tmp_path / f"{name}.log" for name in ("sim", "recorder", "policy")}
    for path in logs.values():
        path.write_text("")  # (the launcher starts them empty)
    splitter = LogSplitter(source, logs)
    step = -(-len(text) // chunks)
    for i in range(0, len(text), step):  # appended in pieces, lines cut anywhere
        with source.open("a") as f:
            f.write(text[i : i + step])
        splitter.pump()
    splitter.stop()
    return {name: path.read_text().splitlines() for name, path in logs.items()}


def test_every_line_goes_to_the_log_of_the_node_it_names(tmp_path):
    for chunks in (1, 7, 50):
        logs = split(tmp_path, OUTPUT, chunks)
        assert logs["sim"] == [
            "[INFO] [1796631431.031] [sim_node]: alone on ROS_DOMAIN_ID=81: no other publisher of /dlo/gripper/state",
            "[WARN] [1796631432.5] [sim_node]: no command for episode 0 step 3",
            "[ERROR] [1796631432.7] [sim_node.rclpy]: a child logger of the sim",
        ], chunks
        assert logs["recorder"] == [
            "[INFO] [1796631431.2] [recorder]: recording '/dlo' + /clock to bags/run1",
            "[INFO] [1796631432.6] [recorder]: stopping (policy ended): draining and closing the bag",
            "  /dlo/clock: received 3, written 3",  # a line naming no node: the node of the line before
        ], chunks
        assert logs["policy"] == [  # built, it had no node name yet: the lines while it was built
            "[policy_node] bad parameter: parameter 'checkpoint': not a dlo-vitac policy file",
            "Traceback (most recent call last):",
            '  File "x.py", line 1, in <module>',
        ], chunks


def test_a_line_left_unfinished_is_kept_at_the_stop(tmp_path):
    logs = split(tmp_path, "[composed] building sim\n[composed] built sim as sim_node\n[INFO] [1.0] [sim_node]: half")
    assert logs["sim"] == ["[INFO] [1.0] [sim_node]: half"]


def test_a_splitter_in_its_thread_copies_as_the_source_grows(tmp_path):
    import time

    source = tmp_path / "composed.log"
    source.write_text("[composed] building sim\n")
    splitter = LogSplitter(source, {"sim": tmp_path / "sim.log"}, period=0.01).start()
    with source.open("a") as f:
        f.write("[INFO] [1.0] [sim_node]: alone on ROS_DOMAIN_ID=12\n")
    deadline = time.monotonic() + 10
    while "alone" not in (tmp_path / "sim.log").read_text() and time.monotonic() < deadline:
        time.sleep(0.01)
    assert "alone on ROS_DOMAIN_ID=12" in (tmp_path / "sim.log").read_text()  # before the stop
    splitter.stop()
