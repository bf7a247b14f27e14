"""Known defect (xfail, strict): a firm grip lets the gripper stretch the cable without bound.

With c >= 0.9 the held particles have inverse mass 0 and ride with the gripper; the stretch solve
caps its correction, so the segment between the fixed end and the grip stretches instead of the
grip slipping or the gripper stopping. The RL agents exploit this (README, "Known limitation").
When the physics is fixed this test passes and strict xfail turns it into a failure: remove the mark.
"""

import numpy as np
import pytest

from dlo_sim import RopeSim
from dlo_sim.config import REST_SPACING


@pytest.mark.xfail(strict=True, reason="grip law + capped stretch solve: held cable stretches without bound")
def test_firm_grip_cannot_stretch_the_cable_far_beyond_its_length():
    sim = RopeSim(1)
    sim.reset(np.array([3]))
    grip_and_pull = np.array([[1.0, 0.0, 1.0]], np.float32)  # c = 1, full speed away from the fixed end
    worst = 0.0
    for _ in range(60):
        sim.step(grip_and_pull)
        held = np.flatnonzero(sim.held_mask()[0])
        if len(held):
            x = sim.positions()[0]
            far = held.max()
            span = np.linalg.norm(x[far] - x[0])  # straight-line distance fixed end -> held particle
            worst = max(worst, span / (far * REST_SPACING))
    assert worst <= 1.15  # a taut cable may stretch a little, not by half again
