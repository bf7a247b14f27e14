"""Command-line helpers shared by the dlo_policy console scripts (light: no torch, no simulator)."""

from __future__ import annotations

import argparse
import dataclasses
import sys
import typing
from typing import Any, Sequence

from dlo_common.params import did_you_mean

from .config import ConfigError, RunConfig


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line on stderr, ``PROG: error: ... (see PROG --help)``, exit 2."""

    def error(self, message: str) -> None:  # noqa: D102 (argparse's hook)
        print(f"{self.prog}: error: {message} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(2)


def config_keys(cls: type = RunConfig, prefix: str = "") -> list[str]:
    """Every settable dotted key of the run configuration (``seed``, ``sac.batch_size``, ``train.eval_every``, ...;
    a section's name too), in declaration order."""
    keys = []
    hints = typing.get_type_hints(cls)
    for field in dataclasses.fields(cls):
        keys.append(prefix + field.name)
        if dataclasses.is_dataclass(hints[field.name]):
            keys += config_keys(hints[field.name], prefix + field.name + ".")
    return keys


def _known_key(key: str) -> bool:
    """Whether `key` names a setting: a field of its section, or anything below a mapping (env_options.X: the
    env module checks those)."""
    cls: Any = RunConfig
    parts = key.split(".")
    for depth, part in enumerate(parts):
        if part not in {field.name for field in dataclasses.fields(cls)}:
            return False
        hint = typing.get_type_hints(cls).get(part)
        if depth == len(parts) - 1:
            return True
        if dataclasses.is_dataclass(hint):
            cls = hint
        else:
            return typing.get_origin(hint) is dict  # below a mapping: free; below a value: load_config says so
    return True


def check_override_keys(overrides: Sequence[str]) -> None:
    """ConfigError ``unknown key 'sac.batch_sise'; did you mean 'sac.batch_size'?`` for the first `key=value`
    override whose key is no setting of the run configuration. Only the keys are checked (the values and the
    rest by load_config); it needs neither torch nor the simulator, so a typo is answered at once."""
    for override in overrides:
        key, sep, _ = override.partition("=")
        key = key.strip()
        if sep and key and not _known_key(key):
            raise ConfigError(f"unknown key {key!r}{did_you_mean(key, config_keys())}")


CHECKPOINT_HELP = "a policy file (policy.pt / checkpoint.pt of a dlo-train run directory), or shipped[:NAME] (a shipped policy)"


def checkpoint_argument(spec: str):
    """argparse ``type=`` of a ``--checkpoint``: the policy file a spec names (``dlo_policy.rundir.checkpoint_path``:
    a path, ``shipped``, ``shipped:NAME``); an unknown shipped name is the parser's one-line error."""
    from .rundir import checkpoint_path  # noqa: PLC0415

    try:
        return checkpoint_path(spec)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
