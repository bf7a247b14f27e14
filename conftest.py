"""Test tiers: the markers of pytest.ini, put on every collected test here (also when only
``ros_ws/src`` is run), so that ``scripts/test.sh -m "not graph and not slow"`` is the fast tier
for the inner loop. Tiers, commands and measured times: tests/README.md#running-the-tests.

- ``graph``: the test starts ROS nodes or a launched graph as processes. Found by the fixtures
  that start or stop them (GRAPH_FIXTURES); tests that start them without one are listed in GRAPH.
- ``slow``: the test trains, or runs a long simulation, evaluation or video render: about 3 s or
  more on its own (SLOW).

A list entry is a test file (every test in it) or ``file::test`` (every parametrization);
tests/test_tiers.py checks that each entry still names a test.

Each xdist worker keeps its own Taichi kernel cache (worker_taichi_cache).

A pytest stopped by SIGTERM (a CI job's timeout, ``kill``) tears its fixtures down as on Ctrl-C, so a
graph a module-scoped fixture started does not outlive the run (pytest_configure below).

Nodes killed with SIGKILL (the crash tests) leave Fast DDS shared-memory files in /dev/shm; the session
removes the ones that appeared while it ran and that no process uses any more (pytest_sessionfinish,
after the fixtures' teardown).
"""

from __future__ import annotations

import pytest

GRAPH_FIXTURES = frozenset(
    {
        "launches",  # tests/test_graph_isolation.py: launch_graph.sh in its own session
        "launch_in_own_group",  # tests/conftest.py: launch_graph.sh, whole process group stopped
        "own_groups",  # tests/conftest.py: node processes started by the test
        "procs",  # ros_ws/src/dlo_{bag,viz,driver_kit}/test/conftest.py: node processes on a test domain
        "launcher",  # ros_ws/src/dlo_viz/test/test_foxglove_bridge.py: launch_graph.sh
        "probe",  # tests/test_graph_faults.py: an in-process node next to node processes
        "broken_checks",  # ros_ws/src/dlo_driver_kit/test/test_driver_check.py: broken drivers and checkers
    }
)

GRAPH = (
    "tests/test_graph_perturbations.py",
    "tests/test_graph.py::test_sigint_mid_run_leaves_a_complete_readable_bag",
    "tests/test_graph_equals_env.py",
    "tests/test_graph_faults.py",
    "tests/test_interfaces_doc.py::test_committed_doc_is_current_with_the_live_graph",
    "tests/test_launch_feedback.py",
    "tests/test_msgs.py::test_every_message_type_crosses_processes",
    "tests/test_node_errors.py",
    "tests/test_node_help.py::test_help_lists_every_parameter_and_starts_nothing",
    "tests/test_node_help.py::test_a_stray_argument_is_a_one_line_error",
    "tests/test_node_help.py::test_a_bad_value_in_a_params_file_is_a_one_line_error",
    "ros_ws/src/dlo_policy/test/test_cli_errors.py::test_policy_node_refuses_a_text_file_as_checkpoint",
    "ros_ws/src/dlo_driver_kit/test/test_driver_check.py::test_no_driver_is_one_clear_line_and_bad_usage_exits_2",
    "ros_ws/src/dlo_driver_kit/test/test_driver_check.py::test_a_late_driver_keeps_the_contract_and_is_reported_beyond_the_shipped_policys_latency_tolerance",
    "ros_ws/src/dlo_common/test/test_testing.py::test_a_killed_participants_shared_memory_is_removed_and_a_live_ones_kept",
)

SLOW = (  # each about 3 s or more: a training, a long simulation, evaluation or video render
    "ros_ws/src/dlo_policy/test/test_shipped_policies.py::test_evaluate_and_robustness_run_a_policy_installed_under_a_name",
    "ros_ws/src/dlo_policy/test/test_shipped_policies.py::test_the_policy_node_takes_a_shipped_name",
    "ros_ws/src/dlo_policy/test/test_perturbations.py",
    "ros_ws/src/dlo_sim/test/test_kernel_pool.py",
    "ros_ws/src/dlo_policy/test/test_init_from.py",
    "ros_ws/src/dlo_policy/test/test_randomise.py",
    "ros_ws/src/dlo_policy/test/test_previous_action.py",
    "ros_ws/src/dlo_driver_kit/test/test_driver_check_envelope.py::test_image_noise_is_estimated_from_the_images_while_holding_still",
    "tests/test_golden_training.py",
    "ros_ws/src/dlo_policy/test/test_train.py::test_a_signal_stops_the_run_at_an_episode_end_with_a_checkpoint_there_and_the_resumed_run_is_the_whole_one",
    "ros_ws/src/dlo_policy/test/test_train.py::test_a_signal_before_the_first_step_leaves_a_checkpoint_at_step_0_and_the_resumed_run_is_the_whole_one",
    "ros_ws/src/dlo_policy/test/test_experiments.py::test_ctrl_c_stops_the_grid_and_its_run_at_an_episode_end_with_a_checkpoint_the_next_start_resumes",
    "ros_ws/src/dlo_policy/test/test_evaluate_scripted.py::test_stdout_is_only_the_title_and_the_table",
    "ros_ws/src/dlo_policy/test/test_train_output.py::test_stdout_is_only_the_json_summary",
    "ros_ws/src/dlo_policy/test/test_train_output.py::test_off_a_terminal_progress_is_a_plain_line_every_tenth_showing_both_outcome_rules",
    "ros_ws/src/dlo_policy/test/test_train_output.py::test_a_short_run_that_does_not_set_checkpoint_every_can_be_resumed",
    "ros_ws/src/dlo_policy/test/test_train_output.py::test_a_checkpoint_interval_that_is_set_is_kept",
    "tests/test_graph_train.py",
    "tests/test_analysis_equals_env.py",
    "tests/test_video.py::test_one_playable_mp4_per_episode",
    "tests/test_video.py::test_gif_and_speed",
    "tests/test_video.py::test_video_progress_on_a_terminal_is_a_bar_and_the_lines",
    "ros_ws/src/dlo_policy/test/test_ray_cluster.py",
    "ros_ws/src/dlo_policy/test/test_train.py::test_resume_after_sigkill_reproduces_the_uninterrupted_run",
    "ros_ws/src/dlo_policy/test/test_experiments.py::test_runner_skips_finished_runs_and_runs_the_rest_in_processes",
    "ros_ws/src/dlo_policy/test/test_experiments.py::test_stopping_the_driver_stops_its_runs",
    "ros_ws/src/dlo_policy/test/test_experiments.py::test_a_second_grid_on_the_same_runs_fails_that_run_in_one_line_and_leaves_the_first_alone",
    "ros_ws/src/dlo_policy/test/test_experiments.py::test_a_partial_local_run_resumes_from_its_checkpoint_and_one_without_starts_afresh",
    "ros_ws/src/dlo_policy/test/test_cli_errors.py::test_dlo_train_warns_when_no_update_will_happen",
    "ros_ws/src/dlo_policy/test/test_evaluate_scripted.py::test_the_same_episodes_as_run_episodes_seed_by_seed",
    "ros_ws/src/dlo_policy/test/test_evaluate_scripted.py::test_a_tiny_real_run_of_the_executable",
    "ros_ws/src/dlo_sim/test/test_rope_physics.py::test_reset_randomises_within_paper_ranges",
    "ros_ws/src/dlo_policy/test/test_env_cable_following.py::test_the_env_steps_the_simulator_backend_it_is_given",
)


def listed(nodeid: str, entries) -> bool:
    """True when ``nodeid`` (``path::test[param]``) is one of ``entries`` (a file or ``file::test``)."""
    path, _, rest = nodeid.partition("::")
    test = f"{path}::{rest.split('[', 1)[0]}" if rest else path
    return any(entry in (path, test) for entry in entries)


def _children(pid: int) -> list[int]:
    """The child processes of ``pid`` (Linux: /proc/PID/task/TID/children)."""
    import pathlib

    kids = []
    for task in pathlib.Path(f"/proc/{pid}/task").glob("*"):
        try:
            kids += [int(k) for k in (task / "children").read_text().split()]
        except OSError:  # the thread ended meanwhile
            pass
    return kids


def pytest_configure(config):
    """SIGTERM becomes KeyboardInterrupt: pytest then runs every fixture's teardown (stopping the node
    processes and graphs tests started) and exits 2, instead of dying with them still running.

    With xdist workers (``-n``) the controller passes the first SIGTERM on to its workers, where the tests
    and their fixtures live: each tears its fixtures down and reports an interrupted session, which stops
    the controller (exit 2) once every worker is done. Interrupting the controller itself instead would
    leave the workers to execnet's shutdown, which interrupts a worker 5 s later and kills it 5 s after
    that, in the middle of its teardown on a loaded machine. A second SIGTERM interrupts the controller."""
    import os
    import signal
    import threading

    forwarded = []

    def interrupt(signum, frame):
        dsession = config.pluginmanager.getplugin("dsession")  # xdist's controller side, when -n is given
        workers = _children(os.getpid()) if dsession is not None and not forwarded else []
        if not workers:
            raise KeyboardInterrupt(f"pytest got signal {signum}")
        forwarded.append(signum)
        for pid in workers:
            try:
                os.kill(pid, signum)
            except ProcessLookupError:
                pass

    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) == signal.SIG_DFL:
        signal.signal(signal.SIGTERM, interrupt)
    worker = getattr(config, "workerinput", {}).get("workerid")
    if worker and "TI_OFFLINE_CACHE_FILE_PATH" not in os.environ:
        os.environ["TI_OFFLINE_CACHE_FILE_PATH"] = worker_taichi_cache(worker)


def worker_taichi_cache(worker: str) -> str:
    """Taichi's offline kernel cache of one xdist worker (and the nodes its tests start): Taichi writes its
    cache as a process exits, under a lock it gives up on after a while, and the workers, which exit
    together, printed "Lock .../ticache.lock failed" under the result line with one shared cache."""
    import os

    home = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(home, "taichi", f"ticache-{worker}")


_DDS_SHM_BEFORE: list[set[str]] = []  # the session's snapshot of Fast DDS's /dev/shm files, once taken


def pytest_sessionstart(session):
    try:
        from harness import dds_shm_entries
    except ImportError:  # pytest without scripts/env.sh: nothing of ours to clean up after
        return
    _DDS_SHM_BEFORE.append(dds_shm_entries())


@pytest.hookimpl(trylast=True)  # after pytest's own, which tears down the fixtures an interrupt left set up
def pytest_sessionfinish(session, exitstatus):
    if _DDS_SHM_BEFORE:
        from harness import remove_orphaned_dds_shm

        remove_orphaned_dds_shm(_DDS_SHM_BEFORE[0])


def pytest_collection_modifyitems(config, items):
    import pytest

    for item in items:
        if GRAPH_FIXTURES.intersection(getattr(item, "fixturenames", ())) or listed(item.nodeid, GRAPH):
            item.add_marker(pytest.mark.graph)
        if listed(item.nodeid, SLOW):
            item.add_marker(pytest.mark.slow)
