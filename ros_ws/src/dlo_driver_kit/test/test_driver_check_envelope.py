"""dlo-driver-check against the shipped policy's robustness envelope (no ROS): the packaged extract is the committed
envelope's; the driver's command-to-state latency, rate jitter, speed, closure lag and image noise measured on
synthetic recordings of drivers with exactly that defect; each compared with the family's 80% tolerance, within or
beyond; and a clear line when the envelope is not installed."""

from __future__ import annotations

import json
import math
import re
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_driver_kit import envelope as shipped  # noqa: E402
from dlo_driver_kit.driver_check import (  # noqa: E402
    ImageSample,
    InfoSample,
    Settings,
    envelope_lines,
    image_noise,
    lag_time_constant,
    motion_latency,
    phase_window,
    response_delay,
)
from dlo_driver_kit.mock_driver_node import draw_cable, mock_cable  # noqa: E402
from dlo_interface.camera import TopCamera  # noqa: E402
from test_driver_check import CLOSURE_TAU, SLOW, complete_recording, ideal_recording, run_main  # noqa: E402

ROOT = Path(__file__).resolve().parents[4]
COMMITTED = ROOT / "results" / "robustness" / "shipped" / "robustness.json"
ENVELOPE, _ = shipped.load()


def line(lines: list[str], start: str) -> str:
    found = [text for text in lines if text.startswith(start)]
    assert len(found) == 1, lines
    return found[0]


def test_the_packaged_envelope_is_the_committed_one_and_ships_in_the_package():
    assert shipped.ENVELOPE_FILE.parent == Path(shipped.__file__).resolve().parent  # no path outside the package
    assert ENVELOPE == shipped.extract(json.loads(COMMITTED.read_text()))
    assert shipped.main([str(COMMITTED), "--check"]) == 0
    assert shipped.tolerance(ENVELOPE, "action_delay") == (1.0, "both rules")
    assert shipped.tolerance(ENVELOPE, "vision_angle_noise") == (20.0, "paper rule")  # the stricter rule
    assert shipped.tolerance(ENVELOPE, "velocity_gain", "below") == (0.25, "authors' rule")
    assert shipped.tolerance(ENVELOPE, "bending_stiffness") == (None, "")
    setup = (ROOT / "ros_ws" / "src" / "dlo_driver_kit" / "setup.py").read_text()
    assert "shipped_envelope.json" in setup  # installed with the module


def test_response_delay_counts_steps_late_and_a_lag_as_its_time_constant():
    assert response_delay([(0, 0), (0, 0), (1, 0), (1, 0)], (0, 0), (1, 0)) == 2.0
    assert response_delay([0.5, 1.0, 1.0], 0.0, 1.0) == 0.5  # half a step late
    rate = -math.expm1(-0.08 / 0.16)
    levels = [1 - (1 - rate) ** (j + 1) for j in range(8)]
    steps = response_delay(levels, 0.0, 1.0)
    assert lag_time_constant(steps, 8, 0.08) == pytest.approx(0.16)
    assert lag_time_constant(0.0, 8, 0.08) == 0.0 and lag_time_constant(8.0, 8, 0.08) == math.inf


@pytest.mark.parametrize(
    "fault, latency, verdict",
    [("", "latency 0.0 steps", "within"), ("late", "latency 1.0 step", "beyond"), ("drops", "latency 0.0 steps", "within")],
)
def test_latency_is_measured_in_control_steps_and_compared_with_the_delay_tolerance(fault, latency, verdict):
    s = Settings()
    rec = ideal_recording(s, fault)
    delays = motion_latency(rec, s)
    assert len(delays) >= 2 and delays == pytest.approx([1.0 if fault == "late" else 0.0] * len(delays), abs=1e-9)
    text = line(envelope_lines(rec, s, ENVELOPE), "latency")
    assert text.startswith(latency + " (command to state: median of")
    assert f": {verdict} the shipped policy's 80% tolerance of 1 step of delay (action_delay; below 80% from there" in text


def test_speed_closure_lag_and_jitter_against_their_families():
    s = Settings()
    slow = envelope_lines(ideal_recording(s, "slow"), s, ENVELOPE)
    assert line(slow, "speed").startswith(f"speed {SLOW:.2f}x the commanded (median of the moves): within")
    assert "below 80% at 0.25x and slower (authors' rule), 1.5x and faster (both rules)" in line(slow, "speed")
    lagging = envelope_lines(ideal_recording(s, "closure_lag"), s, ENVELOPE)
    assert line(lagging, "closure lag").startswith(f"closure lag {CLOSURE_TAU:.2f} s")
    assert "beyond the shipped policy's 80% tolerance of 0.16 s (closure_lag" in line(lagging, "closure lag")
    assert line(envelope_lines(ideal_recording(s), s, ENVELOPE), "closure lag").startswith("closure lag 0.00 s")
    jittery = ideal_recording(s)
    rng = np.random.default_rng(0)
    for x in jittery.states:  # arrivals up to 12 ms off the 80 ms tick
        x.wall += rng.uniform(-0.012, 0.012)
    text = line(envelope_lines(jittery, s, ENVELOPE), "rate jitter")
    std = float(re.match(r"rate jitter ([\d.]+) ms", text).group(1))
    assert 8 < std < 12, text  # differences of two uniforms of +-12 ms: std 9.8 ms
    assert "latency with it 0.2" in text or "latency with it 0.3" in text, text
    assert line(envelope_lines(ideal_recording(s), s, ENVELOPE), "rate jitter").startswith("rate jitter 0.0 ms")


def with_still_images(s: Settings, sigma_m: float, lost_every: int = 0):
    """complete_recording whose hold-still images show the mock cable shifted along y by N(0, sigma_m) in each (a
    noisy camera and segmentation), the cable missing from every ``lost_every``-th."""
    rec = complete_recording(s)
    camera = TopCamera.covering_workspace(128)
    rec.infos = [InfoSample(128, 128, tuple(camera.k_matrix.ravel()), "top_camera_optical")]
    window = phase_window(rec, "idle")
    rng = np.random.default_rng(1)
    cable = mock_cable(0.3, 0.0)
    for k, (im, x) in enumerate(zip(rec.images, rec.states)):
        if window[0] <= x.wall <= window[1]:
            shifted = cable + np.array([0.0, rng.normal(0.0, sigma_m), 0.0])
            pixels = np.zeros((128, 128), np.uint8) if lost_every and k % lost_every == 0 else draw_cable(shifted, camera)
            rec.images[k] = ImageSample(128, 128, "mono8", 128, 128 * 128, im.frame_id, im.stamp_ns, (0, 255), pixels=pixels)
    return rec


def test_image_noise_is_estimated_from_the_images_while_holding_still():
    s = Settings()
    clean = image_noise(with_still_images(s, 0.0))
    n = clean["images"]  # the idle phase's: 2 s at 12.5 Hz
    assert 25 <= n <= 26 and clean["visible"] == n and clean["y_std"] == clean["angle_std"] == 0.0
    noisy = with_still_images(s, 0.006)
    estimate = image_noise(noisy)
    assert estimate["visible"] == n and 0.003 < estimate["y_std"] < 0.009, estimate
    lines = envelope_lines(noisy, s, ENVELOPE)
    (y_line,) = [text for text in lines if " mm on y_V " in text]
    assert re.match(
        rf"image noise \d\.\d mm on y_V \(std over {n} images holding still, the cable seen in {n}\): within the "
        r"shipped policy's 80% tolerance of 16 mm \(vision_offset_noise",
        y_line,
    ), y_line
    (angle_line,) = [text for text in lines if " deg on theta_V " in text]
    assert "the shipped policy's 80% tolerance of 20 deg (vision_angle_noise; below 80% from there, paper rule)" in angle_line
    flicker = line(envelope_lines(with_still_images(s, 0.0, lost_every=5), s, ENVELOPE), "detection flicker")
    lost = len(range(0, n, 5))
    assert flicker.startswith(f"detection flicker {lost / n:.0%} (the cable lost in {lost} of {n} still images): within")
    assert "tolerance of 0.8 (vision_dropout" in flicker
    assert image_noise(ideal_recording(s)) is None  # no images: said so
    assert line(envelope_lines(ideal_recording(s), s, ENVELOPE), "image noise").startswith("image noise: not estimated")


def test_without_the_envelope_the_checker_still_measures_and_says_why_it_cannot_compare(tmp_path):
    envelope, why = shipped.load(tmp_path / "shipped_envelope.json")
    assert envelope is None and why.startswith("the shipped policy's envelope is not installed")
    s = Settings()
    lines = envelope_lines(ideal_recording(s, "late"), s, envelope, why)
    assert line(lines, "latency").endswith(f": not compared ({why})") and "latency 1.0 step " in lines[0]


def test_the_check_prints_the_envelope_section_after_the_rules_and_it_changes_no_exit_status(monkeypatch, capsys):
    s = Settings()
    rc, out, _ = run_main(monkeypatch, capsys, complete_recording(s))
    assert rc == 0 and "9/9 rules passed\nAgainst the shipped policy's robustness envelope" in out
    assert re.search(r"^  latency 0\.0 steps \(.*\): within the shipped policy's 80% tolerance of 1 step of delay", out, re.M)
    late = complete_recording(s)
    late.states = ideal_recording(s, "late").states
    rc, out, _ = run_main(monkeypatch, capsys, late)
    assert re.search(r"^  latency 1\.0 step \(.*\): beyond the shipped policy's 80% tolerance of 1 step of delay", out, re.M)
