"""Errors and exit codes of the bag library and tools (no rclpy here).

:class:`BagError` is one line that says why and what to do; a damaged bag's names the recovery command
(:func:`recover_hint`). One exit-status table for every bag tool (dlo-bag-info, dlo-bag-recover, dlo-analyze).
"""

from __future__ import annotations

import os

RECOVER_COMMAND = "dlo-bag-recover"


class BagError(RuntimeError):
    """A bag cannot be written or read (message says why and what to do)."""


class NotABagError(BagError):
    """The path does not exist or holds no bag (a user's mistake, not a damaged recording)."""


# Exit status of every bag tool (dlo-bag-info, dlo-bag-recover, dlo-analyze):
EXIT_OK = 0
EXIT_BAD_BAG = 1  # the bag is damaged (needs dlo-bag-recover), a part could not be recovered, or
#                   (dlo-analyze) a recomputed outcome differs from the recorded one
EXIT_USAGE = 2  # bad option, no such path, not a bag
EXIT_NO_TASK_STATE = 3  # dlo-analyze: a bag without /dlo/task/state (recorded from a robot driver)


def recover_hint(path: str | os.PathLike) -> str:
    return f"run: {RECOVER_COMMAND} {path}"
