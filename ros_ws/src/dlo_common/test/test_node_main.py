"""dlo_common.node_main.run_node: a node interrupted by SIGINT exits with its "interrupted" status and no
traceback. The signal is noted, never raised: a callback running when it comes finishes (a KeyboardInterrupt raised
inside rclpy left a half-built executor Task whose ``__del__`` printed "Exception ignored", and one raised while
rclpy converted a message became a RuntimeError), an rclpy error of the context the signal shut down is no error,
and a signal that came before rclpy could shut the context down still ends the node."""

import signal
import subprocess
import sys
import types

import pytest

from dlo_common import testing
from dlo_common.node_main import handle_help, params_file_problem, params_files, ros_arguments_problem

BUSY = '''import os, signal, sys, time
import rclpy.node, rclpy.task
from dlo_common.node_main import run_node


class Busy(rclpy.node.Node):
    def __init__(self):
        super().__init__("busy")
        self.create_timer(0.05, self.tick)

    def tick(self):  # goes on after the signal, building what rclpy's executor builds for every callback
        os.kill(os.getpid(), signal.SIGINT)
        os.kill(os.getpid(), signal.SIGINT)  # as a terminal's Ctrl-C and a launcher passing it on deliver it
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            rclpy.task.Task(lambda: None)
        print("the callback finished", flush=True)


sys.exit(run_node(Busy, [], interrupted_rc={rc}))
'''

LATE = '''import os, signal, sys, time
import rclpy, rclpy.node
from dlo_common.node_main import run_node


class Late(rclpy.node.Node):
    def __init__(self):
        super().__init__("late")
        self.create_timer(0.05, self.tick)

    def tick(self):  # makes a timer after the signal has shut the context down: rclpy raises RCLError
        os.kill(os.getpid(), signal.SIGINT)
        deadline = time.monotonic() + 60
        while rclpy.ok() and time.monotonic() < deadline:
            time.sleep(0.01)
        self.create_timer(1.0, lambda: None)


sys.exit(run_node(Late, [], interrupted_rc={rc}))
'''

STUCK = '''import sys, time
import rclpy.node
from dlo_common.node_main import run_node


class Stuck(rclpy.node.Node):
    def __init__(self):
        super().__init__("stuck")
        self.create_timer(0.05, self.tick)

    def tick(self):  # a driver waiting on hardware that never answers
        print("in the callback", flush=True)
        while True:
            time.sleep(0.01)


sys.exit(run_node(Stuck, [], interrupted_rc={rc}))
'''

QUIET = '''import sys, threading, time
import rclpy, rclpy.node
from dlo_common.node_main import run_node


def make():  # an idle node whose context goes down without waking its executor, as after rclpy's SIGINT handling
    node = rclpy.node.Node("quiet")
    context = rclpy.get_default_context()

    def shut_down_unseen():
        time.sleep(0.5)
        with context._Context__context:
            context._Context__context.shutdown()

    threading.Thread(target=shut_down_unseen, daemon=True).start()
    return node


sys.exit(run_node(make, [], interrupted_rc={rc}))
'''

EARLY = '''import signal, sys
import rclpy.node
from dlo_common.node_main import run_node


def make():  # the signal as it comes before rclpy's handler is set or the context made: only noted, none shut down
    signal.getsignal(signal.SIGINT)(signal.SIGINT, None)
    return rclpy.node.Node("early")


sys.exit(run_node(make, [], interrupted_rc={rc}))
'''


FAULTY = '''import sys
import rclpy.node
from dlo_common.node_main import run_node


class Faulty(rclpy.node.Node):
    def __init__(self):
        super().__init__("faulty")
        self.create_timer(0.05, self.tick)

    def tick(self):
        raise RuntimeError("a real bug")


sys.exit(run_node(Faulty, []))
'''


STOPS_ITSELF = '''import ctypes, io, os, signal, sys, time
import rclpy.node
from dlo_common import node_main


class StopsItself(rclpy.node.Node):  # named after its class; sends itself a SIGINT once it spins
    def __init__(self):
        super().__init__(type(self).__name__.lower())
        self.create_timer(0.05, lambda: os.kill(os.getpid(), signal.SIGINT))
'''

HUNG = STOPS_ITSELF + '''
node_main.TEARDOWN_LIMIT = 1.0


class Hung(StopsItself):
    def finish(self):  # the node's own closing work (saving a run): longer than the limit, and not cut
        time.sleep(2 * node_main.TEARDOWN_LIMIT)
        print("finished", flush=True)

    def destroy_node(self):  # the middleware's teardown stuck in C code that holds the GIL (Fast DDS's deadlock)
        ctypes.PyDLL(None).sleep(120)


sys.exit(node_main.run_node(Hung, [], interrupted_rc={rc}))
'''

UNFINISHED = STOPS_ITSELF + '''

class Unfinished(StopsItself):
    def finish(self):  # saving the run on a full disk
        raise OSError(28, "No space left on device")

    def destroy_node(self):
        print("destroyed", flush=True)
        super().destroy_node()


sys.exit(node_main.run_node(Unfinished, [], interrupted_rc={rc}))
'''

GOES_ON = STOPS_ITSELF + '''
node_main.TEARDOWN_LIMIT = 0.5


class Quick(StopsItself):
    pass


print(node_main.run_node(Quick, []), flush=True)
time.sleep(4 * node_main.TEARDOWN_LIMIT)  # a caller that goes on after run_node (a test, a tool)
print("still running", flush=True)
sys.stderr = io.StringIO()  # a test's capture: no file descriptor
with node_main.bounded():
    time.sleep(120)
'''


def default_sigint():
    """SIGINT at its default in the node, as in a terminal (a test run in the background inherits it ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def run_script(script, rc):
    return subprocess.run([sys.executable, "-c", script.format(rc=rc)], env=testing.isolated_env(),
                          capture_output=True, text=True, timeout=300, preexec_fn=default_sigint)


@pytest.mark.parametrize("rc", [0, 130])
def test_a_sigint_lets_the_running_callback_finish_then_ends_the_node_without_a_word(rc):
    pytest.importorskip("rclpy")
    for _ in range(3):
        result = run_script(BUSY, rc)
        assert (result.returncode, result.stderr) == (rc, ""), result.stderr
        assert "the callback finished" in result.stdout


@pytest.mark.parametrize("rc", [0, 130])
def test_a_callback_that_never_finishes_is_interrupted_by_a_later_second_sigint(rc):
    pytest.importorskip("rclpy")
    import time

    from dlo_common.node_main import FORCE_AFTER
    proc = subprocess.Popen([sys.executable, "-c", STUCK.format(rc=rc)], env=testing.isolated_env(), text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, preexec_fn=default_sigint)
    try:
        assert proc.stdout.readline() == "in the callback\n"
        proc.send_signal(signal.SIGINT)
        time.sleep(FORCE_AFTER + 0.5)
        assert proc.poll() is None  # the first SIGINT waits for the callback
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == rc
    assert err == f"[stuck] stopped by a second SIGINT: a callback had not finished {FORCE_AFTER:g} s after the first\n"


@pytest.mark.parametrize("rc", [0, 130])
def test_an_idle_node_whose_context_goes_down_without_waking_its_executor_ends(rc):
    """rclpy's SIGINT handling wakes the executor before it shuts the context down: an executor that looked in
    between waited again, for good on an idle node (a tactile node after its simulator had gone hung so)."""
    pytest.importorskip("rclpy")
    result = run_script(QUIET, rc)
    assert (result.returncode, result.stderr) == (rc, ""), result.stderr


@pytest.mark.parametrize("rc", [0, 130])
def test_an_rclpy_error_of_the_context_a_sigint_shut_down_ends_the_node_as_interrupted(rc):
    pytest.importorskip("rclpy")
    result = run_script(LATE, rc)
    assert (result.returncode, result.stderr) == (rc, ""), result.stderr


@pytest.mark.parametrize("rc", [0, 130])
def test_a_sigint_noted_before_rclpy_could_shut_the_context_down_ends_the_node(rc):
    pytest.importorskip("rclpy")
    result = run_script(EARLY, rc)  # (without the note's check it would spin until the timeout)
    assert (result.returncode, result.stderr) == (rc, ""), result.stderr


@pytest.mark.parametrize("rc", [0, 130])
def test_a_middleware_teardown_that_hangs_holding_the_gil_ends_the_process_after_the_limit(rc):
    """Fast DDS can deadlock destroying a participant while its peers leave (about 1 in 100 stops of a graph):
    the node must still exit, with 1 and the stacks, once TEARDOWN_LIMIT s have passed (not after the 120 s
    its teardown would take); the node's finish() runs before the limit starts, however long it takes."""
    pytest.importorskip("rclpy")
    result = run_script(HUNG, rc)
    assert result.returncode == 1, result.stderr
    assert "finished\n" in result.stdout  # (Fast DDS may print its own lines there)
    assert result.stderr.startswith("Timeout (0:00:01)!\n"), result.stderr
    assert "in shut_down" in result.stderr and "in run_node" in result.stderr, result.stderr


def test_the_teardown_limit_ends_with_the_teardown_and_reports_on_fd_2_when_stderr_has_none():
    """After a teardown in time the watchdog is gone (a caller of run_node goes on as long as it likes); a block
    of bounded() run with sys.stderr replaced by an object without a descriptor still ends, reported on fd 2."""
    pytest.importorskip("rclpy")
    result = run_script(GOES_ON, 0)
    assert result.stdout.splitlines()[-2:] == ["0", "still running"], result.stdout + result.stderr
    assert result.returncode == 1 and result.stderr.startswith("Timeout (0:00:00.500000)!\n"), result.stderr


@pytest.mark.parametrize("rc", [0, 130])
def test_a_finish_that_fails_is_one_line_and_exit_1_and_the_node_is_still_torn_down(rc):
    pytest.importorskip("rclpy")
    result = run_script(UNFINISHED, rc)
    assert result.returncode == 1, result.stderr
    assert result.stderr == "[unfinished] could not finish: OSError: [Errno 28] No space left on device\n"
    assert "destroyed\n" in result.stdout


def test_an_error_in_a_callback_without_a_signal_is_a_traceback():
    pytest.importorskip("rclpy")
    result = subprocess.run([sys.executable, "-c", FAULTY], env=testing.isolated_env(), capture_output=True,
                            text=True, timeout=120)
    assert result.returncode == 1 and "RuntimeError: a real bug" in result.stderr, result.stderr


def test_run_node_destroys_the_node_it_built_also_when_the_context_was_shut_down_under_it(monkeypatch):
    """A clean shutdown for a caller in the same process: once run_node returns, the node it built is destroyed
    (its entities gone from the graph), also when something else shut the context down while it spun."""
    pytest.importorskip("rclpy")
    import rclpy
    from rclpy.node import Node

    from dlo_common.node_main import run_node
    built = []

    def make():
        built.append(Node("stopper"))
        built[0].create_timer(0.05, rclpy.try_shutdown)
        return built[0]

    with testing.reserved_domain() as domain:
        monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
        assert run_node(make, ["stopper"], interrupted_rc=130) == 130
    with pytest.raises(Exception, match="destruction was requested"):
        built[0].get_name()


def test_params_files_are_those_inside_ros_args_only():
    """`--params-file F` counts between `--ros-args` and `--` (or the end), as rcl reads it; a trailing one has no file."""
    argv = ["--params-file", "before.yaml", "--ros-args", "-p", "x:=1", "--params-file", "a.yaml", "--",
            "--params-file", "app.yaml", "--ros-args", "--params-file", "b.yaml", "--params-file"]
    assert params_files(argv) == ["a.yaml", "b.yaml"]
    assert params_files(["--params-file", "x.yaml"]) == []


def write(tmp_path, text, name="params.yaml"):
    path = tmp_path / name
    path.write_bytes(text.encode() if isinstance(text, str) else text)
    return str(path)


def test_a_utf8_params_file_is_read_as_utf8_in_a_c_locale(tmp_path):
    """A comment with a non-ASCII character (µm) in a container whose locale is C (no UTF-8 coercion): the file is
    UTF-8, as rcl reads it, not the locale's ASCII; a file that is not UTF-8 is a one-line 'cannot read it'."""
    good = write(tmp_path, "# the grip in \u00b5m\n/**:\n  ros__parameters:\n    a: 1\n")
    latin = write(tmp_path, b"# \xb5m\n/**:\n  ros__parameters:\n    a: 1\n", "latin1.yaml")
    env = dict(testing.isolated_env(), LC_ALL="C", LANG="C", PYTHONUTF8="0", PYTHONCOERCECLOCALE="0")
    code = ("import sys; from dlo_common.node_main import params_file_problem as p; "
            "print(repr(p(sys.argv[1])), repr(p(sys.argv[2])))")
    result = subprocess.run([sys.executable, "-c", code, good, latin], env=env, capture_output=True, text=True,
                            timeout=120)
    assert result.returncode == 0, result.stderr
    good_problem, latin_problem = (eval(x) for x in result.stdout.split(" ", 1))  # noqa: S307 - our own reprs
    assert good_problem == ""
    assert latin_problem.startswith("cannot read it (") and "utf-8" in latin_problem and "\n" not in latin_problem


def test_yaml_errors_name_their_line_also_a_character_yaml_does_not_allow(tmp_path):
    syntax = write(tmp_path, "/**:\n  ros__parameters:\n    a: [1\n    b: 2\n", "syntax.yaml")
    assert params_file_problem(syntax) == "YAML syntax error at line 4: expected ',' or ']', but got ':'"
    bell = write(tmp_path, "/**:\n  ros__parameters:\n    a: 1\n    b: \x07\n", "bell.yaml")
    assert params_file_problem(bell) == ("YAML syntax error at line 4: unacceptable character #x0007: special "
                                         "characters are not allowed")


def test_an_empty_section_is_named_by_its_whole_path(tmp_path):
    top = write(tmp_path, "/**:\n  ros__parameters:\n", "top.yaml")
    assert "('/**: ros__parameters:' holds no parameters" in params_file_problem(top)
    nested = write(tmp_path, "robot:\n  sim_node:\n    ros__parameters:\n", "nested.yaml")
    assert "('robot/sim_node: ros__parameters:' holds no parameters" in params_file_problem(nested)


def test_every_yaml_document_of_a_params_file_is_checked_as_rcl_reads_them_all(tmp_path):
    two = "/**:\n  ros__parameters:\n    a: 1\n---\nsim_node:\n  ros__parameters:\n    b: 2\n"
    assert params_file_problem(write(tmp_path, two, "two.yaml")) == ""  # rcl takes it: so do we
    listed = "/**:\n  ros__parameters:\n    a: 1\n---\n- 1\n"
    assert params_file_problem(write(tmp_path, listed, "listed.yaml")).startswith(
        "wrong layout (the file holds a list)")


def test_an_rcl_refusal_without_a_line_is_one_line_without_one(tmp_path):
    """rcl names no line for a node name it refuses ('sim-node' for sim_node)."""
    pytest.importorskip("rclpy")
    path = write(tmp_path, "sim-node:\n  ros__parameters:\n    a: 1\n")
    assert ros_arguments_problem(["x", "--ros-args", "--params-file", path]) == (
        f"params file {path}: rcl cannot read it: node name must not contain characters other than alphanumerics "
        "or '_'")


def test_help_reads_the_arguments_it_is_given_and_sys_argv_only_without(monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["sim_node"])
    assert handle_help("dlo_sim", [], args=["--help"]) == 0
    assert "sim_node" in capsys.readouterr().out
    monkeypatch.setattr(sys, "argv", ["sim_node", "--help"])
    assert handle_help("dlo_sim", [], args=[]) is None
    assert handle_help("dlo_sim", []) == 0
    monkeypatch.setattr(sys, "argv", ["sim_node", "stray"])
    assert handle_help("dlo_sim", []) == 2
    assert "unexpected argument 'stray'" in capsys.readouterr().err


def test_explicit_arguments_may_start_with_the_program_name(monkeypatch):
    """`run_node(make, args=sys.argv)` passes the program name first: it is no stray argument (only sys.argv[1:]
    is checked for those)."""
    pytest.importorskip("rclpy")
    monkeypatch.setattr(sys, "argv", ["sim_node"])
    assert handle_help("dlo_sim", [], args=["sim_node", "--ros-args", "-p", "x:=1"]) is None


def make_nothing():  # never called: --help answers before any node is built
    raise AssertionError("a node was built for --help")


@pytest.mark.parametrize(("interrupted_rc", "codes"), [
    (0, "Exit codes: 0 done or stopped by a signal, 1 failed (see stderr), 2 bad parameter, 3 refused to start."),
    (130, "Exit codes: 0 done or stopped by a signal (130), 1 failed (see stderr), 2 bad parameter, 3 refused to "
          "start.")])
def test_help_names_the_package_and_the_exit_code_of_an_interruption(monkeypatch, capsys, interrupted_rc, codes):
    from dlo_common.node_main import run_node
    monkeypatch.setattr(sys, "argv", ["sim_node", "--help"])
    monkeypatch.setattr(make_nothing, "__module__", "dlo_bag.recorder_node")  # the package is the module's first part
    assert run_node(make_nothing, parameters=[], interrupted_rc=interrupted_rc) == 0
    out = capsys.readouterr().out
    assert "ros2 run dlo_bag sim_node" in out and codes in out.splitlines()
    # run as `python -m dlo_sim.sim_node`: the make function's module is __main__, the package is the spec's
    monkeypatch.setattr(make_nothing, "__module__", "__main__")
    monkeypatch.setattr(sys.modules["__main__"], "__spec__", types.SimpleNamespace(name="dlo_sim.sim_node"),
                        raising=False)
    assert run_node(make_nothing, parameters=[], interrupted_rc=interrupted_rc) == 0
    assert "ros2 run dlo_sim sim_node" in capsys.readouterr().out


def refusing_probe(seen):
    """A make_node that builds a node, notes the `answer` parameter it got, and refuses to start (exit 3)."""
    import rclpy.node

    from dlo_common.node_util import NodeStartError

    def make():
        node = rclpy.node.Node("probe")
        seen.append(node.declare_parameter("answer", 0).value)
        node.destroy_node()
        raise NodeStartError("refused")
    return make


def test_run_node_gives_rcl_its_own_arguments_and_runs_in_a_thread(monkeypatch, capsys):
    """The arguments passed to run_node reach rcl (not sys.argv's) and its SIGINT handler is put back on return;
    run from a thread that is not the main one (no signal handler may be set there) it still builds, refuses and
    returns its exit code, also after an earlier run in the same process (the context was shut down)."""
    pytest.importorskip("rclpy")
    import threading

    from dlo_common.node_main import run_node
    with testing.reserved_domain() as domain:
        monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
        monkeypatch.setattr(sys, "argv", ["probe", "--ros-args", "-p", "answer:=1"])
        seen, results = [], []
        before = signal.signal(signal.SIGINT, signal.default_int_handler)  # as in a terminal
        try:
            assert run_node(refusing_probe(seen), ["probe", "--ros-args", "-p", "answer:=42"]) == 3
            assert signal.getsignal(signal.SIGINT) is signal.default_int_handler  # its own handler is gone again
            thread = threading.Thread(target=lambda: results.append(run_node(refusing_probe(seen), [])))
            thread.start()
            thread.join(60)
        finally:
            signal.signal(signal.SIGINT, before)
    assert seen == [42, 0] and results == [3]
    assert capsys.readouterr().err.count("] refused") == 2
