"""dlo_common.console: what the console commands share about their output (module docstring): a quiet end on
a broken pipe or an unhandled Ctrl-C, progress on stderr as a bar on a terminal and plain lines elsewhere."""

import io
import os
import subprocess
import sys

import pytest
from dlo_common import console

# A command printing more than a pipe holds, given a stdout pipe whose reader has already gone.
PRINTER = """
import sys
from dlo_common.console import console_main

@console_main("printer")
def main(argv=None):
    for i in range(20000):
        print(f"line {i}")
    return 0

sys.exit(main())
"""


def run_into_a_closed_pipe(code):
    read, write = os.pipe()
    os.close(read)  # the reader is gone before the first byte (`| head -0`, or head having read its lines)
    try:
        return subprocess.run([sys.executable, "-c", code], stdout=write, stderr=subprocess.PIPE, text=True, timeout=120)
    finally:
        os.close(write)


def test_a_reader_that_goes_away_ends_the_command_quietly_with_141():
    result = run_into_a_closed_pipe(PRINTER)
    assert result.stderr == "" and result.returncode == console.EXIT_BROKEN_PIPE == 141


def test_a_broken_pipe_that_is_not_stdout_is_not_hidden(monkeypatch):
    @console.console_main("prog")
    def main(argv=None):
        raise BrokenPipeError("a subprocess' pipe")

    read, write = os.pipe()  # stdout: a pipe whose reader is still there
    with os.fdopen(read, "rb") as reader, os.fdopen(write, "w") as stdout:
        monkeypatch.setattr(sys, "stdout", stdout)
        with pytest.raises(BrokenPipeError, match="a subprocess' pipe"):
            main()
        assert reader is not None


def test_an_unhandled_ctrl_c_is_one_line_and_130(capsys):
    @console.console_main("prog")
    def main(argv=None):
        print("partial table")
        raise KeyboardInterrupt

    assert main() == console.EXIT_INTERRUPTED == 130
    captured = capsys.readouterr()
    assert captured.err == "prog: interrupted\n" and captured.out == "partial table\n"


def test_the_wrapped_main_returns_what_main_returns_and_lets_system_exit_through(capsys):
    @console.console_main("prog")
    def main(argv=None):
        if argv:
            raise SystemExit(2)
        return 3

    assert main() == 3 and main.__name__ == "main"
    with pytest.raises(SystemExit):
        main(["--bad"])


class Clock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


def test_off_a_terminal_progress_is_a_plain_line_every_tenth_and_at_the_end():
    """No carriage-return refreshes in a log: 200 updates of 1 are 10 lines (20, 40, ..., 200), each with
    the count, the rate, the ETA and the status; close adds none when the last line shows the count."""
    stream, clock = io.StringIO(), Clock()
    progress = console.Progress(200, "All", "step", stream=stream, terminal=False, clock=clock)
    for _ in range(200):
        clock.now += 0.5
        progress.update()
        if progress.n == 100:
            progress.set_status("hold_the_end 10% paper rule / 20% authors' rule")
    progress.close()
    text = stream.getvalue()
    lines = text.splitlines()
    assert "\r" not in text and len(lines) == 10
    assert lines[0] == "All: 20/200 steps (10%), 0:00:10 elapsed, 2.0 steps/s, ETA 0:01:30"
    assert lines[-1] == (
        "All: 200/200 steps (100%), 0:01:40 elapsed, 2.0 steps/s, ETA 0:00:00, hold_the_end 10% paper rule / 20% authors' rule"
    )


def test_off_a_terminal_a_slow_run_still_gets_a_line_every_interval_and_close_shows_the_last_count():
    stream, clock = io.StringIO(), Clock()
    progress = console.Progress(1000, "run", "step", initial=400, stream=stream, terminal=False, clock=clock, interval=300.0)
    clock.now += 299.0
    progress.update(10)  # under a tenth, under the interval: nothing
    assert stream.getvalue() == ""
    clock.now += 2.0
    progress.update(10)  # the interval has passed
    assert stream.getvalue().splitlines() == ["run: 420/1000 steps (42%), 0:05:01 elapsed, 0.1 steps/s, ETA 2:25:29"]
    progress.update(5)
    progress.close()  # the latest count, once
    progress.close()
    assert stream.getvalue().splitlines()[1].startswith("run: 425/1000 steps (42%)")
    assert len(stream.getvalue().splitlines()) == 2


def test_a_disabled_progress_writes_nothing_and_a_terminal_gets_a_bar():
    stream = io.StringIO()
    progress = console.Progress(10, "quiet", stream=stream, terminal=False, enabled=False)
    progress.update(10)
    progress.write("note")
    progress.close()
    assert stream.getvalue() == ""
    progress = console.Progress(10, "bar", "episode", stream=stream, terminal=True)
    progress.update(10)
    progress.set_status("without T")
    progress.close()
    assert "\r" in stream.getvalue() and "10/10" in stream.getvalue() and "without T" in stream.getvalue()
