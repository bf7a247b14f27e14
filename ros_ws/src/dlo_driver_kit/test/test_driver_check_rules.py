"""dlo-driver-check's rules case by case on small synthetic recordings (no ROS): each test makes the one
property a rule judges (module docstring of dlo_driver_kit.driver_check) just hold or just fail, and checks
the line the rule prints; and the schedule is the documented sequence of phases."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_driver_kit.driver_check import (  # noqa: E402
    CONTROL_RATE,
    MAX_SPEED,
    REACT_PERIODS,
    ImageSample,
    InfoSample,
    Recording,
    Settings,
    StateSample,
    check_camera,
    check_invalid,
    check_obey,
    check_rate,
    check_stale,
    check_stamps,
    check_workspace,
    cloud_layout_problem,
    finite,
    judged_states,
    motion_clock,
    moved,
    schedule,
    steps_in,
    typical_period,
)
from test_driver_check import complete_recording, results_of  # noqa: E402


def states(walls, stamps=None, steps=None, episodes=None):
    stamps = walls if stamps is None else stamps
    steps = range(len(walls)) if steps is None else steps
    episodes = [0] * len(walls) if episodes is None else episodes
    return [StateSample(w, t, e, k, 0.0, 0.0, 0.0) for w, t, k, e in zip(walls, stamps, steps, episodes)]


# ------------------------------------------------------------------------------------------------ schedule
@pytest.mark.parametrize("s", [Settings(), Settings(duration=3.0, command_timeout=0.7, workspace=0.2, speed=0.15)])
def test_the_schedule_is_the_documented_sequence_of_phases(s):
    """Hold still, close, open, move +x / +y / -y, go silent, drive to the workspace corner, send invalid
    commands (NaN, speed > 0.25 m/s, closure > 1), each after a valid moving lead-in, start a new episode.
    The whole check takes about --duration + 12 s (the phases plus 0.2 s of listening after them)."""
    v, fast, nan = s.speed, MAX_SPEED, math.nan
    expected = [
        ("idle", "idle", s.duration, (0.0, 0.0, 0.0)),
        ("close", "closure", 0.6, (0.0, 0.0, 1.0)),
        ("open", "closure", 0.6, (0.0, 0.0, 0.0)),
        ("+x", "move", 0.8, (v, 0.0, 0.0)),
        ("+y", "move", 0.8, (0.0, v, 0.0)),
        ("-y", "move", 0.8, (0.0, -v, 0.0)),
        ("lead-stale", "lead", 0.4, (v, 0.0, 0.0)),
        ("silent", "silent", s.command_timeout + 1.0, None),
        ("corner", "workspace", 2.0 * s.workspace / fast + 0.3, (fast, fast, 0.0)),  # across the whole workspace
        ("lead-nan", "lead", 0.4, (-v, -v, 0.0)),  # away from the corner on both axes: free to move
        ("nan", "invalid", 0.6, (nan, 0.0, 0.0)),
        ("lead-speed", "lead", 0.4, (-v, -v, 0.0)),
        ("speed", "invalid", 0.6, (-3.0 * fast, 0.0, 0.0)),
        ("lead-closure", "lead", 0.4, (-v, -v, 0.0)),
        ("closure", "invalid", 0.6, (0.0, 0.0, 1.5)),
        ("reset", "reset", 0.8, (0.0, 0.0, 0.0)),
    ]
    got = [(p.name, p.kind, p.duration, p.command) for p in schedule(s)]
    assert [g[:2] for g in got] == [e[:2] for e in expected]
    for g, e in zip(got, expected):
        assert g[2] == pytest.approx(e[2]), g
        if e[3] is None:
            assert g[3] is None
        else:
            assert len(g[3]) == 3 and all(a == b or (math.isnan(a) and math.isnan(b)) for a, b in zip(g[3], e[3])), g
    if s == Settings():
        assert 11.0 <= sum(p.duration for p in schedule(s)) - s.duration + 0.2 <= 12.5


# ------------------------------------------------------------------------------------------------ helpers
def test_the_invalid_phases_last_long_enough_for_four_judged_steps_at_a_slow_rate():
    """'invalid' judges from the third invalid command on: at --rate 7.5 Hz 0.6 s left it one step or none (a mock
    driver at 7.5 Hz failed with "closure: 1 usable step(s)"); the phases last 6 control periods, at least 0.6 s."""
    durations = lambda rate: {p.name: p.duration for p in schedule(Settings(rate=rate)) if p.kind == "invalid"}  # noqa: E731
    assert durations(CONTROL_RATE) == durations(10.0) == {"nan": 0.6, "speed": 0.6, "closure": 0.6}
    assert durations(7.5) == {"nan": 0.8, "speed": 0.8, "closure": 0.8}
    assert durations(5.0) == {"nan": 1.2, "speed": 1.2, "closure": 1.2}


def test_typical_period_is_the_median_positive_difference():
    rec = Recording(states=states([0.0, 0.0, 0.0, 0.1, 0.2, 0.5]))
    assert typical_period(rec, "wall") == pytest.approx(0.1)  # repeated arrival times left out
    assert typical_period(Recording(states=states([0.0, 0.1, 0.2, 0.3]))) == pytest.approx(0.1)
    assert typical_period(Recording()) == 1.0 / CONTROL_RATE == pytest.approx(0.08)  # nothing to measure
    assert typical_period(Recording(states=states([1.0, 1.0]))) == pytest.approx(0.08)
    # episodes of one step, each new one's state 0 1 ms after the previous final state (the sim, moved sideways
    # under the authors' task rules): those 1 ms are no period; the steps of one episode are
    walls = [0.0, 0.08, 0.081, 0.16, 0.161, 0.24, 0.241, 0.32, 0.321]
    churn = Recording(states=states(walls, steps=[0, 1] * 4 + [0], episodes=[0, 0, 1, 1, 2, 2, 3, 3, 4]))
    assert typical_period(churn, "wall") == pytest.approx(0.079)


def test_motion_is_timed_by_stamps_when_at_least_half_the_steps_have_a_plausible_stamp_difference():
    walls = [0.25 * k for k in range(5)]  # arrival period 0.25 s
    # stamp differences of exactly half and twice the arrival period count as plausible
    assert motion_clock(Recording(states=states(walls, [100.0, 100.125, 100.25, 100.375, 100.875]))) == "stamp"
    assert motion_clock(Recording(states=states(walls, [100.0, 100.5, 101.0, 101.5, 101.625]))) == "stamp"
    assert motion_clock(Recording(states=states(walls, [100.0, 100.625, 101.25, 101.875, 102.5]))) == "wall"  # 2.5x
    # exactly half of the steps plausible: stamps; fewer: arrival
    assert motion_clock(Recording(states=states(walls, [100.0, 100.25, 100.5, 100.5, 100.5]))) == "stamp"
    assert motion_clock(Recording(states=states(walls, [100.0, 100.25, 100.25, 100.25, 100.25]))) == "wall"
    # only consecutive steps of one episode are judged: step jumps and episode changes do not count
    walls = [0.25 * k for k in range(10)]
    stamps = [100.0, 100.25, 100.5, 100.75, 101.0, 101.0, 101.0, 101.0, 101.0, 101.0]
    assert motion_clock(Recording(states=states(walls, stamps, steps=[0, 1, 2, 3, 4, 6, 8, 10, 12, 14]))) == "stamp"
    assert (
        motion_clock(
            Recording(states=states(walls, stamps, episodes=[0, 0, 0, 0, 0, 1, 2, 3, 4, 5], steps=[0, 1, 2, 3, 4, 5, 6, 7, 8, 9]))
        )
        == "stamp"
    )


def test_steps_in_takes_consecutive_steps_whose_answer_and_the_one_before_came_from_the_phase():
    rec = Recording(states=states([0.08 * k for k in range(8)], steps=[0, 1, 2, 3, 4, 6, 7, 8]))
    rec.answered = {(0, 0): "a", (0, 1): "a", (0, 2): "a", (0, 3): "b", (0, 4): "b", (0, 6): "b", (0, 7): "b", (0, 8): "b"}
    pairs = lambda names: [(a.step, b.step) for a, b in steps_in(rec, names)]  # noqa: E731
    # (0, 1): a new episode's first step runs under the answer to its state 0 alone (a driver acts only on commands
    # of its current episode)
    assert pairs("a") == [(0, 1), (1, 2), (2, 3)]
    assert pairs("b") == [(7, 8)]  # (3, 4): step 2 was "a"; (4, 6) is a jump; (6, 7): step 5 unanswered
    assert pairs(("a", "b")) == [(0, 1), (1, 2), (2, 3), (7, 8)]
    rec.answered[(0, 5)] = "b"
    assert pairs("b") == [(6, 7), (7, 8)]
    late = lambda names: [(a.step, b.step) for a, b in steps_in(rec, names, react=2)]  # noqa: E731
    assert late("a") == [(0, 1), (1, 2), (2, 3)]  # before step 0 nothing of this episode answered
    assert late("b") == [(6, 7), (7, 8)]  # (3, 4): steps 1 and 2 were "a"; (4, 6) is a jump
    del rec.answered[(0, 4)]
    assert late("b") == [(7, 8)] and pairs("b") == [(6, 7), (7, 8)]  # (6, 7) needs step 4's answer too
    for x in rec.states[6:]:
        x.episode = 1  # an episode change between steps 6 and 7
    rec.answered.update({(1, 6): "b", (1, 7): "b", (1, 8): "b"})
    assert pairs("b") == [(7, 8)]


def test_judged_states_end_with_the_schedule():
    rec = Recording(states=states([0.0, 1.0, 2.0, 2.5]))
    assert [x.wall for x in judged_states(rec)] == [0.0, 1.0, 2.0, 2.5]  # no schedule: all
    rec.phases = [("idle", 0.0, 1.0), ("reset", 1.0, 2.0)]
    assert [x.wall for x in judged_states(rec)] == [0.0, 1.0, 2.0]  # one arriving exactly at the end counts
    rec = complete_recording(Settings())
    end = rec.phases[-1][2]
    rec.states.append(StateSample(end + 0.1, end + 0.1, 0, rec.states[-1].step + 1, 0.0, 0.0, 0.0))
    assert results_of(rec)["sync"].status == "PASS"  # its image would have come after the checker stopped


def test_finite_means_every_coordinate_finite():
    assert finite(StateSample(0, 0, 0, 0, 0.1, 0.2, 0.3))
    for bad in ((math.nan, 0.0, 0.0), (0.0, math.inf, 0.0), (0.0, 0.0, math.nan)):
        assert not finite(StateSample(0, 0, 0, 0, *bad))


def test_a_cloud_with_another_point_step_or_too_few_bytes_for_its_rows_is_unreadable():
    from dlo_interface.cloud import particle_cloud

    cloud = particle_cloud([[0.0, 0.0, 0.1]] * 4, [False] * 4)
    cloud.width, cloud.height = 2, 2
    assert cloud_layout_problem(cloud) is None
    cloud.data = cloud.data[:40]
    assert cloud_layout_problem(cloud) == "40 bytes for 4 points of 16 bytes"
    cloud = particle_cloud([[0.0, 0.0, 0.1]] * 2, [False] * 2)
    cloud.point_step = 20
    cloud.data = bytes(40)
    assert cloud_layout_problem(cloud) == "not a dlo particle cloud: fields ['x', 'y', 'z', 'held'], point_step 20"


# ------------------------------------------------------------------------------------------------ rate
def idle_recording(walls, idle, stamps=None, steps=None, episodes=None):
    return Recording(states=states(walls, stamps, steps, episodes), phases=[("idle", *idle)])


def test_rate_counts_the_states_of_the_idle_window_edges_included():
    s = Settings()
    rec = idle_recording([0.0, 0.08, 0.16, 0.24], (0.0, 0.16))
    assert check_rate(rec, s).status == "PASS"  # three states in the window, two of them on its edges
    few = check_rate(idle_recording([0.0, 0.08, 0.16, 0.24, 0.32], (0.05, 0.1)), s)
    assert few.status == "FAIL" and few.reason == (
        "1 states in 2 s of holding still (expected about 25): is the driver real-time?"
    )
    none = check_rate(Recording(states=states([0.0, 0.08, 0.16, 0.24])), s)  # the idle phase never ran
    assert none.status == "FAIL" and none.reason.startswith("0 states in 2 s")
    two = check_rate(idle_recording([0.0, 0.08, 0.16, 0.24], (0.0, 0.1)), s)
    assert two.status == "FAIL" and two.reason.startswith("2 states in 2 s")


def test_rate_is_the_median_period_of_consecutive_steps_of_one_episode():
    s = Settings()
    ok = check_rate(idle_recording([0.0, 0.08, 0.16, 0.24], (0.0, 1.0)), s)
    assert ok.status == "PASS"
    assert ok.reason == "12.50 Hz (12.50 Hz by stamps; median of 3 steps), expected 12.5 Hz +-20%"
    # a driver dropping every other state (steps +2, 0.16 s apart) between consecutive ones: those gaps are not periods
    walls = [0.0, 0.08, 0.16, 0.24, 0.40, 0.56, 0.72, 0.88, 1.04, 1.20]
    steps = [0, 1, 2, 3, 5, 7, 9, 11, 13, 15]
    assert check_rate(idle_recording(walls, (0.0, 2.0), steps=steps), s).reason.startswith("12.50 Hz (12.50 Hz by")
    # episode changes are not periods either
    episodes = [0, 0, 0, 0, 1, 2, 3, 4, 5, 6]
    steps = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9]
    assert check_rate(idle_recording(walls, (0.0, 2.0), steps=steps, episodes=episodes), s).status == "PASS"
    # fewer than three consecutive steps at all
    short = check_rate(idle_recording([0.0, 0.08, 0.16, 0.24], (0.0, 1.0), steps=[0, 1, 2, 4]), s)
    assert short.status == "FAIL" and short.reason == "2 consecutive steps in 4 states"


def test_rate_leaves_out_the_steps_from_a_new_episodes_state_0_that_came_off_the_tick():
    """A driver whose episodes end every two steps (the sim under the authors' task rules, moved sideways)
    publishes each new episode's state 0 right after the final state (here 0.03 s after the tick): the steps from
    it are shorter than a period and would be half of all steps; the rate is the driver's tick, from the others."""
    walls, steps, episodes = [], [], []
    for k in range(6):
        walls += [0.16 * k + 0.03, 0.16 * k + 0.08, 0.16 * k + 0.16]
        steps += [0, 1, 2]
        episodes += [k] * 3
    result = check_rate(idle_recording(walls, (0.0, 2.0), steps=steps, episodes=episodes), Settings())
    assert result.status == "PASS" and result.reason.startswith("12.50 Hz ("), result
    assert "median of 6 steps" in result.reason  # one per episode: step 1 -> 2


def test_the_rate_tolerance_is_twenty_percent_either_way_and_stamps_give_their_own_rate():
    for period, rate, status in ((0.0625, 20.0, "PASS"), (0.125, 10.0, "PASS"), (0.2, 12.5, "FAIL"), (0.05, 12.5, "FAIL")):
        walls = [period * k for k in range(6)]
        result = check_rate(idle_recording(walls, (0.0, 10.0)), Settings(rate=rate))
        assert result.status == status, (period, rate, result)
    stamps = [100.0 + 0.1 * k for k in range(6)]
    result = check_rate(idle_recording([0.08 * k for k in range(6)], (0.0, 10.0), stamps=stamps), Settings())
    assert result.reason.startswith("12.50 Hz (10.00 Hz by stamps;")
    stamps[3] = stamps[2]  # one repeated stamp: no rate by stamps (that is for 'stamps' to judge)
    result = check_rate(idle_recording([0.08 * k for k in range(6)], (0.0, 10.0), stamps=stamps), Settings())
    # (median of the 4 steps from step 1 on: the step from state 0 is left out, it may come off the tick)
    assert (
        "12.50 Hz (no rate by stamps: they do not strictly increase, see 'stamps'; median of 4 steps)" in result.reason
        and result.status == "PASS"
    )


# ------------------------------------------------------------------------------------------------ stamps
def test_stamps_rule_counts_each_kind_of_fault_and_names_the_first():
    s = Settings()
    assert check_stamps(Recording(states=states([0.0])), s).reason == "only 1 state(s) received"
    assert check_stamps(Recording(), s).status == "FAIL"
    two = check_stamps(Recording(states=states([0.0, 0.08])), s)
    assert two.status == "PASS" and two.reason.startswith(
        "2 states: stamps strictly increasing, step +1 each (0 new episode(s) from step 0) (no new episode seen"
    )
    back = check_stamps(Recording(states=states([0, 1, 2, 3], stamps=[1.0, 2.0, 1.5, 3.0])), s)
    assert back.reason == (
        "1 non-increasing stamp(s), 0 step jump(s), 0 bad episode change(s) in 4 states; first: stamp 1.5 s after 2 s"
    )
    jump = check_stamps(Recording(states=states([0, 1, 2, 3], steps=[0, 1, 3, 4])), s)
    assert jump.reason == (
        "0 non-increasing stamp(s), 1 step jump(s), 0 bad episode change(s) in 4 states; first: step 1 -> 3 in episode 0"
    )
    both = check_stamps(Recording(states=states([0, 1, 2, 3], stamps=[0, 1, 1, 2], steps=[0, 1, 3, 5])), s)
    assert both.reason == (
        "1 non-increasing stamp(s), 2 step jump(s), 0 bad episode change(s) in 4 states; first: stamp 1 s after 1 s"
    )
    mid_episode = check_stamps(Recording(states=states([0, 1, 2, 3], steps=[0, 1, 5, 6], episodes=[0, 0, 1, 1])), s)
    assert mid_episode.reason == (
        "0 non-increasing stamp(s), 0 step jump(s), 1 bad episode change(s) in 4 states; "
        "first: episode 0 step 1 -> episode 1 step 5"
    )
    backwards = check_stamps(Recording(states=states([0, 1, 2, 3], steps=[0, 1, 0, 1], episodes=[1, 1, 0, 0])), s)
    assert backwards.reason.startswith("0 non-increasing stamp(s), 0 step jump(s), 1 bad episode change(s)")
    new = check_stamps(Recording(states=states([0, 1, 2, 3, 4], steps=[0, 1, 0, 1, 2], episodes=[0, 0, 1, 1, 1])), s)
    assert new.status == "PASS" and "(1 new episode(s) from step 0)" in new.reason and "not judged" not in new.reason


# ------------------------------------------------------------------------------------------------ camera
def camera_result(info=None, images=None):
    rec = complete_recording(Settings())
    if info is not None:
        rec.infos = [info]
    if images is not None:
        rec.images = images
    return check_camera(rec, Settings())


K = (213.3, 0.0, 64.0, 0.0, 213.3, 64.0, 0.0, 0.0, 1.0)


@pytest.mark.parametrize(
    "width, height, k, problem",
    [
        (0, 128, K, "camera_info size 0x128"),
        (128, 0, K, "camera_info size 128x0"),
        (128, 128, K[:4], "K [213.3, 0.0, 64.0, 0.0] is not a pinhole matrix"),
        (128, 128, (math.nan,) + K[1:], "is not a pinhole matrix"),
        (128, 128, (0.0,) + K[1:], "is not a pinhole matrix"),
        (128, 128, K[:4] + (0.0,) + K[5:], "is not a pinhole matrix"),
        (128, 128, K[:2] + (0.0,) + K[3:], "is not a pinhole matrix"),
        (128, 128, K[:2] + (128.0,) + K[3:], "is not a pinhole matrix"),
        (128, 128, K[:5] + (0.0,) + K[6:], "is not a pinhole matrix"),
        (128, 128, K[:5] + (128.0,) + K[6:], "is not a pinhole matrix"),
        (128, 128, K[:8] + (2.0,), "is not a pinhole matrix"),
        (128, 128, K[:8] + (0.5,), "is not a pinhole matrix"),
        (128, 128, K[:8] + (1.0 + 1.5e-9,), "is not a pinhole matrix"),  # K[8] is 1 (to 1e-9)
    ],
)
def test_camera_info_needs_a_size_and_a_pinhole_k_with_the_centre_in_the_image(width, height, k, problem):
    result = camera_result(InfoSample(width, height, k, "top_camera_optical"))
    assert result.status == "FAIL" and problem in result.reason, result


def test_the_smallest_camera_passes_and_camera_info_needs_a_frame():
    one = ImageSample(1, 1, "mono8", 1, 1, "cam", 0, (255,))
    result = camera_result(InfoSample(1, 1, (1.0, 0.0, 0.5, 0.0, 1.0, 0.5, 0.0, 0.0, 1.0), "cam"), [one])
    assert result.status == "PASS", result
    result = camera_result(InfoSample(128, 128, K, ""))
    assert result.status == "FAIL" and "camera_info has no frame_id" in result.reason


@pytest.mark.parametrize(
    "change, problem",
    [
        (dict(width=64, height=64, size=64 * 64, step=64), "image 64x64 but camera_info 128x128"),
        (dict(frame_id="elsewhere"), "image frame 'elsewhere' but camera_info frame 'top_camera_optical'"),
        (
            dict(encoding="rgb8", step=128, size=128 * 128, values=()),
            "image data 16384 bytes for 128 rows of step 128 (rgb8, width 128)",
        ),
        (
            dict(encoding="yuv9", step=100, size=100 * 128, values=()),
            "image data 12800 bytes for 128 rows of step 100 (yuv9, width 128)",
        ),
        (dict(size=128 * 127), "image data 16256 bytes for 128 rows of step 128 (mono8, width 128)"),
    ],
)
def test_images_must_match_camera_info_and_hold_height_times_step_bytes(change, problem):
    rec = complete_recording(Settings())
    for image in rec.images:
        for key, value in change.items():
            setattr(image, key, value)
    result = check_camera(rec, Settings())
    assert result.status == "FAIL" and problem in result.reason, result
    assert result.reason.count("image") <= 3  # one line per kind of problem, not one per image


# ------------------------------------------------------------------------------------------------ obey, invalid
P = 0.0625  # s: a control period that is exact in binary


def driven(spec, lag=0):
    """A recording of a driver that does what ``spec`` says: [(phase, states, (vx, vy, closure) it executes,
    stamp step)], each state answered by its phase's command, which the next state shows executed: its
    position advanced by velocity x its stamp step, its closure the executed one. ``lag``: the driver gets
    its commands that many control periods late (the state after next shows the command at lag 1)."""
    rec, wall, stamp, x, y, step = Recording(), 0.0, 100.0, 0.0, 0.0, 0
    executed = [(0.0, 0.0, 0.0)] * (lag + 1)  # what the states so far answered with, oldest first
    for name, n, command, dt in spec + [("end", 1, (0.0, 0.0, 0.0), P)]:
        for _ in range(n):
            vx, vy, closure = executed[-1 - lag]
            x, y, stamp, wall = x + vx * dt, y + vy * dt, stamp + dt, wall + P
            rec.states.append(StateSample(wall, stamp, 0, step, x, y, closure))
            executed.append(command)
            if name != "end":
                rec.answered[(0, step)] = name
            step += 1
    return rec


def obey_spec(v=0.1, **phases):
    spec = {
        "idle": (4, (0.0, 0.0, 0.0), P),
        "close": (5, (0.0, 0.0, 1.0), P),
        "open": (5, (0.0, 0.0, 0.0), P),
        "+x": (6, (v, 0.0, 0.0), P),
        "+y": (6, (0.0, v, 0.0), P),
        "-y": (6, (0.0, -v, 0.0), P),
    }
    spec.update(phases)
    return [(name, *value) for name, value in spec.items()]


def test_obey_measures_each_move_and_the_closure():
    s = Settings(rate=16.0)
    ok = check_obey(driven(obey_spec()), s)
    assert ok.status == "PASS", ok
    assert ok.reason == (
        "closure 1.00, closure 0.00, +x 0.100 m/s at 0 deg, +y 0.100 m/s at 0 deg, -y 0.100 m/s at "
        "0 deg (commanded 0.1 m/s; closure 1, 0)"
    )
    still = check_obey(driven(obey_spec(**{"+x": (6, (0.0, 0.0, 0.0), P)})), s)
    assert still.status == "FAIL" and still.reason == "+x 0.000 m/s at 180 deg (commanded 0.1 m/s)"
    for speed, status in ((0.119, "PASS"), (0.121, "FAIL"), (0.081, "PASS"), (0.079, "FAIL")):
        result = check_obey(driven(obey_spec(**{"+y": (6, (0.0, speed, 0.0), P)})), s)
        assert result.status == status, (speed, result)
    for angle, status in ((14.0, "PASS"), (16.0, "FAIL"), (-14.0, "PASS"), (-16.0, "FAIL")):
        a = math.radians(angle)
        result = check_obey(driven(obey_spec(**{"-y": (6, (0.1 * math.sin(a), -0.1 * math.cos(a), 0.0), P)})), s)
        assert result.status == status, (angle, result)
        assert f"-y 0.100 m/s at {abs(angle):.0f} deg" in result.reason
    for closure, status in ((0.96, "PASS"), (0.94, "FAIL")):
        result = check_obey(driven(obey_spec(close=(5, (0.0, 0.0, closure), P))), s)
        assert result.status == status, (closure, result)
    assert "closure 0.94 after commanding 1 for 0.6 s" in result.reason
    for closure, status in ((0.04, "PASS"), (0.06, "FAIL")):
        assert check_obey(driven(obey_spec(open=(5, (0.0, 0.0, closure), P))), s).status == status
    # the closure is judged on the last state under the command: a gripper that closes gradually, reaching the
    # commanded closure only at the end of the phase, obeys
    ramp = driven(obey_spec())
    close = [x for x in ramp.states if ramp.answered.get((0, x.step - 1)) == "close"]
    for k, x in enumerate(close):
        x.closure = (k + 1) / len(close)
    assert [round(x.closure, 2) for x in close[-2:]] == [0.8, 1.0]
    assert check_obey(ramp, s).status == "PASS", check_obey(ramp, s)
    none = check_obey(driven(obey_spec(open=(1, (0.0, 0.0, 0.0), P))), s)
    assert none.status == "FAIL" and none.reason == "open: no state under the command"


def test_obey_uses_the_steps_half_to_twice_a_period_long_and_wants_two_of_them():
    s = Settings(rate=16.0)
    edges = driven(obey_spec(**{"+x": (6, (0.1, 0.0, 0.0), 2 * P), "+y": (6, (0.0, 0.1, 0.0), P / 2)}))
    assert check_obey(edges, s).status == "PASS", check_obey(edges, s)
    # (the last step of the phase is stamped P after the one before: the only usable one)
    beyond = check_obey(driven(obey_spec(**{"+x": (6, (0.0, 0.0, 0.0), 2.5 * P)})), s)
    assert beyond.reason == "+x: 1 usable step(s) (states missing, or not half to twice a period apart)"
    beyond = check_obey(driven(obey_spec(**{"+x": (6, (0.0, 0.0, 0.0), 0.4 * P)})), s)
    assert beyond.reason == "+x: 1 usable step(s) (states missing, or not half to twice a period apart)"
    assert check_obey(driven(obey_spec(**{"+x": (3, (0.1, 0.0, 0.0), P)})), s).status == "PASS"
    two = check_obey(driven(obey_spec(**{"+x": (2, (0.1, 0.0, 0.0), P)})), s)
    assert two.status == "FAIL"
    assert two.reason == "+x: 1 usable step(s) (states missing, or not half to twice a period apart)"


def invalid_spec(**phases):
    spec = {
        "idle": (4, (0.0, 0.0, 0.5), P),
        "nan": (5, (0.0, 0.0, 0.5), P),
        "speed": (5, (0.0, 0.0, 0.5), P),
        "closure": (5, (0.0, 0.0, 0.5), P),
    }
    spec.update(phases)
    return [(name, *value) for name, value in spec.items()]


def test_invalid_commands_must_leave_the_gripper_where_it_was():
    s = Settings(rate=16.0)
    held = check_invalid(driven(invalid_spec()), s)
    assert held.status == "PASS" and held.reason == (
        "gripper held (largest step, closure change): nan 0.00 mm/step, closure +0.000, speed 0.00 mm/step, "
        "closure +0.000, closure 0.00 mm/step, closure +0.000"
    )
    for per_step, status in ((0.0004, "PASS"), (0.0006, "FAIL")):
        result = check_invalid(driven(invalid_spec(speed=(5, (per_step / P, 0.0, 0.5), P))), s)
        assert result.status == status, (per_step, result)
    assert result.reason == ("speed 0.60 mm/step, closure +0.000: not rejected (commanded (-0.75, 0.0, 0.0))")
    rec = driven(invalid_spec())
    for x in rec.states:
        if rec.answered.get((0, x.step)) == "closure":
            x.closure = 0.5 + 0.03 * (x.step % 2)
    result = check_invalid(rec, s)
    assert result.status == "FAIL" and "closure 0.00 mm/step, closure +0.030: not rejected" in result.reason
    for x in rec.states:
        if rec.answered.get((0, x.step)) == "closure":
            x.closure = 0.5 + 0.01 * (x.step % 2)
    assert check_invalid(rec, s).status == "PASS"
    rec = driven(invalid_spec())
    nan_steps = [x for x in rec.states if rec.answered.get((0, x.step)) == "nan"]
    nan_steps[-1].x = math.nan
    result = check_invalid(rec, s)
    assert result.status == "FAIL" and result.reason == "nan: state became non-finite (x = nan, closure = 0.5)"
    short = check_invalid(driven(invalid_spec(nan=(3, (0.0, 0.0, 0.5), P))), s)
    assert short.status == "FAIL" and short.reason == "nan: 1 usable step(s)"


def test_a_state_made_non_finite_by_an_invalid_command_fails_even_outside_the_judged_steps():
    """A driver that reports NaN for one step right after the first NaN command (a step the rule allows for
    stopping, so judged by no motion test) and then recovers did not reject the command."""
    s = Settings(rate=16.0)
    for lag in (0, 2):
        for after in range(1 + REACT_PERIODS + 1):  # the states after the phase's 1st, 2nd, 3rd command
            rec = driven(led_in(), lag=lag)
            first = min(x.step for x in rec.states if rec.answered.get((0, x.step)) == "nan")
            hit = next(x for x in rec.states if x.step == first + 1 + after)
            hit.closure = math.nan
            result = check_invalid(rec, s)
            assert result.status == "FAIL" and result.reason == (
                "nan: state became non-finite (x = {}, closure = nan)".format(hit.x)
            ), (lag, after, result)
    # and after the phase's last command: the state that shows it (two periods late at most)
    for late, status in ((1, "FAIL"), (REACT_PERIODS + 1, "FAIL"), (REACT_PERIODS + 2, "PASS")):
        rec = driven(led_in())
        last = max(x.step for x in rec.states if rec.answered.get((0, x.step)) == "speed")
        next(x for x in rec.states if x.step == last + late).x = math.inf
        assert check_invalid(rec, s).status == status, (late, check_invalid(rec, s))
    # a non-finite state before the first invalid command is not this rule's
    rec = driven(led_in())
    first = min(x.step for x in rec.states if rec.answered.get((0, x.step)) == "nan")
    next(x for x in rec.states if x.step == first).y = math.nan
    assert check_invalid(rec, s).status == "PASS", check_invalid(rec, s)


def led_in(invalid=(0.0, 0.0, 0.0), states=10, v=0.1):
    """Each invalid phase after a lead phase moving at (-v, -v), open, as the schedule sends them; the driver
    executes ``invalid`` for the invalid commands (a driver that rejects them: stop, keep the closure)."""
    spec = [("idle", 4, (0.0, 0.0, 0.0), P)]
    for name in ("nan", "speed", "closure"):
        spec += [(f"lead-{name}", 6, (-v, -v, 0.0), P), (name, states, invalid, P)]
    return spec


def test_invalid_commands_may_take_two_control_periods_to_stop_the_gripper():
    """A driver that gets its commands late still moves with the lead command in the first steps answered by
    the invalid phase; the rule allows two control periods of that (as 'stale' does for the pipeline)."""
    s = Settings(rate=16.0)
    for lag in (0, 1, 2):
        result = check_invalid(driven(led_in(), lag=lag), s)
        assert result.status == "PASS", (lag, result)
        assert result.reason.startswith("gripper held (largest step, closure change): nan 0.00 mm/step"), result
    late = check_invalid(driven(led_in(), lag=3), s)
    assert late.status == "FAIL" and late.reason.startswith("nan 8.84 mm/step, closure +0.000: not rejected"), late
    # judged from the third state answered by the phase on: the first two pairs are the lead's
    rec = driven(led_in(), lag=2)
    assert [a.step for a, b in steps_in(rec, "nan", react=2)] == list(range(12, 20))  # nan answers 10-19
    assert moved(*next((a, b) for a, b in zip(rec.states, rec.states[1:]) if a.step == 11)) > 0.008


def test_an_invalid_command_must_not_move_the_gripper_nor_change_its_closure_at_all():
    s = Settings(rate=16.0)
    # ignored (the last valid command goes on until the command timeout, 8 periods), not rejected
    ignored = [(name, *rest) for name, *rest in led_in()]
    at = ignored.index(("nan", 10, (0.0, 0.0, 0.0), P))
    ignored[at : at + 1] = [("nan", 7, (-0.1, -0.1, 0.0), P), ("nan", 3, (0.0, 0.0, 0.0), P)]
    result = check_invalid(driven(ignored), s)
    assert result.status == "FAIL" and result.reason.startswith("nan 8.84 mm/step, closure +0.000: not rejected")
    # closure 1.5 clamped to 1 (the gripper closes once, then holds): the closure it had was 0
    clamped = [(name, n, (0.0, 0.0, 1.0) if name == "closure" else command, dt) for name, n, command, dt in led_in()]
    for lag in (0, 2):  # also by a driver that acts on the command at once (its closure jump is in no judged step)
        result = check_invalid(driven(clamped, lag=lag), s)
        assert result.status == "FAIL" and result.reason == (
            "closure 0.00 mm/step, closure +1.000: not rejected (commanded (0.0, 0.0, 1.5))"
        ), (lag, result)


def test_the_closure_kept_is_the_one_the_gripper_had_in_the_states_episode():
    """A driver whose episode ends during an invalid phase (the sim, its cable dropped) starts the next one at its
    start closure: those states are judged against the closure of their own episode before the phase."""
    s = Settings(rate=16.0)
    rec = driven(led_in())
    start = [x for x in rec.states if rec.answered.get((0, x.step)) == "nan"][5].step
    answered = {}
    for x in rec.states:
        name = rec.answered.get((0, x.step))
        if x.step >= start:
            x.episode, x.step, x.closure = 1, x.step - start, 0.7
        if name is not None:
            answered[(x.episode, x.step)] = name
    rec.answered = answered
    # episode 1 from its state 0 on: its commands are all of the phase (none of episode 0 acts in it)
    assert [(a.episode, a.step) for a, b in steps_in(rec, "nan", react=2)] == [
        (0, 12),
        (0, 13),
        (1, 0),
        (1, 1),
        (1, 2),
        (1, 3),
        (1, 4),
    ]
    result = check_invalid(rec, s)
    assert result.status == "PASS" and "nan 0.00 mm/step, closure +0.000" in result.reason, result
    for x in rec.states:
        if x.episode == 1 and x.step == 3:
            x.closure = 0.73
    result = check_invalid(rec, s)
    assert result.status == "FAIL" and result.reason.startswith("nan 0.00 mm/step, closure +0.030: not rejected")


# ------------------------------------------------------------------------------------------------ stale
def silent_recording(stop_after, publish_until=2.5, period=P, before_from=0.0, t0=1.0):
    """Lead phase 0-1 s, the last command at ``t0``, silence 1-2.5 s; the gripper moves 1 mm a step from
    ``before_from`` until ``stop_after`` s after the last command; states until ``publish_until``."""
    rec = Recording(phases=[("lead-stale", 0.0, 1.0), ("silent", 1.0, 2.5)], last_command_wall=t0)
    wall, x, step = 0.0, 0.0, 0
    while wall <= publish_until + 1e-9:
        if before_from <= wall <= t0 + stop_after:
            x += 0.001
        rec.states.append(StateSample(wall, wall, 0, step, x, 0.0, 0.0))
        wall, step = wall + period, step + 1
    return rec


def test_stale_wants_the_gripper_stopped_within_the_command_timeout_plus_two_periods():
    s = Settings(rate=16.0)  # limit: 0.5 + 2 x 0.0625 + 0.1 = 0.725 s
    ok = check_stale(silent_recording(0.3), s)
    assert ok.status == "PASS" and ok.reason == (
        "stopped 0.25 s after the last command (command_timeout 0.5 s, allowed 0.72 s)"
    ), ok
    assert check_stale(silent_recording(0.70), s).status == "PASS"
    late = check_stale(silent_recording(0.76), s)
    assert late.status == "FAIL" and late.reason == (
        "still moving 0.75 s after the last command (command_timeout 0.5 s, allowed 0.72 s)"
    )
    assert "stopped 0.00 s after" in check_stale(silent_recording(-0.01), s).reason
    slow = silent_recording(0.76, period=0.125)  # a driver slower than --rate: two of its own periods allowed
    result = check_stale(slow, s)
    assert result.status == "PASS" and "allowed 0.85 s" in result.reason, result
    moving_later = silent_recording(0.3)
    for x in moving_later.states:
        if x.wall > 2.5:
            x.x += 1.0  # after the silence (the corner phase): not judged
    assert check_stale(moving_later, s).status == "PASS"


def test_stale_needs_motion_before_the_silence_and_states_after_the_allowed_stop():
    s = Settings(rate=16.0)
    still = check_stale(silent_recording(-1.0), s)
    assert still.status == "FAIL" and still.reason.startswith("the gripper did not move under the last command")
    assert check_stale(silent_recording(0.0, before_from=0.55), s).status == "PASS"  # 0.4 s before the silence
    long_ago = silent_recording(-0.45, before_from=0.0)  # moved only until 0.55 s, 0.45 s before the silence
    assert check_stale(long_ago, s).reason.startswith("the gripper did not move under")
    # the last command's own answer, half a period after it, still counts as moving under it
    assert check_stale(silent_recording(0.03, before_from=1.0), s).status == "PASS"
    gone = check_stale(silent_recording(0.3, publish_until=1.7), s)
    assert gone.status == "FAIL" and gone.reason == (
        "0 states between 0.72 s and 1.50 s after the last command: a real-time driver keeps publishing its state"
    )
    one = check_stale(silent_recording(0.3, publish_until=1.8), s)
    assert one.status == "FAIL" and one.reason.startswith("1 states between")
    assert check_stale(silent_recording(0.3, publish_until=1.9), s).status == "PASS"
    rec = silent_recording(0.3)
    rec.last_command_wall = None
    assert check_stale(rec, s).reason == "the silent phase did not run"
    rec = silent_recording(0.3)
    rec.phases = rec.phases[:1]
    assert check_stale(rec, s).reason == "the silent phase did not run"


# ------------------------------------------------------------------------------------------------ workspace, touch
def test_workspace_reports_where_the_corner_drive_ended():
    s = Settings()
    rec = Recording(
        states=[
            StateSample(k, k, 0, k, x, y, 0.0)
            for k, (x, y) in enumerate([(0.1, 0.0), (math.nan, 0.0), (0.2, 0.25), (0.2985, 0.29)])
        ],
        phases=[("corner", 1.5, 3.5)],
    )
    result = check_workspace(rec, s)
    assert result.status == "PASS" and result.reason == (
        "all 3 states inside |x|, |y| <= 0.3 m (largest 0.298 m); driven to the corner it stopped at the boundary "
        "(x = 0.298, y = 0.290 m)"
    )
    rec.states[-1].x, rec.states[-1].y = 0.25, 0.2985
    assert "stopped at the boundary" in check_workspace(rec, s).reason
    rec.states[-1].x = rec.states[-1].y = 0.2975
    assert check_workspace(rec, s).reason.endswith(
        "; driven to the corner it ended at x = 0.297, y = 0.297 m, short of the boundary"
    )
    rec.phases = []
    assert check_workspace(rec, s).reason == "all 3 states inside |x|, |y| <= 0.3 m (largest 0.297 m)"
    rec.phases = [("corner", 3.0, 3.0)]  # only the last state is in the corner window (its edges included)
    assert "ended at x = 0.297, y = 0.297 m" in check_workspace(rec, s).reason
    rec.phases = [("corner", 2.0, 2.0)]
    assert "ended at x = 0.200, y = 0.250 m" in check_workspace(rec, s).reason
    assert check_workspace(Recording(states=[StateSample(0, 0, 0, 0, math.nan, 0.0, 0.0)]), s).reason == "no finite gripper state"
    outside = Recording(states=[StateSample(0, 0, 0, 7, 0.0, -0.4, 0.0)])
    assert check_workspace(outside, s).reason == ("gripper at x = 0.000 m, y = -0.400 m (step 7), outside |x|, |y| <= 0.3 m")


def test_touch_wants_a_readable_cloud_or_a_tactile_pose():
    from dlo_driver_kit.driver_check import CloudSample, check_touch

    s = Settings()
    assert check_touch(Recording(), s).reason == (
        "no tactile source: neither /dlo/rope/particles (contact points flagged 'held') nor /dlo/tactile/pose"
    )
    assert check_touch(Recording(), s).status == "FAIL"
    poses = check_touch(Recording(tactile_stamps=[1, 2, 3]), s)
    assert poses.status == "PASS" and poses.reason == "3 tactile poses"
    clouds = check_touch(Recording(clouds=[CloudSample(1, ["x"]), CloudSample(2, ["x"])], tactile_stamps=[1]), s)
    assert clouds.status == "PASS" and clouds.reason.startswith("2 particle clouds in the layout tactile_node reads")
    bad = check_touch(Recording(clouds=[CloudSample(1, ["x"]), CloudSample(2, ["x"], "broken")]), s)
    assert bad.status == "FAIL" and bad.reason == "1 of 2 particle clouds unreadable for tactile_node: broken"


# ------------------------------------------------------------------------------------------------ main
def test_main_passes_the_settings_on_and_refuses_nonpositive_values(monkeypatch, capsys):
    from dlo_driver_kit import driver_check

    seen = []

    def record(settings, namespace, timeout):
        seen.append((settings, namespace, timeout))
        return None

    monkeypatch.setattr(driver_check, "record", record)
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
    assert driver_check.main([]) == 1
    assert seen[-1] == (Settings(), "", 10.0)
    assert (
        "no driver: nothing published /dlo/gripper/state within 10 s on ROS_DOMAIN_ID=0 (is the driver running"
        in capsys.readouterr().err
    )
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    args = [
        "--namespace",
        "/r2/",
        "--timeout",
        "3",
        "--duration",
        "1.5",
        "--rate",
        "20",
        "--command-timeout",
        "0.7",
        "--speed",
        "0.25",
        "--workspace",
        "0.2",
        "--skip",
        "rate",
        "--skip",
        "touch",
    ]
    assert driver_check.main(args) == 1
    assert seen[-1] == (
        Settings(rate=20.0, command_timeout=0.7, workspace=0.2, duration=1.5, speed=0.25, skip=("rate", "touch")),
        "/r2/",
        3.0,
    )
    assert capsys.readouterr().err == (
        "dlo-driver-check: no driver: nothing published /r2/dlo/gripper/state within "
        "3 s on ROS_DOMAIN_ID=42 (is the driver running, on this domain and namespace, "
        "in real_time mode?)\n"
    )
    for option in ("--timeout", "--duration", "--rate", "--command-timeout", "--speed", "--workspace"):
        with pytest.raises(SystemExit) as exit_:
            driver_check.main([option, "0"])
        assert exit_.value.code == 2
        assert f"{option} must be > 0, got 0.0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        driver_check.main(["--speed", "0.2501"])
    assert "--speed must be <= 0.25 m/s (the command limit)" in capsys.readouterr().err
    n = len(seen)
    with pytest.raises(SystemExit):
        driver_check.main(["--speed", "-1"])
    assert len(seen) == n  # nothing was checked


def test_a_check_that_cannot_run_is_one_line_and_exit_1(monkeypatch, capsys):
    from dlo_driver_kit import driver_check

    def record(settings, namespace, timeout):
        raise driver_check.CheckError("another node commands the driver")

    monkeypatch.setattr(driver_check, "record", record)
    assert driver_check.main([]) == 1
    out = capsys.readouterr()
    assert out.out == "" and out.err == "dlo-driver-check: another node commands the driver\n"


# ------------------------------------------------------------------------------------------------ sync
def test_sync_without_states_or_inputs():
    from dlo_driver_kit.driver_check import check_sync

    assert check_sync(Recording(), Settings()).reason == "no state received before the end of the check"
    assert check_sync(Recording(), Settings()).status == "FAIL"
    rec = complete_recording(Settings())
    rec.images, rec.clouds = [], []
    result = results_of(rec)["sync"]
    n = len(judged_states(rec))
    assert result.status == "PASS" and result.reason == (
        f"{n} states, nothing else to match (no image and no tactile source to match: see camera, touch)"
    )


def test_sync_names_the_nearest_stamp_later_or_earlier():
    results = results_of(complete_recording(Settings(), state_offset_ns=-400))
    assert "(the nearest 0.4 us later)" in results["sync"].reason, results["sync"]
    rec = complete_recording(Settings())
    for cloud in rec.clouds:
        cloud.stamp_ns += 1000  # the clouds alone
    reason = results_of(rec)["sync"].reason
    assert "states have no particle cloud with their exact stamp" in reason and "image" not in reason.split(";")[0]
    assert "particle cloud stamps 0.000001, 0.080001 nearby (the nearest 1 us later)" in reason


def arrivals(offset_of):
    """complete_recording whose images arrive ``offset_of(k)`` s after the k-th state (None: unknown)."""
    rec = complete_recording(Settings())
    for k, (image, state) in enumerate(zip(rec.images, rec.states)):
        off = offset_of(k)
        image.wall = None if off is None else state.wall + off
    return rec


def test_an_input_a_step_away_is_more_than_half_a_period_off_and_more_than_a_quarter_of_them():
    assert results_of(arrivals(lambda k: 0.039))["sync"].status == "PASS"
    early = results_of(arrivals(lambda k: -0.041))["sync"]
    assert (
        early.status == "FAIL"
        and "get the image carrying their stamp a step away: it arrives 41 ms before the "
        "state (median; the control period is 80 ms)"
        in early.reason
    ), early
    assert results_of(arrivals(lambda k: None))["sync"].status == "PASS"  # arrival unknown: not judged
    n = len(complete_recording(Settings()).states)
    quarter = n // 4
    share = results_of(arrivals(lambda k: 0.08 if k < quarter else 0.0))["sync"]
    assert share.status == "PASS", (n, share)
    over = results_of(arrivals(lambda k: 0.08 if k <= quarter else 0.0))["sync"]
    assert over.status == "FAIL" and f"{quarter + 1} of {n} states get the image" in over.reason


def test_a_stamp_carried_twice_is_left_to_the_stamps_rule():
    from dlo_driver_kit.driver_check import step_away

    rec = arrivals(lambda k: 0.08)
    states = judged_states(rec)
    stamps, walls = [im.stamp_ns for im in rec.images], [im.wall for im in rec.images]
    assert step_away("image", stamps, walls, states, rec) is not None
    assert step_away("image", stamps + stamps, walls + walls, states, rec) is None  # every stamp twice
    twice = [StateSample(x.wall, x.stamp, x.episode, x.step, x.x, x.y, x.closure, x.stamp_ns) for x in states]
    assert step_away("image", stamps, walls, states + twice, rec) is None


# ------------------------------------------------------------------------------------------------ exact edges
def path_recording(points, silent=(1.0, 2.5), t0=1.0):
    """States at the given (wall, x, y) (stamp = wall), consecutive steps; lead phase before the silence."""
    rec = Recording(phases=[("lead-stale", 0.0, silent[0]), ("silent", *silent)], last_command_wall=t0)
    rec.states = [StateSample(w, w, 0, k, x, y, 0.0) for k, (w, x, y) in enumerate(points)]
    return rec


def grid(start, end, step):
    n = round((end - start) / step)
    return [start + k * step for k in range(n + 1)]


def test_stale_edges_are_exact():
    s = Settings(rate=16.0, command_timeout=0.275)  # allowed: 0.275 + 2 x 0.0625 + 0.1 = 0.5 s exactly
    moving_until = lambda t_stop, until=2.5: [(w, 0.016 * min(w, t_stop), 0.0) for w in grid(0.0, until, P)]  # noqa
    at_limit = check_stale(path_recording(moving_until(1.5)), s)  # the last move 0.5 s after the last command
    assert at_limit.status == "PASS" and at_limit.reason.startswith("stopped 0.50 s after"), at_limit
    one_late = check_stale(path_recording(moving_until(1.2, until=1.5625)), s)  # 1.5 is not after the limit
    assert one_late.status == "FAIL" and one_late.reason.startswith("1 states between 0.50 s and 1.50 s"), one_late
    assert check_stale(path_recording(moving_until(1.2, until=1.625)), s).status == "PASS"  # two are enough
    end_at = check_stale(path_recording(moving_until(1.2), silent=(1.0, 1.625)), s)  # a state at the window's end
    assert end_at.status == "PASS", end_at
    # the motion before the silence: from 0.4 s before the window (edge included) ...
    rec = path_recording([(w, 0.001 if w >= 0.5 else 0.0, 0.0) for w in grid(0.0, 2.5, P)], silent=(0.9, 2.5), t0=0.9)
    assert check_stale(rec, s).status == "PASS", check_stale(rec, s)
    # ... to half a control period after the last command (edge included, not a whole period)
    fine = Settings(rate=32.0, command_timeout=0.275)
    for t_move, status in ((1.015625, "PASS"), (1.03125, "FAIL")):
        points = [(w, 0.001 if w >= t_move else 0.0, 0.0) for w in grid(0.0, 2.5, P / 4)]
        assert check_stale(path_recording(points), fine).status == status, t_move
    # 0.5 mm a step is standing still, before the silence and after it
    creep_before = [(w, 0.0005 if w >= 0.9375 else 0.0, 0.0) for w in grid(0.0, 2.5, P)]
    assert check_stale(path_recording(creep_before), s).reason.startswith("the gripper did not move")
    creep_after = [(w, 0.001 if w >= 0.9375 else 0.0, 0.0005 if w >= 2.0 else 0.0) for w in grid(0.0, 2.5, P)]
    result = check_stale(path_recording(creep_after), s)
    assert result.status == "PASS" and result.reason.startswith("stopped 0.00 s after"), result


def test_invalid_edges_are_exact():
    s = Settings(rate=16.0)
    assert check_invalid(driven(invalid_spec(nan=(4, (0.0, 0.0, 0.5), P))), s).status == "PASS"  # two steps do
    rec = driven(invalid_spec())
    speed = [x for x in rec.states if rec.answered.get((0, x.step - 1)) == "speed"]
    speed[2].x = speed[3].x = speed[4].x = 0.0006  # one step of 0.6 mm among still ones
    result = check_invalid(rec, s)
    assert result.status == "FAIL" and "speed 0.60 mm/step" in result.reason
    rec = driven(invalid_spec())
    speed = [x for x in rec.states if rec.answered.get((0, x.step - 1)) == "speed"]
    for x in rec.states:
        x.x = 0.0005 if x.step >= speed[2].step else 0.0  # exactly one step of exactly 0.5 mm: still
    assert check_invalid(rec, s).status == "PASS", check_invalid(rec, s)
    assert "speed 0.50 mm/step" in check_invalid(rec, s).reason
    for closure, status in ((0.02, "PASS"), (-0.03, "FAIL")):
        rec = driven(invalid_spec(closure=(5, (0.0, 0.0, 0.0), P)))
        under = [x for x in rec.states if rec.answered.get((0, x.step - 1)) == "closure"]
        for x in rec.states:
            x.closure = 0.0
        under[2].closure = under[3].closure = under[4].closure = closure
        assert check_invalid(rec, s).status == status, (closure, check_invalid(rec, s))


def test_obey_speed_edge_is_exact_and_a_small_commanded_speed_is_judged_alike():
    """'obey': speed within 20 %: a driver executing 0.12 m/s for a commanded 0.15 m/s (--speed 0.15) is exactly
    20 % slow and passes. Any --speed > 0 is judged the same way: a driver that executes a small commanded speed
    (1.2 um/s) exactly obeys, at 0 deg."""
    result = check_obey(driven(obey_spec(v=0.15, **{"+y": (6, (0.0, 0.12, 0.0), P)})), Settings(rate=16.0, speed=0.15))
    assert result.status == "PASS" and "+y 0.120 m/s at 0 deg" in result.reason, result
    for small in (1.2e-6, 5e-7, 1e-9):  # below 1 um/s the angle was once computed against a floor (76 deg at 5e-7)
        result = check_obey(driven(obey_spec(v=small)), Settings(rate=16.0, speed=small))
        assert (
            result.status == "PASS" and "+x 0.000 m/s at 0 deg, +y 0.000 m/s at 0 deg, -y 0.000 m/s at 0 deg" in result.reason
        ), (small, result)


def test_obey_closure_edge_and_workspace_edges_are_exact():
    s = Settings(rate=16.0)
    assert check_obey(driven(obey_spec(open=(5, (0.0, 0.0, 0.05), P))), s).status == "PASS"
    ws = Settings()
    edge = ws.workspace + 0.001
    for x, y in ((edge, 0.0), (0.0, -edge)):
        rec = Recording(states=[StateSample(0, 0, 0, 0, 0.1, 0.0, 0.0), StateSample(1, 1, 0, 1, x, y, 0.0)])
        assert check_workspace(rec, ws).status == "PASS"
    left = Recording(states=[StateSample(0, 0, 0, 0, 0.1, 0.0, 0.0), StateSample(1, 1, 0, 1, -0.4, 0.05, 0.0)])
    result = check_workspace(left, ws)
    assert result.status == "FAIL" and result.reason.startswith("gripper at x = -0.400 m, y = 0.050 m (step 1)")
    corner = Recording(states=[StateSample(1, 1, 0, 1, ws.workspace - 0.002, 0.1, 0.0)], phases=[("corner", 0.0, 2.0)])
    assert "stopped at the boundary" in check_workspace(corner, ws).reason


def test_sync_reason_lists_only_what_is_absent_and_the_nearest_stamps_of_a_late_miss():
    rec = complete_recording(Settings())
    n = len(judged_states(rec))
    reason = results_of(rec)["sync"].reason
    assert reason == (
        f"{n} states, each with an image and a particle cloud of its exact stamp (the perception and "
        "policy nodes match a step by stamp)"
    )
    rec.clouds = []
    assert results_of(rec)["sync"].reason.endswith(" (no tactile source to match: see touch)")
    rec = complete_recording(Settings())
    missing = rec.clouds[10].stamp_ns
    del rec.clouds[10]
    reason = results_of(rec)["sync"].reason
    before, after = rec.clouds[9].stamp_ns, rec.clouds[10].stamp_ns
    assert before < missing < after
    from dlo_perception.sync import format_stamp

    assert f"particle cloud stamps {format_stamp(before)}, {format_stamp(after)} nearby" in reason, reason


def test_step_away_edges_are_exact():
    from dlo_driver_kit.driver_check import check_sync

    s = Settings(rate=16.0)  # arrival period 0.0625 s exactly: half of it is 0.03125

    def late_by(offset, count=None, away=None):
        rec = complete_recording(s)
        for k, (image, state) in enumerate(zip(rec.images, rec.states)):
            if count is not None and k >= count:
                image.wall = None  # arrival unknown: not judged
            else:
                image.wall = state.wall + (offset if away is None or k < away else 0.0)
        return check_sync(rec, s)

    assert late_by(0.03125).status == "PASS"  # half a period off is still the state's own step
    assert late_by(0.0625).status == "FAIL"
    assert late_by(0.0625, count=40, away=10).status == "PASS"  # a quarter of them may be a step away
    assert late_by(0.0625, count=40, away=11).status == "FAIL"


def test_help_describes_every_option_and_the_exit_status(capsys):
    from dlo_driver_kit import driver_check

    with pytest.raises(SystemExit) as exit_:
        driver_check.main(["--help"])
    assert exit_.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    for phrase in (
        "usage: dlo-driver-check",
        "Check the driver (or sim node in real_time mode) running on this ROS "
        "domain against the topic contract, rule by rule: rate, stamps, sync, camera, obey, invalid, stale, "
        "workspace, touch.",
        "nothing else may command the driver meanwhile",
        "--namespace NAMESPACE topics under /NS/dlo/... (as launch_graph.sh --namespace)",
        "--timeout TIMEOUT s to wait for the driver's first state (10)",
        "--duration DURATION s of holding still for rate/camera/touch (2)",
        "--rate RATE expected control rate [Hz] (12.5)",
        "--command-timeout COMMAND_TIMEOUT the driver's command_timeout [s]: a stale command must stop the gripper (0.5)",
        "--speed SPEED speed of the test motions [m/s] (0.1)",
        "--workspace WORKSPACE half width of the square workspace [m] (0.3)",
        "--skip RULE do not judge this rule (repeatable): one of rate, stamps,",
        "Exit status: 0 every rule passed, 1 a rule failed, no driver answered or another node commands "
        "the driver, 2 bad usage, 130 interrupted.",
        "After the rules it compares the driver's latency, rate jitter, speed, closure lag and image noise with the "
        "shipped policy's robustness envelope (lines only).",
    ):
        assert phrase in text, phrase


def test_skip_takes_only_a_rule_name(monkeypatch, capsys):
    from dlo_driver_kit import driver_check

    monkeypatch.setattr(driver_check, "record", lambda *a: pytest.fail("the check ran"))
    with pytest.raises(SystemExit) as exit_:
        driver_check.main(["--skip", "workspaces"])  # a misspelt rule is refused, not silently ignored
    assert exit_.value.code == 2 and "argument --skip: invalid choice: 'workspaces'" in capsys.readouterr().err
