"""Small helpers shared by the dlo nodes: checked parameters, start errors and shutdown signals."""

from __future__ import annotations

import signal
import threading
from collections.abc import Callable, Sequence
from typing import Any

from rcl_interfaces.msg import ParameterDescriptor

from dlo_common.params import (
    Param,
    ParameterError,
    UnknownParameterError,
    as_params,
    check_value,
    unknown_parameter,
)

__all__ = [
    "NodeStartError",
    "Param",
    "ParameterError",
    "ShutdownRequest",
    "UnknownParameterError",
    "declare_parameters",
    "require_bounds",
]


class NodeStartError(RuntimeError):
    """A node refuses to start or go on (e.g. another simulator already publishes its topics)."""


def declare_parameters(node: Any, specs: Sequence[Param | tuple[str, Any, str]]) -> dict[str, Any]:
    """Declare the parameters ``specs`` (:class:`Param` records or ``(name, default, description)``
    tuples) on ``node`` and return their checked values by name.

    Parameters are declared with ``dynamic_typing`` so that e.g. ``rate:=2`` (an integer) is
    accepted for a float parameter; a value that cannot be read as the default's type, or is outside
    the parameter's range, raises :class:`ParameterError` with a clear message instead of a traceback.

    A value given for a parameter the node does not have (``-p nosuch:=1``, or a name in a params
    file section for this node) raises :class:`UnknownParameterError` naming the closest declared
    one, instead of being ignored; so a node declares all its parameters in this one call.
    """
    params = as_params(specs)
    declared: dict[str, Any] = {}
    for param in params:
        descriptor = ParameterDescriptor(
            description=param.description, dynamic_typing=True, additional_constraints=param.range_text
        )
        default = list(param.default) if isinstance(param.default, tuple) else param.default
        declared[param.name] = node.declare_parameter(param.name, default, descriptor).value
    for name in getattr(node, "_parameter_overrides", {}):  # rclpy: what -p / params files set for this node
        if not node.has_parameter(name) and not name.startswith("qos_overrides."):
            raise unknown_parameter(name, declared)
    return {param.name: check_value(param, declared[param.name]) for param in params}


def require_bounds(
    values: dict[str, Any], at_least: dict[str, float] | None = None, above: dict[str, float] | None = None
) -> None:
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
