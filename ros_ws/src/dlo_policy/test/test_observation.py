"""dlo_policy.observation: the layout of the observation vector and its bounds per modality subset,
batched rows keeping their own values, modality names, and the ablation (``without``) zeroing exactly
the ablated block without ever reading its input."""

import numpy as np
import pytest
from dlo_perception.tactile import TactilePose
from dlo_perception.vision import VisualPose
from dlo_policy.observation import build_observation, observation_bounds, parse_modalities


def test_observation_layout_and_bounds():
    kinematic = np.array([[0.1, -0.2, 0.7]])
    tactile = TactilePose(np.array([0.3]), np.array([0.004]), np.array([True]), np.array([3]))
    visual = VisualPose(np.array([True]), np.array([0.5]), np.array([-0.2]), np.array([0.01]))
    assert build_observation("V+K", kinematic, tactile, visual)[0] == pytest.approx([0.1, -0.2, 0.7, 1.0, 0.5, -0.2, 0.01])
    assert build_observation("T", kinematic, tactile, visual)[0] == pytest.approx([0.3, 0.004])
    assert build_observation(("T", "V"), None, tactile, visual)[0] == pytest.approx([0.3, 0.004, 1.0, 0.5, -0.2, 0.01])
    # everything ablated: a zero row of the full width
    assert build_observation("T+K", without="T+K").tolist() == [[0.0] * 5]
    assert parse_modalities("all") == ("K", "T", "V") and parse_modalities(" v + k ") == ("K", "V")
    for bad in ("", "X", "K+X"):
        with pytest.raises(ValueError):
            parse_modalities(bad)
    with pytest.raises(ValueError):
        build_observation("K+T", kinematic, tactile, without=("V",))
    low, high = observation_bounds("All")
    np.testing.assert_allclose(low, [-0.3, -0.3, 0.0, -np.pi / 2, -0.03, 0.0, 0.0, -np.pi / 2, -0.03], rtol=1e-6)
    np.testing.assert_allclose(high, [0.3, 0.3, 1.0, np.pi / 2, 0.03, 1.0, 1.0, np.pi / 2, 0.03], rtol=1e-6)
    assert observation_bounds("T")[0].dtype == np.float32


def test_batched_observation_rows_keep_their_own_values():
    kinematic = np.array([[0.1, -0.2, 0.7], [0.05, 0.02, 0.9]])
    tactile = TactilePose(np.array([0.3, -0.1]), np.array([0.004, -0.002]), np.array([True, True]), np.array([3, 4]))
    visual = VisualPose(np.array([True, False]), np.array([0.5, 0.0]), np.array([-0.2, 0.0]), np.array([0.01, 0.0]))
    observation = build_observation("All", kinematic, tactile, visual)
    np.testing.assert_allclose(
        observation,
        [[0.1, -0.2, 0.7, 0.3, 0.004, 1.0, 0.5, -0.2, 0.01], [0.05, 0.02, 0.9, -0.1, -0.002, 0.0, 0.0, 0.0, 0.0]],
        rtol=1e-6,
    )


class Unreadable:
    """An input that must not be read (its modality is ablated)."""

    def __getattr__(self, name):
        raise AssertionError(f"the ablated input was read ({name})")


@pytest.mark.parametrize(
    "without, zero",
    [
        (("K",), [0, 1, 2]),
        (("T",), [3, 4]),
        (("V",), [5, 6, 7, 8]),
        (("T", "V"), [3, 4, 5, 6, 7, 8]),
        ("V+K", [0, 1, 2, 5, 6, 7, 8]),
    ],
)
def test_ablation_zeroes_exactly_the_ablated_block_and_never_reads_it(without, zero):
    kinematic = np.array([[0.1, -0.2, 0.7], [0.05, 0.02, 0.9]])
    tactile = TactilePose(np.array([0.3, -0.1]), np.array([0.004, -0.002]), np.array([True, True]), np.array([3, 4]))
    visual = VisualPose(np.array([True, False]), np.array([0.5, 0.0]), np.array([-0.2, 0.0]), np.array([0.01, 0.0]))
    full = build_observation("All", kinematic, tactile, visual)
    inputs = {"K": kinematic, "T": tactile, "V": visual}
    for name in parse_modalities(without):
        inputs[name] = Unreadable()
    ablated = build_observation("All", inputs["K"], inputs["T"], inputs["V"], without=without)
    assert ablated.shape == (2, 9) and ablated.dtype == np.float32
    keep = [c for c in range(9) if c not in zero]
    assert np.all(ablated[:, zero] == 0.0)
    np.testing.assert_array_equal(ablated[:, keep], full[:, keep])


def test_readings_by_keyword_and_calls_that_do_not_fit():
    """build_observation: a reading may be given by keyword (the record's title), also beside positional
    ones; more readings than modalities, an unknown keyword or a reading given twice is a TypeError."""
    kinematic = np.array([[0.1, -0.2, 0.7]])
    tactile = TactilePose(np.array([0.3]), np.array([0.004]), np.array([True]), np.array([3]))
    visual = VisualPose(np.array([True]), np.array([0.5]), np.array([-0.2]), np.array([0.01]))
    assert build_observation("K+T", kinematic=kinematic, tactile=tactile)[0] == pytest.approx([0.1, -0.2, 0.7, 0.3, 0.004])
    assert build_observation("T+V", None, tactile, visual=visual)[0] == pytest.approx([0.3, 0.004, 1.0, 0.5, -0.2, 0.01])
    with pytest.raises(TypeError, match="at most 3 readings, got 4"):
        build_observation("K", kinematic, tactile, visual, visual)
    with pytest.raises(TypeError, match=r"unknown or repeated reading\(s\) \['force'\]"):
        build_observation("K", kinematic, force=kinematic)
    with pytest.raises(TypeError, match=r"unknown or repeated reading\(s\) \['kinematic'\]"):
        build_observation("K", kinematic, kinematic=kinematic)
