"""Which gripper commands the simulator obeys (dlo_interface.command), at the boundaries: the speed limit per
axis, the closure range, the episode/step a command answers in both clock modes, and the throttled,
counted rejection log."""

import math

import pytest
from dlo_interface.command import MAX_SPEED, CommandError, RejectionLog, command_mismatch, command_to_action


@pytest.mark.parametrize("vx,vy", [(0.25, 0.0), (-0.25, 0.0), (0.0, 0.25), (0.0, -0.25), (0.25, -0.25)])
def test_the_speed_limit_itself_is_accepted(vx, vy):
    assert MAX_SPEED == pytest.approx(0.25)
    action = command_to_action(vx, vy, 0.5)
    assert action[0] == pytest.approx(vx / 0.25) and action[1] == pytest.approx(vy / 0.25)


@pytest.mark.parametrize("vx,vy", [(0.2501, 0.0), (-0.2501, 0.0), (0.0, 0.2501), (0.0, -0.2501), (0.2501, 0.2501)])
def test_just_above_the_speed_limit_is_rejected_on_each_axis(vx, vy):
    with pytest.raises(CommandError) as info:
        command_to_action(vx, vy, 0.5)
    assert info.value.cause == "speed"


@pytest.mark.parametrize(
    "values,cause",
    [
        ((math.nan, 0.0, 0.5), "non-finite"),
        ((0.0, math.inf, 0.5), "non-finite"),
        ((0.0, 0.0, math.nan), "non-finite"),
        ((0.0, 0.0, -0.001), "closure"),
        ((0.0, 0.0, 1.001), "closure"),
    ],
)
def test_invalid_commands_name_their_cause(values, cause):
    with pytest.raises(CommandError) as info:
        command_to_action(*values)
    assert info.value.cause == cause
    assert command_to_action(0.0, 0.0, 0.0)[2] == -1.0 and command_to_action(0.0, 0.0, 1.0)[2] == 1.0


def test_step_locked_obeys_only_the_current_episode_and_step():
    assert command_mismatch("step_locked", 3, 40, 3, 40) is None
    assert command_mismatch("step_locked", 3, 40, 3, 39)[0] == "old step"
    assert command_mismatch("step_locked", 3, 40, 3, 41)[0] == "future step"
    assert command_mismatch("step_locked", 3, 40, 999, 99999)[0] == "episode"
    assert command_mismatch("step_locked", 3, 40, 2, 40)[0] == "episode"
    # the answer to the previous episode's final state arrives after the new episode started: expected
    assert command_mismatch("step_locked", 3, 0, 2, 150, previous_final=(2, 150))[0] == "previous episode"
    assert command_mismatch("step_locked", 3, 0, 2, 149, previous_final=(2, 150))[0] == "episode"


def test_real_time_obeys_recent_steps_of_the_current_episode_only():
    period, timeout = 0.08, 0.3  # 3 steps are 0.24 s old, 4 steps 0.32 s
    assert command_mismatch("real_time", 5, 100, 5, 100, period=period, command_timeout=timeout) is None
    assert command_mismatch("real_time", 5, 100, 5, 97, period=period, command_timeout=timeout) is None
    assert command_mismatch("real_time", 5, 100, 5, 96, period=period, command_timeout=timeout)[0] == "stale"
    assert command_mismatch("real_time", 5, 100, 5, 101, period=period, command_timeout=timeout)[0] == "future step"
    assert command_mismatch("real_time", 5, 100, 999, 99999, period=period, command_timeout=timeout)[0] == "episode"
    assert command_mismatch("real_time", 5, 100, 4, 100, period=period, command_timeout=timeout)[0] == "episode"


def test_rejections_are_logged_once_a_second_per_cause_with_a_count():
    log = RejectionLog(interval=1.0)
    lines = []
    for i in range(4080):  # 4,080 bad commands in 5 s (the flood), two causes interleaved
        now = i * 5.0 / 4080
        for cause in ("episode", "speed"):
            line = log.note(cause, f"{cause} #{i}", now)
            if line:
                lines.append((now, cause, line))
        lines += [(now, "due", line) for line in log.due(now)]
    lines += [(6.0, "due", line) for line in log.due(6.0)]
    per_cause = {c: [t for t, cause, line in lines if c in line] for c in ("episode", "speed")}
    for cause, times in per_cause.items():
        assert 5 <= len(times) <= 7, (cause, len(times))
        assert all(b - a >= 1.0 - 1e-9 for a, b in zip(times, times[1:]))
    counted = sum(
        int(line.split("(")[-1].split()[0]) if "such commands" in line else 1 for _, _, line in lines if "episode" in line
    )
    assert counted == 4080  # every rejection is counted in some line
    assert lines[0][2] == "rejected command: episode #0"
    assert log.total == {"episode": 4080, "speed": 4080}
