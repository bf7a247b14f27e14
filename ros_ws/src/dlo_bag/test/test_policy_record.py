"""What drove a run travels with its bag: the policy node publishes its record once, latched, on /dlo/policy/info
(checkpoint and its sha256, modalities, the task rules, grip and env_options it was trained under); the recorder
records it and copies it into every part's metadata; dlo-analyze prints it, puts it into --json and into the video
titles (--policy overrides the titles' label; a bag without a record says 'policy not recorded')."""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_bag import analysis, video  # noqa: E402
from dlo_bag.info import bag_info  # noqa: E402
from dlo_bag.reader import bag_parts, read_messages  # noqa: E402
from dlo_bag.recording import POLICY_KEY, POLICY_TOPIC, POLICY_TYPE, Recorder  # noqa: E402
from dlo_bag.typestore import make_typestore  # noqa: E402
from dlo_bag_testutil import helper_cmd, recorder_cmd  # noqa: E402
from harness import ROS2RUN  # noqa: E402


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


# ------------------------------------------------------------------------------------------ with ROS
def test_a_recorded_run_carries_its_policy_and_dlo_analyze_shows_it(procs, tmp_bags, ros_env):
    """The shipped SAC policy drives: the bag (split in two parts) holds one record, each part's metadata a copy;
    dlo-analyze prints it above the table and puts it into every episode of --json."""
    from dlo_policy.rundir import CONFIG_FILE, shipped_policy_path

    out = tmp_bags / "run"
    rec = procs("recorder", recorder_cmd(out, "split_episodes:=2"))
    policy = procs("policy", [str(ROS2RUN), "dlo_policy", "policy_node", "--ros-args", "-p", "policy:=sac"])
    policy.wait_line("policy sac on", timeout=180)
    rec.wait_line(f"recording {POLICY_TOPIC} [std_msgs/msg/String] (reliable, transient_local)", timeout=60)
    pub = procs("pub", helper_cmd("pub", "--count", "16", "--episode-every", "4", "--topics", "/dlo/task/state"))
    pub.wait_line("PUBLISHED ")
    assert pub.wait(timeout=30) == 0
    rec.signal(2)
    assert rec.wait(timeout=30) == 0, rec.output()

    shipped = shipped_policy_path()
    trained = yaml.safe_load((shipped.parent / CONFIG_FILE).read_text())["env_options"]
    (message,) = [m.msg.data for m in read_messages(out, [POLICY_TOPIC])]
    record = json.loads(message)
    assert record["policy"] == "sac" and record["shipped"] is True
    assert Path(record["checkpoint"]) == shipped.resolve() and record["sha256"] == sha256(shipped)
    assert record["modalities"] == "K+T+V" and record["without"] == ""
    assert record["env_options"] == trained  # what the shipped policy was trained under, its grip included
    assert (record["task_rules"], record["single_particle_grip"]) == (trained["task_rules"], trained["single_particle_grip"])
    parts = bag_parts(out)
    assert len(parts) == 2 and [json.loads(bag_info(p).custom_data[0][POLICY_KEY]) for p in parts] == [record] * 2
    assert analysis.policy_records(parts[1]) == [record]  # the later part: from its metadata (the message is in 0)

    result = subprocess.run(
        [sys.executable, "-m", "dlo_bag.analysis", str(out), "--json", str(tmp_bags / "a.json")],
        env=ros_env,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stdout + result.stderr
    grip = "single-particle grip" if trained["single_particle_grip"] else "finite grip"
    assert result.stdout.splitlines()[0] == (
        f"policy: sac shipped all/policy.pt (sha256 {sha256(shipped)[:8]}) on K+T+V; trained {trained['task_rules']}, {grip}"
    )
    summaries = json.loads((tmp_bags / "a.json").read_text())
    assert len(summaries) == 4 and all(s["policy"] == record for s in summaries)


# ------------------------------------------------------------------------------------------ without ROS
STEPS = 3  # control steps of each episode of the synthetic bags


def write_bag(path: Path, records=(), episodes: int = 1, split: int = 0) -> Path:
    """A small bag written by the recorder's own logic (dlo_bag.recording.Recorder): ``records`` on the policy topic
    first (as the latched message arrives), then ``episodes`` short episodes of task and gripper states whose
    outcomes come from the task module (so dlo-analyze recomputes them without a mismatch)."""
    from dlo_interface.task import EpisodeTracker

    ts = make_typestore()
    T = ts.types
    recorder = Recorder(path, typestore=ts, split_episodes=split, fsync=False)
    types = {
        POLICY_TOPIC: POLICY_TYPE,
        "/dlo/task/state": "dlo_msgs/msg/TaskState",
        "/dlo/gripper/state": "dlo_msgs/msg/GripperState",
    }
    for topic, msgtype in types.items():
        recorder.add_topic(topic, msgtype)
    t = 1_000_000_000

    def put(topic, msg):
        nonlocal t
        t += 1000
        assert recorder.on_message(topic, ts.serialize_cdr(msg, types[topic]), t) is None

    for record in records:
        put(POLICY_TOPIC, T["std_msgs/msg/String"](data=record if isinstance(record, str) else json.dumps(record)))
    for episode in range(episodes):
        tracker = EpisodeTracker(1, horizon=STEPS, task_rules="paper_text")
        for step in range(STEPS + 1):
            header = T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=10 * episode + step, nanosec=0), frame_id="world"
            )
            held = np.arange(step, step + 3, dtype=np.int32)
            p_i, largest = float(held.mean()), int(held.max())
            if step == 0:
                tracker.reset([0], np.array([p_i]), np.array([largest]), np.array([30]), np.array([p_i]))
                reward, done = 0.0, False
            else:
                r, term, trunc = tracker.step(
                    np.array([p_i]),
                    np.array([3]),
                    np.array([largest]),
                    np.array([30]),
                    np.array([0.3]),
                    np.array([p_i]),
                    np.array([3]),
                )
                reward, done = float(r[0]), bool(term[0] or trunc[0])
            put(
                "/dlo/task/state",
                T["dlo_msgs/msg/TaskState"](
                    header=header,
                    episode=episode,
                    seed=70 + episode,
                    step=step,
                    held_indices=held,
                    n_held=3,
                    mean_held_index=p_i,
                    num_particles=30,
                    cable_length=0.3,
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
                "/dlo/gripper/state",
                T["dlo_msgs/msg/GripperState"](
                    header=header, x=-0.25 + 0.01 * step, y=0.0, z=0.1, closure=0.8, episode=episode, step=step
                ),
            )
    summary = recorder.close()
    assert summary.dropped == 0 and summary.complete
    return path


@pytest.fixture
def trained_checkpoint(tmp_path):
    """A copy of the shipped policy in a run directory of its own, trained (its config.yaml says) with the authors'
    carry law, the particles as the vision source, a 6 mm contact radius and their 4 mm move spacing."""
    from dlo_policy.rundir import CONFIG_FILE, shipped_policy_path

    shipped = shipped_policy_path()
    run = tmp_path / "runs" / "fidelity_s3"
    run.mkdir(parents=True)
    shutil.copy(shipped, run / "best_policy.pt")
    config = yaml.safe_load((shipped.parent / CONFIG_FILE).read_text())
    config["env_options"] = {
        "task_rules": "authors_code",
        "single_particle_grip": False,
        "carry_law": "authors",
        "vision_source": "particles",
        "contact_radius": 0.006,
        "move_spacing": 0.004,
    }
    (run / CONFIG_FILE).write_text(yaml.safe_dump(config))
    return run / "best_policy.pt"


@pytest.fixture
def titles(monkeypatch):
    """The title of every video frame set drawn (dlo_bag.video.video_title, as the frames call it)."""
    drawn = []
    original = video.video_title

    def spy(episode, summary, policy):
        drawn.append(original(episode, summary, policy))
        return drawn[-1]

    monkeypatch.setattr(video, "video_title", spy)
    return drawn


def test_the_record_of_a_checkpoint_names_its_file_hash_and_training(trained_checkpoint):
    from dlo_policy.policy_node import policy_record

    record = policy_record("sac", str(trained_checkpoint), ("K", "T"), ("T",))
    assert record["checkpoint"] == str(trained_checkpoint.resolve()) and record["shipped"] is False
    assert record["sha256"] == sha256(trained_checkpoint)
    assert (record["modalities"], record["without"]) == ("K+T", "T")
    assert (record["task_rules"], record["single_particle_grip"]) == ("authors_code", False)
    assert record["env_options"] == {
        "task_rules": "authors_code",
        "single_particle_grip": False,
        "carry_law": "authors",
        "vision_source": "particles",
        "contact_radius": 0.006,
        "move_spacing": 0.004,
    }
    assert analysis.policy_label(record) == (
        f"sac fidelity_s3/best_policy.pt (sha256 {record['sha256'][:8]}) on K+T without T; trained authors_code, "
        "finite grip, carry_law authors, contact_radius 0.006, vision_source particles, move_spacing 0.004"
    )
    scripted = policy_record("tactile_reactive", "", ("K", "T", "V"))
    assert scripted["checkpoint"] is None and scripted["sha256"] is None and scripted["task_rules"] is None
    assert analysis.policy_label(scripted) == "tactile_reactive on K+T+V"
    assert policy_record("random", "", ("V",), seed=7)["seed"] == 7


def test_the_video_titles_and_the_analysis_show_the_recorded_policy(tmp_path, trained_checkpoint, titles, capsys):
    from dlo_policy.policy_node import policy_record

    record = policy_record("sac", str(trained_checkpoint), ("K", "T", "V"))
    bag = write_bag(tmp_path / "bag", [record], episodes=2)
    label = analysis.policy_label(record)
    assert (
        analysis.main([str(bag), "--video", str(tmp_path / "v"), "--video-width", "160", "--json", str(tmp_path / "a.json")]) == 0
    )
    out = capsys.readouterr().out
    assert out.splitlines()[0] == f"policy: {label}"
    for title in titles:  # the episode, the policy (wrapped: at most 100 characters a line), the outcome
        lines = title.splitlines()
        assert len(lines) == 4 and " ".join(lines[1:3]) == f"policy {label}", title
        assert lines[0].startswith("episode ") and lines[3].startswith("outcome: ") and max(map(len, lines)) <= 100
    assert len(titles) == 2
    assert sorted(p.name for p in (tmp_path / "v").iterdir()) == ["episode_0000.mp4", "episode_0001.mp4"]
    assert [s["policy"] for s in json.loads((tmp_path / "a.json").read_text())] == [record, record]
    # --policy: the titles say what is asked instead
    assert analysis.main([str(bag), "--video", str(tmp_path / "w"), "--video-width", "160", "--policy", "sac (shipped)"]) == 0
    assert titles[-1].splitlines()[1] == "policy sac (shipped)"


def test_a_bag_without_a_record_says_so_and_several_records_are_all_named(tmp_path, titles, capsys):
    from dlo_policy.policy_node import policy_record

    bare = write_bag(tmp_path / "bare")
    assert analysis.policy_records(bare) == []
    assert analysis.main([str(bare), "--video", str(tmp_path / "v"), "--video-width", "160"]) == 0
    assert capsys.readouterr().out.splitlines()[0].startswith("episode   seed")  # no policy line
    assert titles[-1].splitlines()[1] == "policy not recorded"
    first, second = policy_record("random", "", ("K",), seed=1), policy_record("tactile_reactive", "", ("K", "T", "V"))
    both = write_bag(tmp_path / "both", [first, first, second, "not json"])
    assert analysis.policy_records(both) == [first, second, {"policy": "not json"}]  # distinct, in order
    assert analysis.recorded_policy(analysis.policy_records(both)) == "random on K, then tactile_reactive on K+T+V, then not json"
