"""Reports of steps whose inputs never meet by stamp (dlo_perception.sync.IncompleteSteps; issue 20):

- the line names the missing input and the stamps each input did carry nearby, exactly (nanoseconds),
  and says so when a stamp is a few microseconds off (a clock read per message, not a lost message);
- one line a second at most with the count of the other incomplete steps, never one per step; a
  step that completes is never reported; a step of the state is preferred to a stamp of another input;
- tactile_node in-process (no graph), fed a driver whose state is stamped 0.4 us after its particle
  cloud: about one error a second, each naming the particle cloud's and the state's stamps.
"""

import pytest
from dlo_perception.sync import NEAR_MISS_NS, IncompleteSteps, StampSync, format_stamp
from harness import LogLines

STEP_NS = 80_000_000


def test_stamps_are_printed_exactly():
    assert format_stamp(1_280_000_400) == "1.2800004"
    assert format_stamp(1_360_000_000) == "1.36"
    assert format_stamp(0) == "0"
    assert format_stamp(1_796_194_734_574_954_704) == "1796194734.574954704"  # beyond a float's precision


def run(sync, report, feeds, period=0.08, steps=40):
    """Feed ``steps`` control steps (``feeds``: key -> stamp offset [ns], None = never) every ``period`` s;
    -> [(time, line)] of the lines ``report.note`` gave."""
    lines = []
    for k in range(steps):
        now, stamp = k * period, 1_280_000_000 + k * STEP_NS
        for key, offset in feeds.items():
            if offset is None:
                continue
            matched = sync.add(key, stamp + offset, key) is not None
            line = report.note(sync, stamp + offset, matched, now, prefer="gripper")
            if line is not None:
                lines.append((now, line))
    return lines


def test_a_state_stamped_apart_from_its_cloud_is_named_once_a_second_with_both_stamps():
    lines = run(StampSync(("particles", "gripper")), IncompleteSteps(timeout=1.0), {"particles": 0, "gripper": 400})
    assert 2 <= len(lines) <= 3  # 3.2 s of steps: a line a second, not one per step (40)
    assert all(b[0] - a[0] >= 1.0 for a, b in zip(lines, lines[1:]))
    first = lines[0][1]
    assert first.startswith(
        "step at t=1.28 s: no particles input after 1.0 s; particle cloud has stamps 1.28, 1.36 "
        "nearby; gripper state at 1.2800004 (the particle cloud's nearest stamp is 0.4 us "
        "earlier: every input of a step must carry the state's exact stamp)"
    ), first
    assert "12 other incomplete steps since the last report" in lines[1][1]  # the states of a second, not stamps


def test_a_missing_input_and_complete_steps():
    lines = run(
        StampSync(("gripper", "tactile", "vision")), IncompleteSteps(timeout=1.0), {"gripper": 0, "vision": 0, "tactile": None}
    )
    assert (
        lines
        and "no tactile input after 1.0 s; gripper state at 1.28; tactile: nothing received yet (is tactile_node running?"
        in lines[0][1]
        and "vision at 1.28" in lines[0][1]
    )
    assert run(StampSync(("gripper", "tactile")), IncompleteSteps(timeout=1.0), {"gripper": 0, "tactile": 0}) == []


def test_a_step_is_reported_only_after_the_timeout_and_the_state_first():
    sync, report = StampSync(("particles", "gripper")), IncompleteSteps(timeout=1.0)
    sync.add("particles", 5, None)
    report.seen(5, 0.0)
    sync.add("gripper", 9, None)
    report.seen(9, 0.001)
    assert report.check(sync, 1.0, prefer="gripper") is None  # nothing older than 1 s yet
    line = report.check(sync, 1.5, prefer="gripper")  # both stamps incomplete: the state's step is reported
    assert line.startswith("step at t=0.00 s: no particles input after 1.0 s; particle cloud has stamps 0.000000005")
    assert "gripper state at 0.000000009" in line and "(1 other" not in line
    assert report.check(sync, 5.0) is None  # reported once
    sync.add("particles", 2_000_000_000, None)  # a cloud whose state never comes
    report.seen(2_000_000_000, 5.0)
    assert report.check(sync, 6.5, prefer="gripper").startswith(
        "step at t=2.00 s: no gripper input after 1.0 s; particle cloud at 2; gripper state has stamps"
    )


def test_an_unknown_input_is_a_key_error_and_changes_nothing():
    sync = StampSync(("image", "gripper"))
    with pytest.raises(KeyError, match="unknown input 'depth'; inputs are"):
        sync.add("depth", 5, None)
    assert sync.pending == {} and sync.missing(5) == ["image", "gripper"]


def test_only_the_latest_history_stamps_of_an_input_count_as_seen():
    sync = StampSync(("image", "gripper"), history=4)
    for stamp in range(6):
        sync.add("image", stamp, stamp)
    assert sync.missing(5) == ["gripper"]
    assert sync.missing(1) == ["image", "gripper"]  # older than the image's last 4 stamps
    assert sync.nearby("image", 0) == [2, 3]


def test_a_completed_step_supersedes_the_incomplete_older_ones_and_depth_bounds_the_rest():
    sync = StampSync(("image", "gripper"), depth=3)
    for stamp in (1, 2, 3, 4, 5):
        assert sync.add("image", stamp, stamp) is None
    assert sorted(sync.pending) == [3, 4, 5]  # the newest 3
    assert sync.add("gripper", 4, "g4") == (4, "g4")
    assert sorted(sync.pending) == [5]  # 3 superseded by 4
    assert sync.add("gripper", 5, "g5") == (5, "g5") and sync.pending == {}


def test_nearby_stamps_are_the_closest_ones_in_time_order_wherever_the_step_lies():
    sync = StampSync(("image", "gripper"))
    for k in range(10):
        sync.add("image", 1_000_000_000 + k * STEP_NS, None)
    middle = 1_000_000_000 + 5 * STEP_NS
    assert sync.nearby("image", middle + 400) == [middle, middle + STEP_NS]
    assert sync.nearby("image", middle - 400) == [middle - STEP_NS, middle]
    assert sync.nearby("image", middle + 400, count=3) == [middle - STEP_NS, middle, middle + STEP_NS]
    assert sync.nearby("gripper", middle) == []


def seen_line(offsets, keys=("gripper", "tactile", "vision")):
    """stamps_seen of the step at 1.28 s when each input of ``offsets`` (key -> [ns off the step]) carried those."""
    sync = StampSync(keys)
    for key, offs in offsets.items():
        for off in offs:
            sync.add(key, 1_280_000_000 + off, None)
    return sync.stamps_seen(1_280_000_000)


def test_the_nearest_stamp_decides_a_near_miss_earlier_or_later_and_the_closest_input_is_named():
    later = seen_line({"gripper": [0], "tactile": [-STEP_NS + 400, 400]}, ("gripper", "tactile"))
    assert later.endswith(
        "(the tactile's nearest stamp is 0.4 us later: every input of a step must carry the state's exact stamp)"
    ), later
    both = seen_line({"gripper": [0], "tactile": [-400], "vision": [100]})
    assert "(the vision's nearest stamp is 0.1 us later" in both, both  # the closer of two near misses
    tie = seen_line({"gripper": [0], "tactile": [400], "vision": [-400]})
    assert "(the tactile's nearest stamp is 0.4 us later" in tie, tie  # the first input of a tie
    one_ns = seen_line({"gripper": [0], "tactile": [1]}, ("gripper", "tactile"))
    assert "nearest stamp is 0.001 us later" in one_ns, one_ns
    for far in (NEAR_MISS_NS, STEP_NS):  # 20 ms or more: another step, not a clock read apart
        text = seen_line({"gripper": [0], "tactile": [far]}, ("gripper", "tactile"))
        assert "nearest stamp" not in text and text.startswith("gripper state at 1.28; tactile has stamps"), text


def test_an_input_of_no_known_publisher_that_sent_nothing_asks_for_its_publisher():
    text = seen_line({"tactile": [0]}, ("gripper", "tactile"))
    assert text == "gripper state: nothing received yet (is its publisher running?); tactile at 1.28", text


def test_a_shared_first_seen_is_the_one_used_and_a_matched_step_leaves_it():
    first_seen = {}
    report = IncompleteSteps(first_seen=first_seen)
    sync = StampSync(("image", "gripper"))
    sync.add("image", 5, None)
    assert report.note(sync, 5, False, 0.0) is None and first_seen == {5: 0.0}
    assert sync.add("gripper", 5, None) is not None
    assert report.note(sync, 5, True, 0.5) is None and first_seen == {}  # nothing kept of a completed step
    assert report.check(sync, 5.0) is None


def test_a_step_every_input_delivered_or_none_still_holds_is_not_reported():
    sync, report = StampSync(("image", "gripper")), IncompleteSteps(timeout=1.0)
    sync.add("image", 5, None)
    sync.add("gripper", 5, None)  # complete, though the node did not call matched()
    report.seen(5, 0.0)
    assert report.check(sync, 2.0) is None and report.first_seen == {}
    sync, report = StampSync(("image", "gripper"), history=2), IncompleteSteps(timeout=1.0)
    sync.add("image", 7, None)
    report.seen(7, 0.0)
    for stamp in (8, 9):  # the image's stamp 7 ages out of its history of 2: no input holds it now
        sync.add("image", stamp, None)
    assert report.check(sync, 2.0) is None and report.first_seen == {}


def test_a_line_once_interval_has_passed_not_before():
    sync, report = StampSync(("image", "gripper")), IncompleteSteps(timeout=1.0, interval=1.0)
    for stamp, at in ((1, 0.0), (2, 1.0), (3, 1.5)):
        sync.add("image", stamp, None)
        report.seen(stamp, at)
    assert report.check(sync, 1.5) is not None  # stamp 1, waiting 1.5 s
    assert report.check(sync, 2.25) is None  # stamp 2 is due, but the last line was 0.75 s ago
    assert report.check(sync, 2.5) is not None  # exactly 1 s after the last line


# ------------------------------------------------------------------------------- tactile_node in-process
rclpy = pytest.importorskip("rclpy")


def test_tactile_node_reports_a_state_stamped_apart_from_its_cloud(context, monkeypatch):
    import numpy as np
    from dlo_interface.cloud import particle_cloud
    from dlo_msgs.msg import GripperState
    from dlo_perception import tactile_node as module

    init = rclpy.node.Node.__init__
    monkeypatch.setattr(rclpy.node.Node, "__init__", lambda self, *a, **k: init(self, *a, **{"context": context, **k}))
    node = module.TactileNode()
    monkeypatch.setattr(rclpy.node.Node, "__init__", init)
    log, clock = LogLines(), [50.0]
    monkeypatch.setattr(node, "get_logger", lambda: log)
    monkeypatch.setattr(module, "time", type("Clock", (), {"monotonic": staticmethod(lambda: clock[0])}))
    published = []
    node.publisher = type("Published", (), {"publish": staticmethod(published.append)})()
    try:
        for k in range(50):  # 4 s of a driver whose state is stamped 0.4 us after its cloud
            cloud = particle_cloud(np.array([[-0.25, 0.0, 0.1], [0.0, 0.0, 0.1]]), [False, True])
            state = GripperState(x=0.0, y=0.0, z=0.1, closure=0.7, episode=0, step=k)
            cloud.header.stamp.sec, cloud.header.stamp.nanosec = divmod(1_000_000_000 + k * STEP_NS, 1_000_000_000)
            state.header.stamp.sec, state.header.stamp.nanosec = divmod(1_000_000_400 + k * STEP_NS, 1_000_000_000)
            node.on_input("particles", cloud)
            node.on_input("gripper", state)
            clock[0] += 0.08
    finally:
        node.destroy_node()
    assert published == []  # no step ever matched
    assert 3 <= len(log.of("error")) <= 4, log.of("error")  # once a second, not 50 times
    assert log.of("error")[0].startswith(
        "step at t=1.00 s: no particles input after 1.0 s; particle cloud has stamps 1, 1.08 nearby; gripper state at 1.0000004"
    ), log.of("error")[0]
