"""What the dlo-vitac console commands (dlo-train, dlo-evaluate, dlo-bag-info, ...; not the nodes) share
about their output: stdout carries only what a command promises (a table, a JSON summary), so that it can
be piped; progress and notices go to stderr.

- :func:`console_main`: the decorator of a command's ``main``. A reader that goes away early
  (``dlo-bag-info BAG | head -3``) ends the command quietly with EXIT_BROKEN_PIPE (141, 128 + SIGPIPE,
  as coreutils' commands end in a shell), not a BrokenPipeError traceback; Ctrl-C that the command
  does not handle itself is one line ``PROG: interrupted`` and EXIT_INTERRUPTED (130), not a
  KeyboardInterrupt traceback.
- :class:`Progress`: a progress display on stderr: a live bar (tqdm) on a terminal; anywhere else (a log
  file, a pipe) a plain line at every tenth of the work and at least every few minutes, and one at the
  end, instead of a bar's carriage-return refreshes in the log.

Standard library only (tqdm is imported when a terminal shows a bar).
"""

from __future__ import annotations

import functools
import math
import os
import select
import sys
import time
from typing import Any, Callable, Optional, TextIO

EXIT_INTERRUPTED = 130  # 128 + SIGINT
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE: what a shell reports for `yes | head -1`'s yes

PROGRESS_FRACTION = 0.1  # Progress off a terminal: a line at every tenth of the total ...
PROGRESS_INTERVAL = 300.0  # ... and at least every 5 minutes [s]


def console_main(prog: str) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorate a console command's ``main(argv=None) -> int``: see the module docstring. The wrapped
    function returns what ``main`` returns (SystemExit, e.g. from ``--help``, passes through) after
    flushing stdout, so that a broken pipe is met here and not in the interpreter's exit."""

    def decorate(main: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(main)
        def run(*args: Any, **kwargs: Any) -> Any:
            try:
                try:
                    return main(*args, **kwargs)
                finally:
                    _flush(sys.stdout)
            except BrokenPipeError:
                if not stdout_is_broken():
                    raise  # another pipe (a subprocess', a socket): not the reader of our output
                silence_stdout()
                return EXIT_BROKEN_PIPE
            except KeyboardInterrupt:
                _say(f"{prog}: interrupted")
                return EXIT_INTERRUPTED

        return run

    return decorate


def _flush(stream: Optional[TextIO]) -> None:
    if stream is not None:
        stream.flush()


def _say(line: str) -> None:
    """One line on stderr; nothing when stderr is gone too."""
    try:
        print(line, file=sys.stderr, flush=True)
    except (OSError, ValueError):
        pass


def stdout_is_broken() -> bool:
    """Whether file descriptor 1 is a pipe whose reader has gone (poll reports an error on it); True when
    that cannot be told (no descriptor, no poll)."""
    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), select.POLLOUT)
        return any(events & (select.POLLERR | select.POLLHUP) for _, events in poller.poll(0))
    except (AttributeError, OSError, ValueError):
        return True


def silence_stdout() -> None:
    """Point file descriptor 1 at /dev/null, so that what is still buffered for it (flushed again when the
    interpreter exits) is dropped instead of raising BrokenPipeError once more."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):
        return
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
    finally:
        os.close(devnull)


def is_terminal(stream: Optional[TextIO]) -> bool:
    try:
        return stream is not None and stream.isatty()
    except (OSError, ValueError):
        return False


def _duration(seconds: float) -> str:
    seconds = int(max(seconds, 0.0))
    hours, rest = divmod(seconds, 3600)
    return f"{hours}:{rest // 60:02d}:{rest % 60:02d}"


class Progress:
    """Progress over ``total`` units (steps, episodes) on ``stream`` (default stderr).

    On a terminal (or ``terminal=True``): a tqdm bar, ``status`` as its postfix. Elsewhere: a plain line
    ``DESC: N/TOTAL UNITs (P%), H:MM:SS elapsed, R UNITs/s, ETA H:MM:SS[, STATUS]`` each time another
    ``fraction`` of the total is done or ``interval`` seconds have passed since the last line (checked at
    each update), and one from ``close`` when the last line is not the latest count. ``enabled=False``:
    nothing at all. ``initial``: units done before (a resumed run); rates count from there."""

    def __init__(
        self,
        total: int,
        desc: str,
        unit: str = "it",
        *,
        initial: int = 0,
        enabled: bool = True,
        stream: Optional[TextIO] = None,
        terminal: Optional[bool] = None,
        fraction: float = PROGRESS_FRACTION,
        interval: float = PROGRESS_INTERVAL,
        clock: Callable[[], float] = time.monotonic,
    ):
        self.total, self.desc, self.unit, self.n, self.initial = total, desc, unit, initial, initial
        self.enabled = enabled
        self.stream = stream
        self.status = ""
        self.interval, self.clock = interval, clock
        self.chunk = max(1, math.ceil(total * fraction))
        self.started = self.last_time = clock()
        self.shown_n: Optional[int] = None
        self.next_n = (initial // self.chunk + 1) * self.chunk
        self.bar = None
        if enabled and (is_terminal(self._stream()) if terminal is None else terminal):
            from tqdm import tqdm  # noqa: PLC0415 (only a terminal shows a bar)

            self.bar = tqdm(total=total, initial=initial, desc=desc, unit=unit, file=self._stream(), dynamic_ncols=True)

    def _stream(self) -> TextIO:
        return self.stream if self.stream is not None else sys.stderr

    def update(self, n: int = 1) -> None:
        self.n += n
        if self.bar is not None:
            self.bar.update(n)
        elif self.enabled and (self.n >= self.next_n or self.clock() - self.last_time >= self.interval):
            self.line()

    def set_status(self, text: str) -> None:
        """What the bar's postfix (or the end of the next line) says, e.g. the last evaluation."""
        self.status = text
        if self.bar is not None:
            self.bar.set_postfix_str(text)

    def line(self) -> None:
        """Write the plain line now (off a terminal)."""
        now = self.clock()
        elapsed = now - self.started
        done = self.n - self.initial
        rate = done / elapsed if elapsed > 0 else math.nan
        eta = (self.total - self.n) / rate if rate and math.isfinite(rate) and rate > 0 else math.nan
        percent = 100.0 * self.n / self.total if self.total else 100.0
        text = (
            f"{self.desc}: {self.n}/{self.total} {self.unit}s ({percent:.0f}%), {_duration(elapsed)} elapsed, "
            f"{rate:.1f} {self.unit}s/s, ETA {_duration(eta) if math.isfinite(eta) else '?'}"
        )
        self.write(text + (f", {self.status}" if self.status else ""))
        self.shown_n, self.last_time = self.n, now
        self.next_n = (self.n // self.chunk + 1) * self.chunk

    def write(self, text: str) -> None:
        """A line of the caller's own, above a terminal's bar (nothing when disabled)."""
        if self.bar is not None:
            self.bar.write(text, file=self._stream())
        elif self.enabled:
            print(text, file=self._stream(), flush=True)

    def close(self) -> None:
        """End the display: the bar's line is finished; off a terminal the latest count is written."""
        if self.bar is not None:
            self.bar.close()
            self.bar = None
        elif self.enabled and self.shown_n != self.n:
            self.line()
        self.enabled = False

    def __enter__(self) -> "Progress":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
