"""dlo_perception.vision.visual_pose (the image kernel) pixel by pixel, on hand-painted top-view images.

The camera is chosen so that everything is exact: 1 m from the gripper's plane, 250 px focal length, so one
pixel is 4 mm and the cable radius 2 px, the occlusion radius 3.625 px, the confidence length 6 px. The
default gripper sits at pixel (u, v) = (40.25, 50.75): the occlusion edge is at u = 43.875, so the strand
starts in column 44 (the first centred beyond it); a pixel's row position relative to the gripper is
row + 0.5 - 50.75. Each scene names the cable pixels the strand must be followed through; the expected
pose then follows from the definition (vision.py): y = -(first column's centre) * 4 mm, angle from the
least-squares line through the columns' centres, confidence from the last followed column's centre less
the cable radius, measured from the occlusion edge. Scenes: tilted strands, the track length, gripper
pixels pushing the start, the patch's edges, the image's borders, gaps, strands nearby and crossing.
"""

import numpy as np
import pytest
from dlo_interface.camera import TopCamera
from dlo_perception.vision import (
    CABLE_RADIUS,
    CONFIDENCE_LENGTH,
    GRIPPER_MARGIN_PIXELS,
    IMAGE_CABLE,
    IMAGE_GRIPPER,
    OCCLUSION_RADIUS,
    SEARCH_HALF_WIDTH,
    TRACK_LENGTH,
    visual_pose,
)

H = W = 96
CAMERA = TopCamera(W, H, 250.0, 250.0, 48.0, 48.0, (0.0, 0.0, 1.25))
PLANE_Z = 0.25  # 1 m below the camera
MPP = 0.004  # m per pixel at PLANE_Z
U, V = 40.25, 50.75  # default gripper pixel
TRACK_COLUMNS = int(np.ceil(TRACK_LENGTH / MPP))  # 11 columns are followed at most
HALF_ROWS = int(np.ceil((SEARCH_HALF_WIDTH + TRACK_LENGTH) / MPP))  # the patch: rows 50 +- 19
PATCH_COLUMNS = int(np.ceil(OCCLUSION_RADIUS / MPP)) + GRIPPER_MARGIN_PIXELS + TRACK_COLUMNS  # columns 40..58


def test_the_camera_makes_the_numbers_exact():
    assert CAMERA.metres_per_pixel(PLANE_Z) == MPP and CABLE_RADIUS / MPP == 2.0
    assert CAMERA.world_to_pixel(np.append(CAMERA.pixel_to_world([U, V], PLANE_Z), PLANE_Z)).tolist() == [U, V]
    assert (TRACK_COLUMNS, HALF_ROWS, PATCH_COLUMNS) == (11, 19, 19)


class Scene:
    """A top view: background 0, cable pixels 255, gripper pixels 128; the gripper at pixel (u, v)."""

    def __init__(self, u=U, v=V):
        self.u, self.v = u, v
        self.image = np.zeros((H, W), np.uint8)

    def cable(self, columns, top, bottom):
        """Cable in rows top..bottom (inclusive) of each column; top/bottom: a row or a function of the column."""
        for column in columns:
            t, b = (top(column) if callable(top) else top), (bottom(column) if callable(bottom) else bottom)
            self.image[max(t, 0) : b + 1, column] = IMAGE_CABLE
        return self

    def gripper(self, columns, top, bottom):
        """The drawn finger, on top of the cable."""
        self.image[top : bottom + 1, columns.start : columns.stop] = IMAGE_GRIPPER
        return self

    @property
    def xy(self):
        return CAMERA.pixel_to_world([self.u, self.v], PLANE_Z)


def expected(scene, followed):
    """O_V (visible, confidence, angle, y) by the definition, from the pixel runs the strand is followed through:
    followed = [(column, top row, bottom row)] in consecutive columns; [] = not visible."""
    if not followed:
        return False, 0.0, 0.0, 0.0
    columns = [column for column, _, _ in followed]
    assert columns == list(range(columns[0], columns[0] + len(columns)))
    centres = np.array([(top + bottom) / 2 + 0.5 - scene.v for _, top, bottom in followed])  # [px], row - v_G
    dx = (columns[-1] + 0.5 - (scene.u + OCCLUSION_RADIUS / MPP)) * MPP - CABLE_RADIUS
    confidence = min(max(dx / CONFIDENCE_LENGTH, 0.0), 1.0)
    row_slope = np.polyfit(np.arange(len(centres)), centres, 1)[0] if len(centres) >= 2 else 0.0
    angle = np.arctan(-row_slope)  # image rows grow with -y
    y = float(np.clip(-centres[0] * MPP, -SEARCH_HALF_WIDTH, SEARCH_HALF_WIDTH))
    return True, confidence, angle, y


def assert_pose(pose, index, want, name=""):
    visible, confidence, angle, y = want
    got = (bool(pose.visible[index]), pose.confidence[index], pose.angle[index], pose.y[index])
    assert got == (visible, pytest.approx(confidence, abs=1e-9), pytest.approx(angle, abs=1e-9), pytest.approx(y, abs=1e-12)), (
        name
    )


def held(scene, top=48, bottom=51, columns=range(10, 44)):
    """The cable up to the gripper (a 4 px thick strand through it) and the finger drawn over it."""
    return scene.cable(columns, top, bottom).gripper(range(37, 44), 44, 57)


def flat(columns, top=48, bottom=51):
    return [(column, top, bottom) for column in columns]


def scenes():
    """(name, scene, followed) in batch order."""
    out = []

    def add(name, scene, followed):
        out.append((name, scene, followed))

    # a strand rising (world +y) by half a row per column; the run of each column counts whole
    rising = [(44, 47, 50), (45, 46, 50), (46, 46, 49), (47, 45, 49), (48, 45, 48)]
    s = held(Scene(), 47, 50)
    for column, top, bottom in rising:
        s.cable([column], top, bottom)
    add("rising", s, rising)
    # a strand one pixel thin at 45 degrees: its pixels touch only diagonally (the gate's +-1 row)
    add(
        "thin_rising",
        Scene().cable(range(30, 61), lambda c: 94 - c, lambda c: 94 - c),
        [(c, 94 - c, 94 - c) for c in range(44, 44 + TRACK_COLUMNS)],
    )
    add(
        "thin_falling",
        Scene().cable(range(30, 61), lambda c: c + 6, lambda c: c + 6),
        [(c, c + 6, c + 6) for c in range(44, 44 + TRACK_COLUMNS)],
    )
    # two pixels thin, rising two rows per column: each column's top pixel touches the next one's bottom
    steep_thin = lambda c: 138 - 2 * c  # noqa: E731  (rows 50..51 in column 44)
    add(
        "thin_steep_rising",
        Scene().cable(range(44, 53), steep_thin, lambda c: steep_thin(c) + 1),
        [(c, steep_thin(c), steep_thin(c) + 1) for c in range(44, 53)],
    )
    # at most TRACK_COLUMNS columns: a kink in the 11th counts, farther ones do not
    s = held(Scene(), columns=range(10, 54)).cable(range(54, 70), lambda c: c - 5, lambda c: c - 2)
    add("kink_in_the_last_column", s, flat(range(44, 54)) + [(54, 49, 52)])
    # the finger drawn wider than the occlusion radius: the strand starts right of its pixels ...
    s = Scene().cable(range(10, 58), 48, 51).cable(range(58, 70), lambda c: c - 9, lambda c: c - 6)
    add("wide_finger", s.gripper(range(36, 48), 43, 58), flat(range(48, 58)) + [(58, 49, 52)])
    # ... and is never followed out of the patch (PATCH_COLUMNS from the gripper's column): 10 columns here
    s = Scene().cable(range(10, 59), 48, 51).cable(range(59, 70), lambda c: c - 10, lambda c: c - 7)
    add("finger_past_the_margin", s.gripper(range(36, 49), 43, 58), flat(range(49, 59)))
    # a gripper pixel anywhere in the patch, even in its last row (v + 19), pushes the start past it
    s = held(Scene()).cable(range(44, 61), lambda c: 92 - c, lambda c: 95 - c)
    s.image[50 + HALF_ROWS, 45] = IMAGE_GRIPPER
    add("gripper_pixel_in_the_patch_corner", s, [(c, 92 - c, 95 - c) for c in range(46, 46 + TRACK_COLUMNS)])
    # the strand ends at the first column without cable: a piece farther right in line is not joined
    s = held(Scene(), columns=range(10, 48)).cable(range(49, 70), 48, 51)
    add("gap", s, flat(range(44, 48)))
    # ... nor one starting two rows off (not touching the previous column's pixels), above or below
    s = held(Scene(), columns=range(10, 48)).cable(range(48, 70), 43, 46)
    add("offset_above", s, flat(range(44, 48)))
    s = held(Scene(), columns=range(10, 48)).cable(range(48, 70), 53, 56)
    add("offset_below", s, flat(range(44, 48)))
    # one column beyond the occlusion edge: visible, but confidence 0 (it ends within a cable radius)
    add("stub", held(Scene(), columns=range(10, 45)), flat([44]))
    add("two_columns", held(Scene(), columns=range(10, 45)).cable([45], 47, 50), flat([44]) + [(45, 47, 50)])
    # two strands in the window: the one nearer the gripper's row wins, above or below it
    s = held(Scene(), 46, 49, columns=range(10, 50)).cable(range(10, 50), 52, 55)
    add("nearer_above", s, flat(range(44, 50), 46, 49))
    s = held(Scene(), 45, 48, columns=range(10, 50)).cable(range(10, 50), 51, 54)
    add("nearer_below", s, flat(range(44, 50), 51, 54))
    # steep strands reach the patch's last rows (v +- 19): what lies beyond is not seen
    steep = {44: (1, 5), 45: (5, 9), 46: (9, 13), 47: (13, 17), 48: (15, 21), 49: (19, 25), 50: (23, 29)}
    s = Scene()
    for column, (top, bottom) in steep.items():
        s.cable([column], 50 + top, 50 + bottom)
    add("steep_down", s, [(44, 51, 55), (45, 55, 59), (46, 59, 63), (47, 63, 67), (48, 65, 69), (49, 69, 69)])
    s = Scene()
    for column, (top, bottom) in steep.items():
        s.cable([column], 50 - bottom, 50 - top)
    add("steep_up", s, [(44, 45, 49), (45, 41, 45), (46, 37, 41), (47, 33, 37), (48, 31, 35), (49, 31, 31)])
    # a strand crossing the followed one (from its 2nd column on): the long run is cut around the prediction;
    # a crossing that reaches equally far above and below leaves the pose of the strand alone ("plain")
    add("crossing", held(Scene(), columns=range(10, 70)).cable(range(45, 47), 20, 80), flat(range(44, 55)))
    add("plain", held(Scene(), columns=range(10, 70)), flat(range(44, 55)))
    # one that starts at the strand and runs down: the cut keeps the rows within half a strand's extent
    # (2 px * sqrt(1 + slope^2) + 0.5, slope 0 then 1/2 row per column) of the predicted row
    s = held(Scene(), columns=range(10, 70)).cable(range(45, 47), 48, 80)
    add("crossing_below", s, flat([44]) + [(45, 48, 52), (46, 48, 53)] + flat(range(47, 55)))
    # in the entry column there is no prediction yet: its run counts whole, however long
    s = held(Scene(), columns=range(10, 70)).cable([44], 40, 80)
    add("crossing_at_the_entry", s, [(44, 40, 69)] + flat(range(45, 55)))
    # another strand's end touching the followed one: a run of 7 rows (2 * 2 px radius + 3) is still one
    # strand, one of 8 rows is cut to the rows within 2.5 px of the prediction
    s = held(Scene(), columns=range(10, 70)).cable([45], 52, 54)
    add("touching_run_of_7", s, flat([44]) + [(45, 48, 54)] + flat(range(46, 55)))
    s = held(Scene(), columns=range(10, 70)).cable([45], 52, 55)
    add("touching_run_of_8", s, flat([44]) + [(45, 48, 52)] + flat(range(46, 55)))
    # the strand rises one row per column into a crossing that lies wholly below its prediction: the
    # cable pixel nearest the prediction (the crossing's top) is taken; nothing follows it
    s = held(Scene()).cable([44], 48, 51).cable([45], 47, 50).cable([46], 46, 49).cable([47], 50, 80)
    add("into_a_crossing_off_the_prediction", s, [(44, 48, 51), (45, 47, 50), (46, 46, 49), (47, 50, 50)])
    # the strand forks: the branch nearer the prediction is followed, on a strand rising one row per
    # column (a branch leaves downwards) as on one falling below the gripper's row (a branch leaves upwards)
    up = lambda c: 92 - c  # noqa: E731  (rows 48..51 in column 44, one higher per column)
    s = held(Scene()).cable(range(44, 60), up, lambda c: up(c) + 3).cable(range(47, 60), lambda c: c + 3, lambda c: c + 6)
    add("fork_rising", s, [(c, up(c), up(c) + 3) for c in range(44, 55)])
    down = lambda c: c + 9  # noqa: E731  (rows 53..56 in column 44, one lower per column)
    s = held(Scene(), 53, 56).cable(range(44, 60), down, lambda c: down(c) + 3)
    s.cable(range(47, 60), lambda c: 98 - c, lambda c: 101 - c)
    add("fork_falling", s, [(c, down(c), down(c) + 3) for c in range(44, 55)])
    # a symmetric fork, both branches exactly as near the prediction: the one higher in the image is taken
    s = held(Scene(), columns=range(10, 46)).cable(range(46, 60), lambda c: 91 - c, lambda c: 94 - c)
    s.cable(range(46, 60), lambda c: c + 5, lambda c: c + 8)
    add("fork_tie", s, flat([44, 45]) + [(c, 91 - c, 94 - c) for c in range(46, 55)])
    # the image's borders: nothing beyond them is cable (the next image of the batch follows the last row)
    add("bottom_border", Scene(v=91.75).cable(range(10, 50), 92, 95), flat(range(44, 50), 92, 95))
    add("top_border", Scene(v=4.75).cable(range(10, 50), 0, 3), flat(range(44, 50), 0, 3))
    add("right_border", Scene(u=88.25).cable(range(0, W), 48, 51), flat(range(92, W)))
    add("left_border", Scene(u=-3.75).cable(range(0, 5), 48, 51), flat(range(0, 5)))
    add("nothing", Scene(), [])
    # not visible: confidence 0 even where the start, pushed past a wide finger, lies far right of the edge
    add("only_a_wide_finger", held(Scene(), columns=range(10, 37)).gripper(range(36, 49), 43, 58), [])
    return out


SCENES = scenes()


@pytest.fixture(scope="module")
def batch():
    images = np.stack([scene.image for _, scene, _ in SCENES])
    return visual_pose(images, CAMERA, np.stack([scene.xy for _, scene, _ in SCENES]), PLANE_Z)


@pytest.mark.parametrize("index", range(len(SCENES)), ids=[name for name, _, _ in SCENES])
def test_pose_of_the_followed_pixels(batch, index):
    name, scene, followed = SCENES[index]
    assert_pose(batch, index, expected(scene, followed), name)


def test_the_expectations_themselves():
    """A few of the scenes' numbers by hand, so that `expected` is not the only word."""
    by_name = {name: expected(scene, followed) for name, scene, followed in SCENES}
    assert by_name["rising"] == pytest.approx(
        (True, (4.625 * MPP - CABLE_RADIUS) / CONFIDENCE_LENGTH, np.arctan(0.5), 1.75 * MPP)
    )
    assert by_name["thin_rising"][2] == pytest.approx(np.pi / 4) and by_name["thin_falling"][2] == pytest.approx(-np.pi / 4)
    assert by_name["stub"] == (True, 0.0, 0.0, 0.75 * MPP)
    assert by_name["two_columns"][2] == pytest.approx(np.pi / 4)
    assert by_name["gap"][1] == pytest.approx((3.625 * MPP - CABLE_RADIUS) / CONFIDENCE_LENGTH)
    assert by_name["kink_in_the_last_column"][2] < -0.01 and by_name["finger_past_the_margin"][2] == pytest.approx(0.0)
    assert by_name["crossing"] == by_name["plain"]


def test_a_stub_is_visible_with_zero_confidence(batch):
    index = [name for name, _, _ in SCENES].index("stub")
    assert batch.visible[index] and batch.confidence[index] == 0.0


def test_the_gripper_height_is_the_plane_given_not_a_third_column():
    """gripper_xy may carry more columns (a z, say): only x and y are read; pixels are at plane_z."""
    name, scene, followed = SCENES[0]
    with_z = np.append(scene.xy, [0.9, 7.0])[None]
    assert_pose(visual_pose(scene.image[None], CAMERA, with_z, PLANE_Z), 0, expected(scene, followed), name)
