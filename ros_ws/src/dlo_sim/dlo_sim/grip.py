"""The paper's grip law: closure c in [0, 1] -> inverse mass of the particles between the fingers.

``w = max(2.25 w_nom - 2.5 w_nom max(c, 0.5), 0)``: c <= 0.5 leaves the particles free (w = w_nom),
c >= 0.9 makes them kinematic (w = 0, held firmly), in between they slide with growing drag.
Held particles are carried with the gripper in proportion ``1 - w / w_nom``. The Taichi kernel
(``kernels.py``) mirrors this function.
"""

from __future__ import annotations

import numpy as np


def inverse_mass(c, w_nom):
    """Inverse mass [1/kg] of a held particle at closure ``c`` (scalar or array)."""
    c = np.asarray(c, dtype=np.float64)
    return np.maximum(2.25 * w_nom - 2.5 * w_nom * np.maximum(c, 0.5), 0.0)


def carried_fraction(c):
    """Fraction of the gripper's displacement a held particle follows at closure ``c``."""
    return 1.0 - inverse_mass(c, 1.0)
