"""One exit-status table for the bag tools (dlo_bag.errors EXIT_*), each case as a user meets it."""

import pytest
from dlo_bag import analysis, bag_info, recover
from dlo_bag.analysis import recompute_episode
from dlo_bag.errors import EXIT_BAD_BAG, EXIT_OK, EXIT_USAGE
from dlo_bag.writer import BagWriter
from dlo_msgs.msg import TaskState
from rclpy.serialization import serialize_message

TOOLS = {"dlo-bag-info": bag_info.main, "dlo-analyze": analysis.main, "dlo-bag-recover": recover.main}


@pytest.mark.parametrize("tool", sorted(TOOLS))
@pytest.mark.parametrize("case", ["missing", "empty_dir", "file"])
def test_a_path_that_is_not_a_bag_is_a_usage_error_in_every_tool(tool, case, tmp_path, capsys):
    path = {"missing": tmp_path / "nope", "empty_dir": tmp_path, "file": tmp_path / "f.txt"}[case]
    if case == "file":
        path.write_text("not a bag\n")
    assert TOOLS[tool]([str(path)]) == EXIT_USAGE == 2
    out = capsys.readouterr()
    lines = (out.out + out.err).strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and "Traceback" not in lines[0], lines


@pytest.mark.parametrize("tool", sorted(TOOLS))
def test_a_damaged_bag_is_exit_1_in_every_tool(tool, tmp_path, capsys):
    bag = tmp_path / "run"
    bag.mkdir()
    (bag / "run_0.mcap").write_bytes(b"\x89MCAP0\r\n" + b"\x00" * 40)  # a recorder killed at once: no metadata.yaml
    assert TOOLS[tool]([str(bag)]) == EXIT_BAD_BAG == 1
    out = capsys.readouterr()
    assert "Traceback" not in out.out + out.err
    if tool != "dlo-bag-recover":
        assert f"dlo-bag-recover {bag}" in out.err  # the fix is named


@pytest.mark.parametrize("tool", sorted(TOOLS))
def test_a_bad_option_is_exit_2_in_every_tool(tool, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        TOOLS[tool]([str(tmp_path), "--no-such-option"])
    assert exit_.value.code == EXIT_USAGE == 2
    err = capsys.readouterr().err
    assert "unrecognized arguments: --no-such-option" in err and "Traceback" not in err


def _task_bag(path, recorded_outcome=None, recorded_return_offset=0.0):
    """A bag of one finished 3-step episode (a short cable held near its end, then dropped at step 2)
    whose recorded outcome and return are what dlo_interface.task gives, or ``recorded_outcome`` instead, and
    the return plus ``recorded_return_offset``."""
    held = {0: [1, 2], 1: [28, 29], 2: []}
    states = {
        step: TaskState(
            episode=0,
            seed=42,
            step=step,
            held_indices=held[step],
            n_held=len(held[step]),
            held_indices_authors=held[step],
            num_particles=30,
            cable_length=0.1247,
            done=step == 2,
            task_rules="paper_text",
        )
        for step in held
    }
    summary = recompute_episode(states)
    final = states[2]
    final.outcome = final.outcome_authors = {"hold_the_end": 1, "stop_before": 2, "reach_end_but_drop": 3, "drop_before": 4}[
        recorded_outcome or summary["outcome"]
    ]
    final.episode_return = summary["episode_return"] + recorded_return_offset
    with BagWriter(path) as writer:
        writer.add_topic("/dlo/task/state", "dlo_msgs/msg/TaskState")
        for step, msg in states.items():
            msg.header.stamp.nanosec = step + 1
            writer.write("/dlo/task/state", serialize_message(msg), 100 + step)
    return summary


def test_a_recomputed_outcome_that_differs_from_the_recorded_one_is_exit_1(tmp_path, capsys):
    """README (Replay, analysis and video) and dlo-analyze --help: a mismatch with the recorded outcome
    is reported and exits 1; an agreeing bag exits 0."""
    summary = _task_bag(tmp_path / "agrees")
    assert analysis.main([str(tmp_path / "agrees")]) == 0
    out = capsys.readouterr()
    assert "MISMATCH" not in out.err and summary["outcome"] == "reach_end_but_drop"
    _task_bag(tmp_path / "differs", recorded_outcome="hold_the_end")
    assert analysis.main([str(tmp_path / "differs")]) == EXIT_BAD_BAG == 1
    err = capsys.readouterr().err
    assert "MISMATCH episode 0: recomputed reach_end_but_drop / reach_end_but_drop" in err
    assert "recorded hold_the_end / hold_the_end" in err and "Traceback" not in err


def test_a_recorded_return_that_differs_is_a_mismatch_exit_1(tmp_path, capsys):
    """dlo-analyze: the recomputed return must equal the recorded one (1e-6) like the outcomes."""
    _task_bag(tmp_path / "agrees", recorded_return_offset=1e-9)
    assert analysis.main([str(tmp_path / "agrees")]) == EXIT_OK
    assert "MISMATCH" not in capsys.readouterr().err
    _task_bag(tmp_path / "differs", recorded_return_offset=0.5)
    assert analysis.main([str(tmp_path / "differs")]) == EXIT_BAD_BAG
    assert "MISMATCH episode 0" in capsys.readouterr().err


def test_a_bag_whose_only_episode_is_unfinished_prints_an_empty_table(tmp_path, capsys):
    """dlo-analyze of a recording stopped mid-episode: no finished episode to count (0/0), the unfinished
    one named, exit 0 (outcome_table of no episodes)."""
    with BagWriter(tmp_path / "run") as writer:
        writer.add_topic("/dlo/task/state", "dlo_msgs/msg/TaskState")
        for step in range(3):
            msg = TaskState(
                episode=0,
                seed=7,
                step=step,
                held_indices=[10, 11],
                n_held=2,
                held_indices_authors=[10, 11],
                num_particles=30,
                cable_length=0.1247,
                task_rules="paper_text",
            )
            msg.header.stamp.nanosec = step + 1
            writer.write("/dlo/task/state", serialize_message(msg), 100 + step)
    assert analysis.main([str(tmp_path / "run")]) == EXIT_OK
    out = capsys.readouterr().out
    assert "(1 episode(s) unfinished in the bag, not counted)" in out
    assert "hold_the_end" in out and "0/0" in out and "Traceback" not in out
