"""Episode videos and plots from a bag (dlo-analyze --video / --plots), on a small synthetic bag.

The bag is written with the recorder's BagWriter: two short episodes of every topic the analysis
reads, whose rewards and outcomes come from the task module itself (so dlo-analyze recomputes
them without a mismatch). No ROS processes, no simulator: a few seconds.

Guards: one playable H.264 MP4 per episode with one frame per control step at 12.5 frames/s
(real time); --video-speed changes the rate; --video-format gif writes looping GIFs with 80 ms
frames; titles carry seed, policy, both outcomes and the return; the first step at the end and
the still spans are found; plots are written with the same title; bad options are one line.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("imageio_ffmpeg")

STEPS = (12, 9)  # control steps of the two episodes (step 0 = reset state, then 1..N)
N_C = 40


@pytest.fixture(scope="module")
def synthetic_bag(tmp_path_factory):
    if "DLO_ROOT" not in os.environ:
        pytest.skip("source scripts/env.sh first")
    from dlo_perception.cloud import pack_particles
    from dlo_sim.task import EpisodeTracker
    from dlo_tools.bag import BagWriter, make_typestore

    ts = make_typestore()
    T = ts.types
    path = tmp_path_factory.mktemp("video") / "bag"
    topics = {"/dlo/task/state": "dlo_msgs/msg/TaskState", "/dlo/gripper/state": "dlo_msgs/msg/GripperState",
              "/dlo/gripper/cmd": "dlo_msgs/msg/GripperCommand", "/dlo/tactile/pose": "dlo_msgs/msg/TactilePose",
              "/dlo/vision/pose": "dlo_msgs/msg/VisualPose", "/dlo/rope/particles": "sensor_msgs/msg/PointCloud2",
              "/dlo/camera/image": "sensor_msgs/msg/Image"}
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
                    r, term, trunc = tracker.step(np.array([p_i]), np.array([n_h]), np.array([largest]),
                                                  np.array([N_C]), np.array([0.4]), np.array([p_i]),
                                                  np.array([n_h]))
                    reward, done = float(r[0]), bool(term[0] or trunc[0])
                x = -0.25 + 0.01 * index
                positions = np.stack([-0.25 + 0.01 * np.arange(N_C), np.zeros(N_C), np.full(N_C, 0.1)], axis=1)
                flags = np.isin(np.arange(N_C), held)
                put("/dlo/rope/particles", T["sensor_msgs/msg/PointCloud2"](
                    header=header, height=1, width=N_C,
                    fields=[T["sensor_msgs/msg/PointField"](name=n, offset=4 * k, datatype=7, count=1)
                            for k, n in enumerate(("x", "y", "z", "held"))],
                    is_bigendian=False, point_step=16, row_step=16 * N_C,
                    data=np.frombuffer(pack_particles(positions, flags), np.uint8), is_dense=True))
                image = np.zeros((32, 32), np.uint8)
                image[16, :] = 255
                image[14:19, int(np.clip(16 + 100 * x, 0, 31))] = 128
                put("/dlo/camera/image", T["sensor_msgs/msg/Image"](header=header, height=32, width=32,
                                                                    encoding="mono8", is_bigendian=0, step=32,
                                                                    data=image.ravel()))
                put("/dlo/task/state", T["dlo_msgs/msg/TaskState"](
                    header=header, episode=episode, seed=500 + episode, step=step, held_indices=held, n_held=n_h,
                    mean_held_index=p_i, num_particles=N_C, cable_length=0.4, reward=reward,
                    episode_return=float(tracker.episode_return[0]), done=done,
                    outcome=int(tracker.outcome[0]) if done else 0, held_indices_authors=held,
                    mean_held_index_authors=p_i, outcome_authors=int(tracker.outcome_authors[0]) if done else 0,
                    task_rules="paper_text"))
                put("/dlo/tactile/pose", T["dlo_msgs/msg/TactilePose"](header=header, angle=0.01 * step, y=0.001,
                                                                       contact=True, contact_count=3))
                put("/dlo/vision/pose", T["dlo_msgs/msg/VisualPose"](header=header, visible=True, confidence=0.5,
                                                                     angle=-0.01 * step, y=0.002))
                put("/dlo/gripper/state", T["dlo_msgs/msg/GripperState"](header=header, x=x, y=0.0, z=0.1,
                                                                         closure=0.8, episode=episode, step=step))
                if not done:
                    moving = index < target
                    put("/dlo/gripper/cmd", T["dlo_msgs/msg/GripperCommand"](
                        header=header, vx=0.25 if moving else 0.0, vy=0.0, closure=0.8, episode=episode, step=step))
    return path


def frames_of(path: Path):
    import imageio_ffmpeg

    reader = imageio_ffmpeg.read_frames(str(path))
    meta = next(reader)
    return meta, sum(1 for _ in reader)


def test_one_playable_mp4_per_episode(synthetic_bag, tmp_path, capsys):
    from dlo_tools.analysis import main

    out = tmp_path / "videos"
    rc = main([str(synthetic_bag), "--video", str(out), "--policy", "scripted test", "--json",
               str(tmp_path / "e.json"), "--plots", str(tmp_path / "plots")])
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


def test_gif_and_speed(synthetic_bag, tmp_path):
    from PIL import Image

    from dlo_tools.analysis import main

    assert main([str(synthetic_bag), "--video", str(tmp_path / "gif"), "--video-format", "gif",
                 "--video-width", "320"]) == 0
    with Image.open(tmp_path / "gif" / "episode_0001.gif") as gif:
        assert gif.n_frames == STEPS[1] + 1 and gif.size == (320, 240)
        assert gif.info["duration"] == 80 and gif.info.get("loop") == 0
    assert main([str(synthetic_bag), "--video", str(tmp_path / "fast"), "--video-speed", "2",
                 "--video-width", "320"]) == 0
    meta, count = frames_of(tmp_path / "fast" / "episode_0000.mp4")
    assert abs(meta["fps"] - 25.0) < 1e-6 and count == STEPS[0] + 1


def test_titles_marks_and_still_spans(synthetic_bag):
    from dlo_tools.analysis import episode_title, read_run, recompute_episode
    from dlo_tools.episode_series import episode_series, still_spans
    from dlo_tools.video import EpisodeFrames, video_title

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
    from dlo_tools.analysis import main

    with pytest.raises(SystemExit) as err:
        main([str(synthetic_bag), "--video", str(tmp_path / "v"), "--video-speed", "0"])
    assert err.value.code == 2
    assert "--video-speed must be > 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(synthetic_bag), "--video", str(tmp_path / "v"), "--video-format", "avi"])
    assert not (tmp_path / "v").exists()
