"""dlo_common.node_main.run_node keeps the promises its module docstring numbers; each test names the promise it
holds. A SIGINT or SIGTERM requests the stop and is never raised: a callback running when it comes finishes (a
KeyboardInterrupt raised inside rclpy left a half-built executor Task whose ``__del__`` printed "Exception ignored",
and one raised while rclpy converted a message became a RuntimeError); one sent again later interrupts the node's own
code, never rclpy's; finish() runs with the node and its context up; the teardown shuts down the context run_node
made, no other, and notes a late signal only; afterwards SIGINT and SIGTERM are the caller's again."""

import signal
import subprocess
import sys
import types

import harness as testing
import pytest
from dlo_common.node_main import handle_help, params_file_problem, params_files, ros_arguments_problem

BUSY = """import os, signal, sys, time
import rclpy.node, rclpy.task
from std_msgs.msg import String
from dlo_common.node_main import run_node


class Busy(rclpy.node.Node):
    def __init__(self):
        super().__init__("busy")
        self.publisher = self.create_publisher(String, "busy", 1)
        self.create_timer(0.05, self.tick)
        self.ticks = 0

    def tick(self):  # goes on after the signal, building what rclpy's executor builds for every callback
        self.ticks += 1
        os.kill(os.getpid(), signal.{sig})
        os.kill(os.getpid(), signal.{sig})  # as a terminal's Ctrl-C and a launcher passing it on deliver it
        deadline = time.monotonic() + 0.5
        while time.monotonic() < deadline:
            rclpy.task.Task(lambda: None)
        self.publisher.publish(String(data="after the signal"))  # (the context is still up: no RCLError)
        print("the callback finished", flush=True)

    def finish(self):
        print(f"callbacks run: {{self.ticks}}", flush=True)


sys.exit(run_node(Busy, [], interrupted_rc={rc}))
"""

LATE = """import os, signal, sys, time
import rclpy, rclpy.node
from dlo_common.node_main import run_node


class Late(rclpy.node.Node):
    def __init__(self):
        super().__init__("late")
        self.create_timer(0.05, self.tick)

    def tick(self):  # SIGINT ignored at the start: rclpy's handler takes it and shuts the context down under the callback
        os.kill(os.getpid(), signal.SIGINT)
        deadline = time.monotonic() + 10
        while rclpy.ok() and time.monotonic() < deadline:
            time.sleep(0.01)
        if rclpy.ok():
            print("the SIGINT did not shut the context down", flush=True)
            os._exit(9)
        self.create_timer(1.0, lambda: None)  # rclpy raises RCLError: the context is shut down


sys.exit(run_node(Late, [], interrupted_rc={rc}))
"""

THREADED = """import os, signal, sys, threading, time
import rclpy, rclpy.node
from dlo_common.node_main import run_node


class Threaded(rclpy.node.Node):  # run_node in a thread: only the main thread may set handlers, rclpy's take the signals
    def __init__(self):
        super().__init__("threaded")
        self.create_timer(0.05, lambda: os.kill(os.getpid(), signal.{sig}))


for sig in (signal.SIGINT, signal.SIGTERM):  # (rclpy's handler passes the signal on to these)
    signal.signal(sig, lambda signum, frame: print(signal.Signals(signum).name, "in the main thread", flush=True))
results = []
thread = threading.Thread(target=lambda: results.append(run_node(Threaded, [], interrupted_rc={rc})), daemon=True)
thread.start()
thread.join(60)
print("run_node returned", results, flush=True)
"""

CALLERS_SIGTERM = """import os, signal, sys, time
import rclpy, rclpy.node
from dlo_common.node_main import run_node


class Callers(rclpy.node.Node):
    def __init__(self):
        super().__init__("callers")
        self.create_timer(0.05, self.tick)
        self.ticks = 0

    def tick(self):
        self.ticks += 1
        if self.ticks == 1:
            os.kill(os.getpid(), signal.SIGTERM)
        if self.ticks == 200:
            print("the SIGTERM did not stop the node", flush=True)
            os._exit(9)


signal.signal(signal.SIGTERM, lambda *_: print("the caller's SIGTERM handler", flush=True))
sys.exit(run_node(Callers, [], interrupted_rc={rc}))
"""

STUCK = """import sys, time
import rclpy.node
from dlo_common.node_main import run_node


class Stuck(rclpy.node.Node):
    def __init__(self):
        super().__init__("stuck")
        self.create_timer(0.05, self.tick)

    def tick(self):  # a driver waiting on hardware that never answers (the signal finds it in its own frame)
        print("in the callback", flush=True)
        while True:
            time.sleep(3600)


sys.exit(run_node(Stuck, [], interrupted_rc={rc}))
"""

QUIET = """import sys, threading, time
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
"""

EARLY = """import signal, sys
import rclpy.node
from dlo_common.node_main import run_node


def make():  # a signal while the node is being built (called as Python calls it): noted, the node never spins
    signal.getsignal(signal.SIGINT)(signal.SIGINT, None)
    return rclpy.node.Node("early")


sys.exit(run_node(make, [], interrupted_rc={rc}))
"""


FAULTY = """import sys
import rclpy.node
from dlo_common.node_main import run_node


class Faulty(rclpy.node.Node):
    def __init__(self):
        super().__init__("faulty")
        self.create_timer(0.05, self.tick)

    def tick(self):
        raise RuntimeError("a real bug")


sys.exit(run_node(Faulty, []))
"""


STOPS_ITSELF = """import ctypes, io, os, signal, sys, time
import rclpy.node
from dlo_common import node_main


class StopsItself(rclpy.node.Node):  # named after its class; sends itself a SIGINT once it spins
    def __init__(self):
        super().__init__(type(self).__name__.lower())
        self.create_timer(0.05, lambda: os.kill(os.getpid(), signal.SIGINT))
"""

HUNG = (
    STOPS_ITSELF
    + """
node_main.TEARDOWN_LIMIT = 1.0


class Hung(StopsItself):
    def finish(self):  # the node's own closing work (saving a run): longer than the limit, and not cut
        time.sleep(2 * node_main.TEARDOWN_LIMIT)
        print("finished", flush=True)

    def destroy_node(self):  # the middleware's teardown stuck in C code that holds the GIL (Fast DDS's deadlock)
        ctypes.PyDLL(None).sleep(120)


sys.exit(node_main.run_node(Hung, [], interrupted_rc={rc}))
"""
)

UNFINISHED = (
    STOPS_ITSELF
    + """

class Unfinished(StopsItself):
    def finish(self):  # saving the run on a full disk
        raise OSError(28, "No space left on device")

    def destroy_node(self):
        print("destroyed", flush=True)
        super().destroy_node()


sys.exit(node_main.run_node(Unfinished, [], interrupted_rc={rc}))
"""
)

GOES_ON = (
    STOPS_ITSELF
    + """
node_main.TEARDOWN_LIMIT = 0.5


class Quick(StopsItself):
    pass


print(node_main.run_node(Quick, []), flush=True)
time.sleep(4 * node_main.TEARDOWN_LIMIT)  # a caller that goes on after run_node (a test, a tool)
print("still running", flush=True)
sys.stderr = io.StringIO()  # a test's capture: no file descriptor
with node_main.bounded():
    time.sleep(120)
"""
)


TASKS = """import dis, os, signal, sys, threading, time, traceback
import rclpy.node, rclpy.task
from dlo_common import node_main

node_main.FORCE_AFTER = 0.2
TASK_INIT = rclpy.task.Task.__init__.__code__
# Where the main thread stands in rclpy's Task constructor before Future.__init__ has set the task's _exception: at the
# constructor's start and right after its call of super(). A signal that comes then is handled at the main thread's
# next check, mostly still before _exception exists: after super() returns, or as Future.__init__ starts.
BEFORE_FUTURE_INIT = {{TASK_INIT.co_firstlineno,
                      next(i.positions.lineno for i in dis.get_instructions(TASK_INIT) if i.opname == "CALL")}}


def sigint_inside_the_task_constructor(main):
    sys.setswitchinterval(1e-6)  # the main thread hands the GIL over at almost every check it makes
    while True:
        frame = sys._current_frames().get(main)
        if frame is not None and frame.f_code is TASK_INIT and frame.f_lineno in BEFORE_FUTURE_INIT:
            signal.raise_signal(signal.SIGINT)
            sys.setswitchinterval(0.005)
            return
        time.sleep(0)  # (gives the GIL back)


def sigint_as_future_init_starts(frame, event, arg):  # a profile function: the late SIGINT as Python handles it when
    if event == "call" and frame.f_code is rclpy.task.Future.__init__.__code__:  # it comes at Future.__init__'s start
        sys.setprofile(None)
        signal.getsignal(signal.SIGINT)(signal.SIGINT, frame)  # (its handler, with the frame that runs)


class Tasks(rclpy.node.Node):
    def __init__(self):
        super().__init__("tasks")
        self.create_timer(0.05, self.tick)

    def tick(self):  # goes on after the first SIGINT building executor tasks; a later SIGINT comes in their constructor
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(2 * node_main.FORCE_AFTER)
        if {from_thread}:
            threading.Thread(target=sigint_inside_the_task_constructor, args=(threading.get_ident(),), daemon=True).start()
        else:
            sys.setprofile(sigint_as_future_init_starts)
        deadline = time.monotonic() + 60
        try:
            while time.monotonic() < deadline:
                rclpy.task.Task(lambda: None)
        except KeyboardInterrupt as interrupt:  # where: the innermost frame not node_main's (its handler, its tracer)
            where = [f.filename for f in traceback.extract_tb(interrupt.__traceback__) if "node_main" not in f.filename]
            print("interrupted", "inside rclpy" if "/rclpy/" in where[-1] else "outside rclpy", flush=True)
            raise
        print("never interrupted", flush=True)


sys.exit(node_main.run_node(Tasks, [], interrupted_rc={rc}))
"""

LANDING = """import functools, os, signal, sys, time, traceback
import rclpy.node, rclpy.task
from dlo_common import node_main

node_main.FORCE_AFTER = 0.2


def found_in_rclpy(future):  # called by rclpy's add_done_callback: the late SIGINT, its handler called as Python
    signal.getsignal(signal.SIGINT)(signal.SIGINT, sys._getframe(1))  # calls it while add_done_callback runs


def keep(value):  # the node's own code
    return value


def builds(future):  # a done-callback: the node's code again, called by rclpy's add_done_callback
    keep(future.add_done_callback(found_in_rclpy))


class Landing(rclpy.node.Node):
    def __init__(self):
        super().__init__("landing")
        self.create_timer(0.05, self.tick)

    def tick(self):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(2 * node_main.FORCE_AFTER)
        done = rclpy.task.Future()
        done.set_result(None)  # (add_done_callback calls back at once)
        try:
            {build}
            print("never interrupted", flush=True)
        except KeyboardInterrupt as interrupt:  # where: the innermost frame not node_main's (its handler, its tracer)
            where = [f.name for f in traceback.extract_tb(interrupt.__traceback__) if "node_main" not in f.filename]
            print("interrupted in", where[-1], flush=True)
            raise


# a trace function of the process's own (as coverage's), in C: no Python frame of its own
BEFORE = functools.partial(print, file=open(os.devnull, "w")) if {traced} else None
sys.settrace(BEFORE)
rc = node_main.run_node(Landing, [], interrupted_rc={rc})
print("the trace function before run_node is back:", sys.gettrace() is BEFORE, flush=True)
sys.exit(rc)
"""

DONE_CALLBACK = """import os, signal, sys, threading, time, traceback
import rclpy.node, rclpy.task
from dlo_common import node_main

node_main.FORCE_AFTER = 0.2


def arms_then_sleeps(future):  # a done-callback rclpy calls: a late SIGINT, its handler called as Python calls it while
    signal.getsignal(signal.SIGINT)(signal.SIGINT, sys._getframe(1))  # add_done_callback runs (it waits for tick);
    time.sleep(3600)  # then this callback, the node's code but not tick, never returns


def third_sigint(main):  # once the main thread sleeps in arms_then_sleeps
    while sys._current_frames()[main].f_code is not arms_then_sleeps.__code__:
        time.sleep(0.01)
    signal.pthread_kill(main, signal.SIGINT)


class DoneCallback(rclpy.node.Node):
    def __init__(self):
        super().__init__("done_callback")
        self.create_timer(0.05, self.tick)

    def tick(self):
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(2 * node_main.FORCE_AFTER)
        threading.Thread(target=third_sigint, args=(threading.get_ident(),), daemon=True).start()
        done = rclpy.task.Future()
        done.set_result(None)  # (add_done_callback calls back at once)
        try:
            done.add_done_callback(arms_then_sleeps)
        except KeyboardInterrupt as interrupt:  # where: the innermost frame not node_main's
            where = [f.name for f in traceback.extract_tb(interrupt.__traceback__) if "node_main" not in f.filename]
            print("interrupted in", where[-1], flush=True)
            raise


sys.exit(node_main.run_node(DoneCallback, [], interrupted_rc={rc}))
"""

BUILDING = """import os, signal, sys, time
import rclpy.node
from dlo_common import node_main

node_main.FORCE_AFTER = 0.2
sys.argv[0] = "building_node"


def make():  # a driver that waits, while it is being built, for hardware that never answers
    node = rclpy.node.Node("building")
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(2 * node_main.FORCE_AFTER)
    os.kill(os.getpid(), signal.SIGINT)
    for _ in range(6000):
        time.sleep(0.01)
    print("never interrupted", flush=True)
    return node


sys.exit(node_main.run_node(make, [], interrupted_rc={rc}))
"""

FINISHING = (
    STOPS_ITSELF
    + """
from std_msgs.msg import String
node_main.FORCE_AFTER = 0.2


class Finishing(StopsItself):
    def finish(self):  # closing work that never ends (a save to a hung network disk), after a late second SIGINT
        time.sleep(2 * node_main.FORCE_AFTER)
        os.kill(os.getpid(), signal.SIGINT)
        for _ in range(6000):
            time.sleep(0.01)
        print("never interrupted", flush=True)

    def destroy_node(self):
        print("destroyed", flush=True)
        super().destroy_node()


sys.exit(node_main.run_node(Finishing, [], interrupted_rc={rc}))
"""
)

CONTEXTS = (
    STOPS_ITSELF
    + """
from std_msgs.msg import String

other = rclpy.Context()  # a context of the process's own, beside run_node's
rclpy.init(context=other)
built = []


class Contexts(StopsItself):
    def finish(self):  # after the SIGINT: publishes a last message, with the node and its context up
        self.create_publisher(String, "last_words", 1).publish(String(data="done"))
        print("finish: default context", self.context is rclpy.get_default_context(), "up", self.context.ok(),
              "other up", other.ok(), flush=True)


def make():
    built.append(Contexts())
    return built[0]


rc = node_main.run_node(make, [], interrupted_rc={rc})
print("after: the node's context up", built[0].context.ok(), "other up", other.ok(), flush=True)
rclpy.try_shutdown(context=other)
sys.exit(rc)
"""
)

TEARDOWN = (
    STOPS_ITSELF
    + """
node_main.FORCE_AFTER = 0.2


class Teardown(StopsItself):
    def destroy_node(self):  # the middleware's teardown taking its time while late signals come
        for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGINT):
            time.sleep(2 * node_main.FORCE_AFTER)
            os.kill(os.getpid(), sig)
        print("destroyed", flush=True)
        super().destroy_node()


sys.exit(node_main.run_node(Teardown, [], interrupted_rc={rc}))
"""
)

AFTERWARDS = (
    STOPS_ITSELF
    + """

class Quick(StopsItself):
    pass


rc = node_main.run_node(Quick, [], interrupted_rc={rc})
print("run_node returned", rc, flush=True)
try:
    os.kill(os.getpid(), signal.SIGINT)
    time.sleep(5)
except KeyboardInterrupt:
    print("KeyboardInterrupt in the caller", flush=True)
os.kill(os.getpid(), signal.SIGTERM)
time.sleep(5)
print("the SIGTERM was swallowed", flush=True)
sys.exit(rc)
"""
)

EXITING = """import sys
import rclpy.node
from dlo_common.node_main import run_node


class Exiting(rclpy.node.Node):
    def __init__(self):
        super().__init__("exiting")
        self.create_timer(0.05, self.tick)

    def tick(self):  # as sim_node after its last episode
        raise SystemExit(5)

    def finish(self):
        print("finished", flush=True)

    def destroy_node(self):
        print("destroyed", flush=True)
        super().destroy_node()


sys.exit(run_node(Exiting, []))
"""


def default_signals():
    """SIGINT and SIGTERM at their defaults in the node, as in a terminal (a test run in the background inherits
    SIGINT ignored)."""
    signal.signal(signal.SIGINT, signal.SIG_DFL)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def sigint_ignored():
    """SIGINT ignored in the node, as in a background job of a shell."""
    default_signals()
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def run_script(script, rc, preexec_fn=default_signals, **fields):
    return subprocess.run(
        [sys.executable, "-c", script.format(rc=rc, **fields)],
        env=testing.isolated_env(),
        capture_output=True,
        text=True,
        timeout=300,
        preexec_fn=preexec_fn,
    )


@pytest.mark.parametrize(("sig", "rc"), [("SIGINT", 0), ("SIGINT", 130), ("SIGTERM", 130)])
def test_a_first_signal_lets_the_running_callback_finish_with_the_context_up_then_ends_the_node_without_a_word(sig, rc):
    """Promises 3 and 4: the callback running at the first SIGINT/SIGTERM (two copies, as a terminal and a launcher
    deliver them) finishes, and what it publishes then is published (rclpy's handler had shut the context down under
    it: RCLError); no other callback runs; no word, the interrupted exit code."""
    pytest.importorskip("rclpy")
    result = run_script(BUSY, rc, sig=sig)
    assert (result.returncode, result.stderr) == (rc, ""), result.stderr
    assert "the callback finished\n" in result.stdout and "callbacks run: 1\n" in result.stdout, result.stdout


@pytest.mark.parametrize(("sig", "rc"), [("SIGINT", 0), ("SIGINT", 130), ("SIGTERM", 130)])
def test_a_callback_that_never_finishes_is_interrupted_by_a_later_second_signal(sig, rc):
    """Promise 5: a second SIGINT or SIGTERM FORCE_AFTER s after the first interrupts a callback stuck in its own code
    at once, inside its sleep (rclpy's SIGTERM handler never did: the node hung); the first waits for it."""
    pytest.importorskip("rclpy")
    import time

    from dlo_common.node_main import FORCE_AFTER

    proc = subprocess.Popen(
        [sys.executable, "-c", STUCK.format(rc=rc)],
        env=testing.isolated_env(),
        text=True,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        preexec_fn=default_signals,
    )
    try:
        assert proc.stdout.readline() == "in the callback\n"
        proc.send_signal(getattr(signal, sig))
        time.sleep(FORCE_AFTER + 0.5)
        assert proc.poll() is None  # the first signal waits for the callback
        proc.send_signal(getattr(signal, sig))
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == rc
    assert err == f"[stuck] stopped by a second {sig}: a callback had not finished {FORCE_AFTER:g} s after the first\n"


@pytest.mark.parametrize(("rc", "from_thread"), [(0, False), (130, False), (130, True)])
def test_a_late_sigint_that_comes_inside_rclpys_task_constructor_is_not_raised_there(rc, from_thread):
    """Promise 5, issue 38 item 9: a late SIGINT handled while rclpy's Task constructor runs, before Future.__init__
    has set the task's _exception: its handler called as Python calls it at Future.__init__'s first instruction
    (from a profile function), or a SIGINT sent from a thread while the main thread stands in the constructor (Python
    handles it at a check of the main thread soon after: mostly still before _exception exists). Raised there, it left
    a half-built task whose Future.__del__ printed "Exception ignored in: <function Future.__del__ ...>
    AttributeError" (before the change: every run from the profile function, most from the thread); now it
    interrupts the callback outside rclpy."""
    pytest.importorskip("rclpy")
    result = run_script(TASKS, rc, from_thread=from_thread)
    assert "Exception ignored" not in result.stderr, result.stderr
    assert result.returncode == rc, result.stderr
    assert result.stderr == "[tasks] stopped by a second SIGINT: a callback had not finished 0.2 s after the first\n"
    assert "interrupted outside rclpy\n" in result.stdout, result.stdout


@pytest.mark.parametrize(
    ("build", "where", "traced"),
    [("keep(done.add_done_callback(found_in_rclpy))", "keep", False), ("done.add_done_callback(builds)", "tick", True)],
)
def test_a_late_sigint_that_finds_rclpys_code_waits_for_the_next_line_of_the_nodes_own_code(build, where, traced):
    """Promise 5: a late SIGINT found while rclpy's add_done_callback runs (its handler called as Python calls it, with
    that frame) waits until rclpy has returned to the callback: raised as the callback calls keep() on the same line,
    never in a function rclpy calls. Where add_done_callback runs in a done-callback that rclpy called from the
    callback, it waits for the callback itself (its next line), never raised through the rclpy call between them.
    The trace function it sets meanwhile is gone afterwards; one of the process's own (coverage's) is back."""
    pytest.importorskip("rclpy")
    result = run_script(LANDING, 130, build=build, traced=traced)
    assert (result.returncode, result.stderr) == (
        130,
        "[landing] stopped by a second SIGINT: a callback had not finished 0.2 s after the first\n",
    )
    assert f"interrupted in {where}\n" in result.stdout, result.stdout
    assert result.stdout.splitlines()[-1:] == ["the trace function before run_node is back: True"], result.stdout


def test_a_late_sigint_that_finds_the_nodes_code_is_raised_there_also_while_an_earlier_one_waits():
    """Promise 5: a late SIGINT found while rclpy's add_done_callback runs waits for the callback's own code; a third
    finds the done-callback that rclpy called from there asleep (the node's code, not the frame the second one waits
    for): it is raised there at once and the one that waited is dropped: the callback's except block runs to its end
    (raised again in it, the waiting one cut it short)."""
    pytest.importorskip("rclpy")
    result = run_script(DONE_CALLBACK, 130)
    assert (result.returncode, result.stderr) == (
        130,
        "[done_callback] stopped by a second SIGINT: a callback had not finished 0.2 s after the first\n",
    )
    assert "interrupted in arms_then_sleeps\n" in result.stdout, result.stdout


def test_a_make_node_that_never_returns_is_interrupted_by_a_later_second_sigint():
    """Promise 5: a late second SIGINT also interrupts the node's building (a driver waiting for its hardware)."""
    pytest.importorskip("rclpy")
    result = run_script(BUILDING, 130)
    assert (result.returncode, result.stderr) == (
        130,
        "[building_node] stopped by a second SIGINT: the node was not built 0.2 s after the first\n",
    )


def test_a_finish_that_never_returns_is_interrupted_by_a_later_second_sigint_with_exit_1():
    """Promises 5 and 6: a late second SIGINT interrupts finish() (its closing work left undone: one line, exit 1);
    the node is torn down all the same (it escaped run_node as a KeyboardInterrupt traceback before)."""
    pytest.importorskip("rclpy")
    result = run_script(FINISHING, 130)
    assert (result.returncode, result.stderr) == (
        1,
        "[finishing] could not finish: stopped by a second SIGINT 0.2 s after the first\n",
    )
    assert "destroyed\n" in result.stdout and "never interrupted" not in result.stdout, result.stdout


@pytest.fixture(scope="module")
def contexts_run():
    """CONTEXTS run once for the two tests below."""
    pytest.importorskip("rclpy")
    return run_script(CONTEXTS, 130)


def test_finish_runs_with_the_node_and_its_context_up(contexts_run):
    """Promise 6: after the SIGINT, finish() can still publish; the signal shut no context down."""
    assert (contexts_run.returncode, contexts_run.stderr) == (130, ""), contexts_run.stderr
    assert "finish: default context True up True other up True\n" in contexts_run.stdout, contexts_run.stdout


def test_the_teardown_shuts_down_the_nodes_context_and_no_other(contexts_run):
    """Promise 7: once run_node returns, the default context the node was built in is shut down; another context of
    the process is not (rclpy's SIGINT handler shut every context down)."""
    assert "after: the node's context up False other up True\n" in contexts_run.stdout, contexts_run.stdout


@pytest.mark.parametrize("rc", [0, 130])
def test_signals_during_the_teardown_are_only_noted(rc):
    """Promise 7: SIGINT and SIGTERM during the teardown, FORCE_AFTER s and more after the first, raise nothing there
    (the bound ends a teardown that hangs): the node is destroyed and exits as interrupted, without a word."""
    pytest.importorskip("rclpy")
    result = run_script(TEARDOWN, rc)
    assert (result.returncode, result.stderr) == (rc, ""), result.stderr
    assert "destroyed\n" in result.stdout, result.stdout


def test_after_run_node_returns_sigint_and_sigterm_are_the_callers_again():
    """Promise 8: a SIGINT after run_node returned is a KeyboardInterrupt in the caller and a SIGTERM ends the process
    (rclpy's handler, left installed after its context was shut down, swallowed it)."""
    pytest.importorskip("rclpy")
    result = run_script(AFTERWARDS, 130)
    assert "run_node returned 130\nKeyboardInterrupt in the caller\n" in result.stdout, result.stdout
    assert result.returncode == -signal.SIGTERM, result.stdout + result.stderr
    assert "swallowed" not in result.stdout


@pytest.mark.parametrize("rc", [0, 130])
def test_a_sigint_ignored_at_the_start_is_rclpys_and_its_context_error_in_a_callback_is_the_signals(rc):
    """Promise 9: a node started with SIGINT ignored (a background job) is stopped by rclpy's handler, which shuts
    the context down under the running callback; the rclpy error the callback then gets is the signal's."""
    pytest.importorskip("rclpy")
    result = run_script(LATE, rc, preexec_fn=sigint_ignored)
    assert (result.returncode, result.stderr) == (rc, ""), result.stdout + result.stderr


@pytest.mark.parametrize("sig", ["SIGINT", "SIGTERM"])
def test_run_node_in_a_thread_leaves_the_signals_to_rclpy(sig):
    """Promise 9: run_node in a thread sets no handler (only the main thread may); rclpy's SIGINT and SIGTERM handlers
    stop the node and pass the signal on to the main thread's."""
    pytest.importorskip("rclpy")
    result = run_script(THREADED, 130, sig=sig)
    assert (result.returncode, result.stderr) == (0, ""), result.stderr
    assert f"{sig} in the main thread\n" in result.stdout, result.stdout
    assert result.stdout.endswith("run_node returned [130]\n"), result.stdout


def test_a_sigterm_with_a_handler_of_the_callers_is_left_to_rclpy():
    """Promise 9: SIGTERM had a handler of the caller's (SIGINT is run_node's): rclpy's handler takes SIGTERM, stops
    the node and passes it on to the caller's."""
    pytest.importorskip("rclpy")
    result = run_script(CALLERS_SIGTERM, 130)
    assert (result.returncode, result.stderr) == (130, ""), result.stdout + result.stderr
    assert "the caller's SIGTERM handler\n" in result.stdout, result.stdout


@pytest.mark.parametrize("rc", [0, 130])
def test_an_idle_node_whose_context_goes_down_without_waking_its_executor_ends(rc):
    """Promise 3: the spin loop looks every SPIN_TIMEOUT s. rclpy's SIGINT handling wakes the executor before it shuts
    the context down: an executor that looked in between waited again, for good on an idle node (a tactile node
    after its simulator had gone hung so); a request, which wakes nothing, is noticed the same way."""
    pytest.importorskip("rclpy")
    result = run_script(QUIET, rc)
    assert (result.returncode, result.stderr) == (rc, ""), result.stderr


@pytest.mark.parametrize("rc", [0, 130])
def test_a_signal_while_the_node_is_being_built_stops_it_before_it_spins(rc):
    """Promise 3: a request during make_node() stops the node before it spins."""
    pytest.importorskip("rclpy")
    result = run_script(EARLY, rc)  # (without the request's check it would spin until the timeout)
    assert (result.returncode, result.stderr) == (rc, ""), result.stderr


@pytest.mark.parametrize("rc", [0, 130])
def test_a_middleware_teardown_that_hangs_holding_the_gil_ends_the_process_after_the_limit(rc):
    """Promises 6 and 7: Fast DDS can deadlock destroying a participant while its peers leave (about 1 in 100 stops
    of a graph): the node must still exit, with 1 and the stacks, once TEARDOWN_LIMIT s have passed (not after the
    120 s its teardown would take); the node's finish() runs before the limit starts, however long it takes."""
    pytest.importorskip("rclpy")
    result = run_script(HUNG, rc)
    assert result.returncode == 1, result.stderr
    assert "finished\n" in result.stdout  # (Fast DDS may print its own lines there)
    assert result.stderr.startswith("Timeout (0:00:01)!\n"), result.stderr
    assert "in shut_down" in result.stderr and "in run_node" in result.stderr, result.stderr


def test_the_teardown_limit_ends_with_the_teardown_and_reports_on_fd_2_when_stderr_has_none():
    """Promise 7: after a teardown in time the watchdog is gone (a caller of run_node goes on as long as it likes); a
    block of bounded() run with sys.stderr replaced by an object without a descriptor still ends, reported on fd 2."""
    pytest.importorskip("rclpy")
    result = run_script(GOES_ON, 0)
    assert result.stdout.splitlines()[-2:] == ["0", "still running"], result.stdout + result.stderr
    assert result.returncode == 1 and result.stderr.startswith("Timeout (0:00:00.500000)!\n"), result.stderr


@pytest.mark.parametrize("rc", [0, 130])
def test_a_finish_that_fails_is_one_line_and_exit_1_and_the_node_is_still_torn_down(rc):
    """Promise 6."""
    pytest.importorskip("rclpy")
    result = run_script(UNFINISHED, rc)
    assert result.returncode == 1, result.stderr
    assert result.stderr == "[unfinished] could not finish: OSError: [Errno 28] No space left on device\n"
    assert "destroyed\n" in result.stdout


def test_an_error_in_a_callback_without_a_signal_is_a_traceback():
    """Promises 2 and 10."""
    pytest.importorskip("rclpy")
    result = subprocess.run(
        [sys.executable, "-c", FAULTY], env=testing.isolated_env(), capture_output=True, text=True, timeout=120
    )
    assert result.returncode == 1 and "RuntimeError: a real bug" in result.stderr, result.stderr


def test_a_systemexit_of_the_node_passes_through_after_finish_and_the_teardown():
    """Promise 10: sim_node ends with SystemExit after its last episode: that status, after finish() and teardown."""
    pytest.importorskip("rclpy")
    result = run_script(EXITING, 0)
    assert (result.returncode, result.stderr) == (5, ""), result.stderr
    assert "finished\ndestroyed\n" in result.stdout, result.stdout


def test_run_node_destroys_the_node_it_built_also_when_the_context_was_shut_down_under_it(monkeypatch):
    """Promise 7: a clean shutdown for a caller in the same process: once run_node returns, the node it built is
    destroyed (its entities gone from the graph), also when something else shut the context down while it spun."""
    pytest.importorskip("rclpy")
    import rclpy
    from dlo_common.node_main import run_node
    from rclpy.node import Node

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
    argv = [
        "--params-file",
        "before.yaml",
        "--ros-args",
        "-p",
        "x:=1",
        "--params-file",
        "a.yaml",
        "--",
        "--params-file",
        "app.yaml",
        "--ros-args",
        "--params-file",
        "b.yaml",
        "--params-file",
    ]
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
    code = (
        "import sys; from dlo_common.node_main import params_file_problem as p; print(repr(p(sys.argv[1])), repr(p(sys.argv[2])))"
    )
    result = subprocess.run([sys.executable, "-c", code, good, latin], env=env, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    good_problem, latin_problem = (eval(x) for x in result.stdout.split(" ", 1))  # noqa: S307 - our own reprs
    assert good_problem == ""
    assert latin_problem.startswith("cannot read it (") and "utf-8" in latin_problem and "\n" not in latin_problem


def test_yaml_errors_name_their_line_also_a_character_yaml_does_not_allow(tmp_path):
    syntax = write(tmp_path, "/**:\n  ros__parameters:\n    a: [1\n    b: 2\n", "syntax.yaml")
    assert params_file_problem(syntax) == "YAML syntax error at line 4: expected ',' or ']', but got ':'"
    bell = write(tmp_path, "/**:\n  ros__parameters:\n    a: 1\n    b: \x07\n", "bell.yaml")
    assert params_file_problem(bell) == (
        "YAML syntax error at line 4: unacceptable character #x0007: special characters are not allowed"
    )


def test_an_empty_section_is_named_by_its_whole_path(tmp_path):
    top = write(tmp_path, "/**:\n  ros__parameters:\n", "top.yaml")
    assert "('/**: ros__parameters:' holds no parameters" in params_file_problem(top)
    nested = write(tmp_path, "robot:\n  sim_node:\n    ros__parameters:\n", "nested.yaml")
    assert "('robot/sim_node: ros__parameters:' holds no parameters" in params_file_problem(nested)


def test_every_yaml_document_of_a_params_file_is_checked_as_rcl_reads_them_all(tmp_path):
    two = "/**:\n  ros__parameters:\n    a: 1\n---\nsim_node:\n  ros__parameters:\n    b: 2\n"
    assert params_file_problem(write(tmp_path, two, "two.yaml")) == ""  # rcl takes it: so do we
    listed = "/**:\n  ros__parameters:\n    a: 1\n---\n- 1\n"
    assert params_file_problem(write(tmp_path, listed, "listed.yaml")).startswith("wrong layout (the file holds a list)")


def test_an_rcl_refusal_without_a_line_is_one_line_without_one(tmp_path):
    """rcl names no line for a node name it refuses ('sim-node' for sim_node)."""
    pytest.importorskip("rclpy")
    path = write(tmp_path, "sim-node:\n  ros__parameters:\n    a: 1\n")
    assert ros_arguments_problem(["x", "--ros-args", "--params-file", path]) == (
        f"params file {path}: rcl cannot read it: node name must not contain characters other than alphanumerics or '_'"
    )


def test_help_reads_the_arguments_it_is_given_and_sys_argv_only_without(monkeypatch, capsys):
    """Promise 1."""
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


@pytest.mark.parametrize(
    ("interrupted_rc", "codes"),
    [
        (0, "Exit codes: 0 done or stopped by a signal, 1 failed (see stderr), 2 bad parameter, 3 refused to start."),
        (130, "Exit codes: 0 done or stopped by a signal (130), 1 failed (see stderr), 2 bad parameter, 3 refused to start."),
    ],
)
def test_help_names_the_package_and_the_exit_code_of_an_interruption(monkeypatch, capsys, interrupted_rc, codes):
    """Promises 1 and 10."""
    from dlo_common.node_main import run_node

    monkeypatch.setattr(sys, "argv", ["sim_node", "--help"])
    monkeypatch.setattr(make_nothing, "__module__", "dlo_bag.recorder_node")  # the package is the module's first part
    assert run_node(make_nothing, parameters=[], interrupted_rc=interrupted_rc) == 0
    out = capsys.readouterr().out
    assert "ros2 run dlo_bag sim_node" in out and codes in out.splitlines()
    # run as `python -m dlo_sim.sim_node`: the make function's module is __main__, the package is the spec's
    monkeypatch.setattr(make_nothing, "__module__", "__main__")
    monkeypatch.setattr(sys.modules["__main__"], "__spec__", types.SimpleNamespace(name="dlo_sim.sim_node"), raising=False)
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
    """Promises 2, 8 and 9: the arguments passed to run_node reach rcl (not sys.argv's) and its SIGINT handler is put
    back on return; run from a thread that is not the main one (no signal handler may be set there) it still builds,
    refuses and returns its exit code, also after an earlier run in the same process (the context was shut down)."""
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
