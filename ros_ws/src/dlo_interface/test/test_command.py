"""dlo_interface.command: the policy's action <-> the command in SI units both ways, the hold action, the error
each bad command raises, the texts of step mismatches and the rejection log's summaries (the gate's
boundaries as the sim node applies them: tests/test_command_gate.py)."""

import numpy as np
import pytest
from dlo_interface.command import (
    MAX_SPEED,
    SPEED_TOLERANCE,
    CommandError,
    RejectionLog,
    action_to_command,
    command_mismatch,
    command_to_action,
    hold_action,
)


@pytest.mark.parametrize(
    "action, command",
    [
        ((1.0, -1.0, 1.0), (0.25, -0.25, 1.0)),
        ((-0.5, 0.2, -1.0), (-0.125, 0.05, 0.0)),
        ((0.0, 0.0, 0.0), (0.0, 0.0, 0.5)),
        ((3.0, -7.0, 2.0), (0.25, -0.25, 1.0)),
        ((-3.0, 7.0, -2.0), (-0.25, 0.25, 0.0)),
    ],
)  # clipped to [-1, 1] first
def test_action_to_command_in_si_units(action, command):
    assert MAX_SPEED == pytest.approx(0.25)
    result = action_to_command(np.array(action, np.float32))
    assert result == pytest.approx(command)
    assert all(type(v) is float for v in result)


@pytest.mark.parametrize("action", [(0.3, -0.7, 0.1), (1.0, 1.0, -1.0), (-1.0, 0.0, 1.0)])
def test_command_round_trip(action):
    back = command_to_action(*action_to_command(action))
    assert back.dtype == np.float32 and back.shape == (3,)
    np.testing.assert_allclose(back, action, atol=1e-6)


def test_within_the_rounding_allowance_the_action_is_clipped_to_the_box():
    tiny = 0.5e-6  # below SPEED_TOLERANCE: accepted, and mapped onto the action box's edge exactly
    assert command_to_action(MAX_SPEED + tiny, -(MAX_SPEED + tiny), 1.0).tolist() == [1.0, -1.0, 1.0]
    assert command_to_action(0.0, 0.0, 0.0).tolist() == [0.0, 0.0, -1.0]
    edge = MAX_SPEED + SPEED_TOLERANCE  # the limit is inclusive up to the allowance itself, on each axis
    assert command_to_action(edge, -edge, 0.5).tolist() == [1.0, -1.0, 0.0]
    assert command_to_action(-edge, edge, 0.5).tolist() == [-1.0, 1.0, 0.0]


def test_hold_action_keeps_the_closure_and_stands_still():
    for closure in (0.0, 0.35, 1.0):
        action = hold_action(closure)
        assert action.dtype == np.float32
        np.testing.assert_allclose(action, [0.0, 0.0, 2.0 * closure - 1.0], atol=1e-7)
        assert action_to_command(action) == pytest.approx((0.0, 0.0, closure))


def test_errors_are_value_errors_naming_the_rule_and_the_values():
    with pytest.raises(ValueError) as info:
        command_to_action(0.3, 0.0, 0.5)
    assert info.value.cause == "speed" and "vx=0.3" in str(info.value) and "0.25" in str(info.value)
    with pytest.raises(CommandError) as info:
        command_to_action(0.0, 0.0, 1.5)
    assert "closure out of range: 1.5" in str(info.value)
    assert CommandError("x").cause == "invalid" and str(CommandError("why", "speed")) == "why"


def test_mismatch_texts_name_the_steps():
    cause, text = command_mismatch("step_locked", 3, 40, 3, 39)
    assert "step 39" in text and "current step 40" in text and "episode 3" in text
    cause, text = command_mismatch("real_time", 5, 100, 5, 90, period=0.08, command_timeout=0.5)
    assert cause == "stale" and "0.80 s old" in text and "0.5 s" in text
    assert (
        command_mismatch("step_locked", 3, 0, 2, 150, previous_final=(2, 150))[1]
        == "for the final step of the previous episode 2"
    )
    assert command_mismatch("real_time", 5, 100, 5, 94, period=0.08, command_timeout=0.5) is None  # 0.48 s
    assert command_mismatch("real_time", 1, 10, 1, 5, period=0.1, command_timeout=0.5) is None  # exactly the timeout


def test_rejection_log_summaries_are_due_once_the_interval_passed():
    log = RejectionLog(interval=1.0)
    assert log.note("speed", "for a", 0.0) == "rejected command: for a"
    assert log.note("speed", "for b", 0.5) is None and log.note("speed", "for c", 0.9) is None
    assert log.due(0.99) == []
    assert log.due(1.0) == ["rejected command: for c (2 such commands in 0.5 s)"]
    assert log.due(5.0) == []  # nothing pending
    assert log.note("speed", "for d", 1.5) is None  # within the interval of the summary
    assert log.note("speed", "for e", 2.0) == "rejected command: for e (2 such commands in 0.5 s)"
    assert log.total == {"speed": 5}
