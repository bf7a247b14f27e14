"""Small helpers shared by the dlo_tools nodes: checked parameters and shutdown signals."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Sequence
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor


class ParameterError(ValueError):
    """A parameter has a wrong type or value (the message names it and what is expected)."""


class NodeStartError(RuntimeError):
    """A node refuses to start or go on (e.g. another simulator already publishes its topics)."""


def _coerce(name: str, value: Any, default: Any) -> Any:
    """Coerce a parameter value to the type of its default, or raise ParameterError."""
    def bad(expected: str) -> ParameterError:
        return ParameterError(f"parameter '{name}': expected {expected}, got {value!r} "
                              f"({type(value).__name__})")

    if isinstance(default, bool):
        if isinstance(value, bool):
            return value
        raise bad("a bool (true/false)")
    if isinstance(default, int):
        if isinstance(value, int) and not isinstance(value, bool):
            return value
        raise bad("an integer")
    if isinstance(default, float):
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            return float(value)
        raise bad("a number")
    if isinstance(default, str):
        if isinstance(value, (str, int, float)) and not isinstance(value, bool):
            return str(value)
        raise bad("a string")
    if isinstance(default, (list, tuple)):
        if isinstance(value, str):  # one topic, or a comma-separated list
            return [v.strip() for v in value.split(",") if v.strip()]
        if isinstance(value, (list, tuple)) and all(isinstance(v, str) for v in value):
            return list(value)
        raise bad("a list of strings, e.g. \"['/dlo/a', '/dlo/b']\"")
    return value


def declare_parameters(node: Any, specs: Sequence[tuple[str, Any, str]]) -> dict[str, Any]:
    """Declare ``(name, default, description)`` parameters and return their checked values.

    Parameters are declared with ``dynamic_typing`` so that e.g. ``rate:=2`` (an integer) is
    accepted for a float parameter; any value that cannot be read as the default's type raises
    :class:`ParameterError` with a clear message instead of a traceback.
    """
    values: dict[str, Any] = {}
    for name, default, description in specs:
        descriptor = ParameterDescriptor(description=description, dynamic_typing=True)
        param = node.declare_parameter(name, default, descriptor)
        values[name] = _coerce(name, param.value, default)
    return values


def require_bounds(values: dict[str, Any], at_least: dict[str, float] | None = None,
                   above: dict[str, float] | None = None) -> None:
    """Raise ParameterError for the first value below its ``at_least`` bound or not above its ``above`` bound."""
    for name, low in (at_least or {}).items():
        if values[name] < low:
            raise ParameterError(f"parameter '{name}': must be >= {low}, got {values[name]}")
    for name, low in (above or {}).items():
        if not values[name] > low:
            raise ParameterError(f"parameter '{name}': must be > {low}, got {values[name]}")


class ShutdownRequest:
    """Turns SIGINT/SIGTERM/SIGHUP into a flag the spin loop checks (no exception mid-write)."""

    SIGNALS = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)

    def __init__(self, on_signal: Callable[[int], None] | None = None) -> None:
        self._event = threading.Event()
        self.signum: int | None = None
        self._on_signal = on_signal
        self._previous: dict[int, Any] = {}

    def install(self) -> ShutdownRequest:
        for sig in self.SIGNALS:
            self._previous[sig] = signal.signal(sig, self._handle)
        return self

    def restore(self) -> None:
        for sig, handler in self._previous.items():
            signal.signal(sig, handler)
        self._previous.clear()

    def _handle(self, signum: int, _frame: Any) -> None:
        first = not self._event.is_set()
        if first:
            self.signum = signum
        self._event.set()
        if first and self._on_signal is not None:
            self._on_signal(signum)

    def request(self) -> None:
        self._event.set()

    def is_set(self) -> bool:
        return self._event.is_set()

    @property
    def name(self) -> str:
        return signal.Signals(self.signum).name if self.signum else "request"
