"""Episode videos and plots from a bag (dlo-analyze --video / --plots), on a small synthetic bag.

The bag is written with the recorder's BagWriter: two short episodes of every topic the analysis
reads, whose rewards and outcomes come from the task module itself (so dlo-analyze recomputes
them without a mismatch). No ROS processes, no simulator: a few seconds.

Guards: one playable H.264 MP4 per episode with one frame per control step at 12.5 frames/s
(real time); --video-speed changes the rate; --video-format gif writes looping GIFs with 80 ms
frames; titles carry seed, policy, both outcomes and the return; the first step at the end and
the still spans are found; plots are written with the same title and no text of the plot covers
another (issue 20: the subtitle sat on the top view's tick labels); --video reports on stderr, one line
per finished video (a bar too on a terminal); bad options are one line.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import numpy as np
import pytest
from harness import made_up_force_topic

pytest.importorskip("imageio_ffmpeg")

STEPS = (12, 9)  # control steps of the two episodes (step 0 = reset state, then 1..N)
N_C = 40


@pytest.fixture(scope="module")
def synthetic_bag(tmp_path_factory):
    if "DLO_ROOT" not in os.environ:
        pytest.skip("source scripts/env.sh first")
    from dlo_bag.typestore import make_typestore
    from dlo_bag.writer import BagWriter
    from dlo_interface.cloud import pack_particles
    from dlo_interface.task import EpisodeTracker

    ts = make_typestore()
    T = ts.types
    path = tmp_path_factory.mktemp("video") / "bag"
    topics = {
        "/dlo/task/state": "dlo_msgs/msg/TaskState",
        "/dlo/gripper/state": "dlo_msgs/msg/GripperState",
        "/dlo/gripper/cmd": "dlo_msgs/msg/GripperCommand",
        "/dlo/tactile/pose": "dlo_msgs/msg/TactilePose",
        "/dlo/vision/pose": "dlo_msgs/msg/VisualPose",
        "/dlo/rope/particles": "sensor_msgs/msg/PointCloud2",
        "/dlo/camera/image": "sensor_msgs/msg/Image",
    }
    t = 1_000_000_000
    with BagWriter(path, ts, fsync=False) as writer:
        for topic, msgtype in topics.items():
            writer.add_topic(topic, msgtype)

        def put(topic, msg):
            nonlocal t
            t += 1000
            writer.write(topic, ts.serialize_cdr(msg, topics[topic]), t)

        for episode, steps in enumerate(STEPS):
            tracker = EpisodeTracker(1, horizon=steps, task_rules="paper_text")
            for step in range(steps + 1):
                stamp = T["builtin_interfaces/msg/Time"](sec=100 * episode + step, nanosec=0)
                header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="world")
                # the gripper slides along the cable and stops at particle 36 (episode 0: at the end)
                # or at particle 20 (episode 1: stops before); it stands still for the last steps
                target = 36 if episode == 0 else 20
                index = min(2 + 4 * step, target)
                held = np.arange(index - 2, index + 1, dtype=np.int32)
                p_i, n_h, largest = float(held.mean()), len(held), int(held.max())
                if step == 0:
                    tracker.reset([0], np.array([p_i]), np.array([largest]), np.array([N_C]), np.array([p_i]))
                    reward, done = 0.0, False
                else:
                    r, term, trunc = tracker.step(
                        np.array([p_i]),
                        np.array([n_h]),
                        np.array([largest]),
                        np.array([N_C]),
                        np.array([0.4]),
                        np.array([p_i]),
                        np.array([n_h]),
                    )
                    reward, done = float(r[0]), bool(term[0] or trunc[0])
                x = -0.25 + 0.01 * index
                positions = np.stack([-0.25 + 0.01 * np.arange(N_C), np.zeros(N_C), np.full(N_C, 0.1)], axis=1)
                flags = np.isin(np.arange(N_C), held)
                put(
                    "/dlo/rope/particles",
                    T["sensor_msgs/msg/PointCloud2"](
                        header=header,
                        height=1,
                        width=N_C,
                        fields=[
                            T["sensor_msgs/msg/PointField"](name=n, offset=4 * k, datatype=7, count=1)
                            for k, n in enumerate(("x", "y", "z", "held"))
                        ],
                        is_bigendian=False,
                        point_step=16,
                        row_step=16 * N_C,
                        data=np.frombuffer(pack_particles(positions, flags), np.uint8),
                        is_dense=True,
                    ),
                )
                image = np.zeros((32, 32), np.uint8)
                image[16, :] = 255
                image[14:19, int(np.clip(16 + 100 * x, 0, 31))] = 128
                put(
                    "/dlo/camera/image",
                    T["sensor_msgs/msg/Image"](
                        header=header, height=32, width=32, encoding="mono8", is_bigendian=0, step=32, data=image.ravel()
                    ),
                )
                put(
                    "/dlo/task/state",
                    T["dlo_msgs/msg/TaskState"](
                        header=header,
                        episode=episode,
                        seed=500 + episode,
                        step=step,
                        held_indices=held,
                        n_held=n_h,
                        mean_held_index=p_i,
                        num_particles=N_C,
                        cable_length=0.4,
                        reward=reward,
                        episode_return=float(tracker.episode_return[0]),
                        done=done,
                        outcome=int(tracker.outcome[0]) if done else 0,
                        held_indices_authors=held,
                        mean_held_index_authors=p_i,
                        outcome_authors=int(tracker.outcome_authors[0]) if done else 0,
                        task_rules="paper_text",
                        move_spacing=0.0,
                    ),
                )
                put(
                    "/dlo/tactile/pose",
                    T["dlo_msgs/msg/TactilePose"](header=header, angle=0.01 * step, y=0.001, contact=True, contact_count=3),
                )
                put(
                    "/dlo/vision/pose",
                    T["dlo_msgs/msg/VisualPose"](header=header, visible=True, confidence=0.5, angle=-0.01 * step, y=0.002),
                )
                put(
                    "/dlo/gripper/state",
                    T["dlo_msgs/msg/GripperState"](header=header, x=x, y=0.0, z=0.1, closure=0.8, episode=episode, step=step),
                )
                if not done:
                    moving = index < target
                    put(
                        "/dlo/gripper/cmd",
                        T["dlo_msgs/msg/GripperCommand"](
                            header=header, vx=0.25 if moving else 0.0, vy=0.0, closure=0.8, episode=episode, step=step
                        ),
                    )
    return path


def frames_of(path: Path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    return meta, sum(1 for _ in reader)


def test_one_playable_mp4_per_episode(synthetic_bag, tmp_path, capsys):
    from dlo_bag.analysis import main

    out = tmp_path / "videos"
    rc = main(
        [
            str(synthetic_bag),
            "--video",
            str(out),
            "--policy",
            "scripted test",
            "--json",
            str(tmp_path / "e.json"),
            "--plots",
            str(tmp_path / "plots"),
        ]
    )
    assert rc == 0, capsys.readouterr()
    assert sorted(p.name for p in out.iterdir()) == ["episode_0000.mp4", "episode_0001.mp4"]
    for episode, steps in enumerate(STEPS):
        meta, count = frames_of(out / f"episode_{episode:04d}.mp4")
        assert meta["codec"] == "h264" and meta["pix_fmt"].startswith("yuv420p")
        assert abs(meta["fps"] - 12.5) < 1e-6  # real time: one control step (0.08 s) per frame
        assert count == steps + 1  # one frame per recorded step, reset state included
        assert meta["size"] == (960, 720)
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == ["episode_0000.png", "episode_0001.png"]
    import json

    summaries = json.loads((tmp_path / "e.json").read_text())
    assert [s["outcome"] for s in summaries] == ["hold_the_end", "stop_before"]
    assert summaries[0]["video"].endswith("episode_0000.mp4")
    # progress: one line per finished video on stderr (path, frames, time taken); stdout stays the table
    out_text, err_text = capsys.readouterr()
    progress = [line for line in err_text.splitlines() if line.startswith("dlo-analyze: ")]
    assert progress[0] == f"dlo-analyze: rendering 2 videos ({sum(STEPS) + 2} frames) into {out}"
    for k, steps in enumerate(STEPS):
        assert re.fullmatch(
            rf"dlo-analyze: video {k + 1}/2: {re.escape(str(out))}/episode_000{k}\.mp4 "
            rf"\(episode {k}, {steps + 1} frames in \d+\.\d s\)",
            progress[k + 1],
        ), progress
    assert len(progress) == 3 and "dlo-analyze: video" not in out_text
    assert out_text.splitlines()[0].startswith("episode   seed")


def test_video_progress_on_a_terminal_is_a_bar_and_the_lines(synthetic_bag, tmp_path, capsys):
    """On a terminal the same lines come with a tqdm bar over all the frames (to the same stream)."""
    import io

    from dlo_bag.analysis import read_run, write_videos

    class Terminal(io.StringIO):
        def isatty(self):
            return True

    run = read_run(synthetic_bag, extra={"/dlo/camera/image": "image"})
    terminal = Terminal()
    written = write_videos(run, {}, tmp_path / "v", width=160, log=terminal)
    assert [w["episode"] for w in written] == [0, 1]
    text = terminal.getvalue()
    assert "videos: 100%" in text and f"{sum(STEPS) + 2}/{sum(STEPS) + 2}" in text, text  # the bar reached the end
    lines = re.findall(r"dlo-analyze: video \d/2: \S+", text)
    assert [line.split()[-1] for line in lines] == [w["path"] for w in written]
    write_videos(run, {}, tmp_path / "q", width=160)  # no log stream (library use): silent
    assert capsys.readouterr() == ("", "")


def test_gif_and_speed(synthetic_bag, tmp_path):
    from dlo_bag.analysis import main
    from PIL import Image

    assert main([str(synthetic_bag), "--video", str(tmp_path / "gif"), "--video-format", "gif", "--video-width", "320"]) == 0
    with Image.open(tmp_path / "gif" / "episode_0001.gif") as gif:
        assert gif.n_frames == STEPS[1] + 1 and gif.size == (320, 240)
        assert gif.info["duration"] == 80 and gif.info.get("loop") == 0
    assert main([str(synthetic_bag), "--video", str(tmp_path / "fast"), "--video-speed", "2", "--video-width", "320"]) == 0
    meta, count = frames_of(tmp_path / "fast" / "episode_0000.mp4")
    assert abs(meta["fps"] - 25.0) < 1e-6 and count == STEPS[0] + 1


def test_titles_marks_and_still_spans(synthetic_bag):
    from dlo_bag.analysis import episode_title, read_run, recompute_episode
    from dlo_bag.episode_series import episode_series, still_spans
    from dlo_bag.video import EpisodeFrames, video_title

    run = read_run(synthetic_bag, extra={"/dlo/camera/image": "image"})
    summary = {"episode": 0, **recompute_episode(run[0]["task"])}
    title = video_title(0, summary, "sac (shipped)")
    assert "seed 500" in title and "sac (shipped)" in title and "return" in title
    assert "hold_the_end (paper rule)" in title and "(authors' rule)" in title
    assert episode_title(0, summary).splitlines()[0].startswith("episode 0  ·  seed 500  ·  return")
    s = episode_series(0, run[0])
    # index 2 + 4 k reaches particle 30 = n_c - 10 at step 7 (largest held index 30)
    assert s.first_at_end == 7 and s.final_step == STEPS[0]
    s1 = episode_series(1, run[1])
    assert s1.first_at_end is None
    assert still_spans(s, min_steps=3) == [(9, 12)]  # stopped at particle 36 from step 9 on
    frames = EpisodeFrames(0, run[0], summary, policy="x", width=480)
    rgb = frames.frame(3)
    assert rgb.shape == (360, 480, 3) and rgb.dtype == np.uint8 and rgb.std() > 10
    frames.close()


def test_bad_video_options_are_one_line(synthetic_bag, tmp_path, capsys):
    from dlo_bag.analysis import main

    with pytest.raises(SystemExit) as err:
        main([str(synthetic_bag), "--video", str(tmp_path / "v"), "--video-speed", "0"])
    assert err.value.code == 2
    assert "--video-speed must be > 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(synthetic_bag), "--video", str(tmp_path / "v"), "--video-format", "avi"])
    assert not (tmp_path / "v").exists()


def text_overlaps(fig) -> list:
    """Pairs of texts of a drawn figure whose boxes (matplotlib's renderer, display pixels) intersect: the
    suptitle and every axes title against each other, against every axis' drawn tick labels and label
    (``Axis.get_tightbbox``: only the ticks inside the view) and against the legends; legends against each
    other and against other axes' tick labels."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.text import Text

    renderer = FigureCanvasAgg(fig).get_renderer()
    fig.draw(renderer)  # the layout engine places everything on a draw
    suptitle = [t for t in fig.findobj(Text) if t.get_text() and t is getattr(fig, "_suptitle", None)]
    titles = [("suptitle", t.get_window_extent(renderer)) for t in suptitle]
    titles += [(f"axes {i} title", ax.title.get_window_extent(renderer)) for i, ax in enumerate(fig.axes) if ax.title.get_text()]
    axis_boxes, legends = [], []
    for i, ax in enumerate(fig.axes):
        for name, axis in (("x", ax.xaxis), ("y", ax.yaxis)):
            box = axis.get_tightbbox(renderer)
            if box is not None and box.width > 0 and box.height > 0:
                axis_boxes.append((i, f"axes {i} {name} tick labels and label", box))
        if ax.get_legend() is not None:
            legends.append((i, f"axes {i} legend", ax.get_legend().get_window_extent(renderer)))
    found = []
    for k, (name, box) in enumerate(titles):
        others = [(n, b) for n, b in titles[k + 1 :]] + [(n, b) for _, n, b in axis_boxes + legends]
        found += [(name, n) for n, b in others if box.overlaps(b)]
    for k, (i, name, box) in enumerate(legends):
        found += [(name, n) for j, n, b in legends[k + 1 :] + axis_boxes if j != i and box.overlaps(b)]
    return found


def test_the_episode_plot_has_no_overlapping_texts(synthetic_bag):
    """The plot's titles (the figure's two-line title, the top view's, the signals' subtitle) do not cover
    any axis' tick labels or each other, and the legends outside the axes do not cover each other: checked
    on the boxes matplotlib's renderer draws, for both episodes (one with the still-gripper annotation)."""
    from dlo_bag.analysis import episode_figure, read_run, recompute_episode

    run = read_run(synthetic_bag)
    for episode in run:
        summary = {"episode": episode, **recompute_episode(run[episode]["task"])}
        fig = episode_figure(episode, run[episode], summary)
        assert text_overlaps(fig) == [], episode
        assert [ax.get_title() for ax in fig.axes[:2]] == [
            "top view (world frame)",
            "signals over the episode (dotted: first step at the end, green = paper "
            "rule, purple = authors' rule; grey: gripper still)",
        ]


def test_the_plots_observation_axes_come_from_the_registry(synthetic_bag, monkeypatch):
    """The episode plot's observation series are the plot series of the registry's observation topics
    (dlo_common.topics): the paper's with the closure (q_V) and on the angle (theta_T, theta_V) and offset axes
    (y_T, y_V in mm); a topic added with a series of another unit gets an axis of its own with its values, with no
    change to bag analysis; a unit the bag has no value of gets none."""
    from types import SimpleNamespace

    from dlo_bag.analysis import episode_figure, read_run
    from dlo_common import topics

    streams = read_run(synthetic_bag)[0]

    def axes(fig) -> dict:
        """{y label: {legend label: line}} of the signal axes."""
        return {
            ax.get_ylabel(): {ln.get_label(): ln for ln in ax.get_lines() if not ln.get_label().startswith("_")}
            for ax in fig.axes[1:]
        }

    paper = axes(episode_figure(0, streams))
    layout = ["closure [-]", "held particle\nindex [-]", "angle [rad]", "offset [mm]", "command\n[m/s]", "reward [-]"]
    assert list(paper) == layout
    assert list(paper["closure [-]"]) == ["c_G measured", "c_G commanded", "q_V vision"]
    assert list(paper["angle [rad]"]) == ["θ_T tactile", "θ_V vision"]
    assert list(paper["offset [mm]"]) == ["y_T tactile", "y_V vision"]
    steps = sorted(streams["tactile"])
    y_t = paper["offset [mm]"]["y_T tactile"]
    np.testing.assert_allclose(y_t.get_ydata()[: len(steps)], [1000 * streams["tactile"][k].y for k in steps])

    wrist = made_up_force_topic(topics.Series("wrench.force.x", "G_x", "kN"), topics.Series("wrench.force.y", "G_y", "kN"))
    monkeypatch.setattr(topics, "TOPICS", topics.TOPICS + (wrist,))
    assert list(axes(episode_figure(0, streams))) == layout  # no force in the bag: no force axis
    force = {
        k: SimpleNamespace(wrench=SimpleNamespace(force=SimpleNamespace(x=0.5 * k, y=-0.25 * k))) for k in streams["gripper"]
    }
    added = axes(episode_figure(0, {**streams, "test_force": force}))
    assert list(added) == layout[:4] + ["[kN]"] + layout[4:]  # a unit without a word: its axis says the unit
    assert list(added["[kN]"]) == ["G_x test_force", "G_y test_force"]
    np.testing.assert_allclose(added["[kN]"]["G_y test_force"].get_ydata(), [-0.25 * k for k in sorted(force)])


def strip_rows(frames) -> dict:
    """{y label (on one line): {legend label: line}} of a video's strip rows (the cursor and the marks have no legend)."""
    return {
        ax.get_ylabel().replace("\n", " "): {ln.get_label(): ln for ln in ax.get_lines() if not ln.get_label().startswith("_")}
        for ax in frames.strip_axes
    }


def test_the_video_strip_follows_the_registry(synthetic_bag, monkeypatch):
    """The video strip's rows are the plots' (``dlo_bag.analysis.observation_axes``): the closure with the unitless
    observation series (q_V), one row per other unit of the registry's observation plot series in registry order
    (angles; offsets in mm), the reward last, labelled as the plots label them. A topic added to the registry gets
    rows with no change to the video: its unitless series with the closure, a new unit a row of its own, in a frame of
    the same size; a unit the episode has no value of gets no row (as in the plots)."""
    from types import SimpleNamespace

    from dlo_bag.analysis import read_run
    from dlo_bag.video import EpisodeFrames
    from dlo_common import topics

    streams = read_run(synthetic_bag, extra={"/dlo/camera/image": "image"})[0]

    def rows(streams) -> dict:
        frames = EpisodeFrames(0, streams, {}, width=480)
        try:
            assert frames.frame(3).shape == (360, 480, 3)  # the frame keeps its size, whatever the rows
            return strip_rows(frames)
        finally:
            frames.close()

    paper = rows(streams)
    layout = ["closure [-]", "angle [rad]", "offset [mm]", "reward [-]"]
    assert list(paper) == layout
    assert list(paper["closure [-]"]) == ["closure c_G", "q_V vision"]
    assert list(paper["angle [rad]"]) == ["θ_T tactile", "θ_V vision"]
    assert list(paper["offset [mm]"]) == ["y_T tactile", "y_V vision"]
    assert list(paper["reward [-]"]) == ["reward"]
    steps = sorted(streams["tactile"])
    y_v = paper["offset [mm]"]["y_V vision"].get_ydata()
    np.testing.assert_allclose(y_v, [1000 * streams["vision"][k].y for k in steps])

    wrist = made_up_force_topic(
        topics.Series("wrench.force.x", "G_x", "kN"),
        topics.Series("wrench.force.y", "G_y", "kN"),
        topics.Series("wrench.torque.z", "g_q", "-"),
    )
    monkeypatch.setattr(topics, "TOPICS", topics.TOPICS + (wrist,))
    assert list(rows(streams)) == layout  # no force in the episode: no force row (the unitless one has the closure)
    force = {
        k: SimpleNamespace(wrench=SimpleNamespace(force=SimpleNamespace(x=0.5 * k, y=-0.25 * k), torque=SimpleNamespace(z=0.1)))
        for k in streams["gripper"]
    }
    added = rows({**streams, "test_force": force})
    assert list(added) == layout[:3] + ["[kN]"] + layout[3:]  # a unit without a word: its row says the unit
    assert list(added["[kN]"]) == ["G_x test_force", "G_y test_force"]
    assert list(added["closure [-]"]) == ["closure c_G", "q_V vision", "g_q test_force"]
    np.testing.assert_allclose(added["[kN]"]["G_y test_force"].get_ydata(), [-0.25 * k for k in sorted(force)])
