"""Command-line helpers shared by the dlo_policy console scripts."""
from __future__ import annotations

import argparse
import sys


class OneLineErrorParser(argparse.ArgumentParser):
    """argparse whose usage errors are one line on stderr, ``PROG: error: ... (see PROG --help)``, exit 2."""

    def error(self, message: str) -> None:  # noqa: D102 (argparse's hook)
        print(f"{self.prog}: error: {message} (see {self.prog} --help)", file=sys.stderr)
        raise SystemExit(2)
