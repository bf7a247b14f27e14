"""dlo_policy.modalities: the one registry of the observation modalities.

- every record is complete: labels, bounds, its topic in dlo_common.topics, a converter for its message (each
  record of the registry, whatever it holds);
- the paper's K, T, V are there, in that order, with their entries (a registry mistake fails here, a modality
  added does not);
- "All" is the paper's K+T+V, a named constant: a modality added to the registry does not join it;
- a modality added to the registry alone reaches the observation vector, its bounds and the gym env;
- checkpoints store the expanded modalities; one from before (none stored) still loads and its run's "All"
  means K+T+V (the shipped policy).
"""

import sys
from pathlib import Path

import numpy as np
import pytest
from dlo_common.topics import message_class, topic
from dlo_policy import modalities
from dlo_policy.config import SACConfig
from dlo_policy.modalities import ALL, MODALITIES, Modality, by_name, names, parse_modalities, without_problem
from dlo_policy.observation import build_observation, observation_bounds, observation_labels, observation_size
from dlo_policy.sac import SAC, read_checkpoint

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib: helper modules
from sac_reach_env import ReachEnv  # noqa: E402

TINY = dict(hidden_sizes=(16, 16), batch_size=8, learning_starts=100, buffer_size=200, observation_scaling="none")


@pytest.mark.parametrize("m", MODALITIES, ids=lambda m: m.name)
def test_every_record_is_complete(m):
    assert by_name(m.name) is m and len(m.labels) == len(m.bounds) == m.size
    assert all(low < high for low, high in m.bounds)
    assert topic(m.topic).role in ("state", "observation") and m.message_type == topic(m.topic).type
    reading = m.from_message(message_class(m.message_type)())  # a default message: zeros
    assert m.columns(reading).shape == (1, m.size)
    assert len(set(names())) == len(MODALITIES) and len({m.title for m in MODALITIES}) == len(MODALITIES)
    with pytest.raises(KeyError, match="no modality 'X'"):
        by_name("X")


# The paper's modalities (docs/ARCHITECTURE.md#observations): name, entries, topic's key, whether it needs the image
PAPER_MODALITIES = (
    ("K", ("x_G", "y_G", "c_G"), "gripper", False),
    ("T", ("theta_T", "y_T"), "tactile", False),
    ("V", ("v_V", "q_V", "theta_V", "y_V"), "vision", True),
)


def test_the_papers_k_t_v_in_their_order_and_sizes():
    assert ALL == ("K", "T", "V") and tuple(n for n in names() if n in ALL) == ALL
    assert [(m.name, m.labels, m.input_key, m.renders) for m in MODALITIES if m.name in ALL] == list(PAPER_MODALITIES)
    assert observation_size("All") == 9 and observation_labels("All") == sum((row[1] for row in PAPER_MODALITIES), ())


def test_all_is_the_papers_k_t_v_not_every_modality_known(monkeypatch):
    assert ALL == ("K", "T", "V") and parse_modalities("All") == parse_modalities("all") == ALL
    known = names()
    monkeypatch.setattr(modalities, "MODALITIES", MODALITIES + (grip_twice(),))
    assert names() == (*known, "G")
    assert parse_modalities("All") == ("K", "T", "V")  # the shipped All policy keeps its meaning
    assert parse_modalities("G+K") == ("K", "G")
    with pytest.raises(ValueError, match=rf"subset of {', '.join(known)}, G or 'All'"):
        parse_modalities("X")


def test_the_launchers_without_check_reads_the_registry():
    assert without_problem("") is None and without_problem("T+V") is None and without_problem("K") is None
    for bad in ("X", "T+", "t", " T"):
        assert without_problem(bad) == (
            f"--without must be empty or modalities joined by '+' ({', '.join(names())}), e.g. T or T+V, got '{bad}'"
        )


def grip_twice() -> Modality:
    """A modality made up for the test: the closure once more, from the gripper state."""
    return Modality(
        "G",
        "grip",
        ("c_G2",),
        ((0.0, 1.0),),
        observe=lambda env: env.task.state.gripper[:, 3:4],
        columns=lambda grip: np.asarray(grip, dtype=np.float32).reshape(-1, 1),
        topic="/dlo/gripper/state",
        from_message=lambda msg: np.array([[msg.closure]]),
    )


def test_a_new_modality_is_one_record(monkeypatch):
    """Added to the registry alone, a modality has its labels, bounds and block in the observation vector, and
    the gym env observes it."""
    from dlo_policy.env import make_vec_env

    monkeypatch.setattr(modalities, "MODALITIES", MODALITIES + (grip_twice(),))
    assert observation_labels("K+G") == ("x_G", "y_G", "c_G", "c_G2") and observation_size("T+G") == 3
    low, high = observation_bounds("G+T")
    np.testing.assert_allclose(high, [np.pi / 2, 0.03, 1.0], rtol=1e-6)
    kinematic = np.array([[0.1, -0.2, 0.7]])
    assert build_observation("K+G", kinematic, grip=[[0.25]])[0] == pytest.approx([0.1, -0.2, 0.7, 0.25])
    assert build_observation("K+G", kinematic, grip=[[0.25]], without="G")[0] == pytest.approx([0.1, -0.2, 0.7, 0.0])
    env = make_vec_env(2, modalities="K+G", seed=3)
    try:
        observation, _ = env.reset(seed=3)
        assert env.single_observation_space.shape == (4,) and env.modalities == ("K", "G")
        np.testing.assert_array_equal(observation[:, 3], observation[:, 2])
    finally:
        env.close()


def test_checkpoints_store_the_expanded_modalities(tmp_path):
    env = ReachEnv("All")
    agent = SAC(9, env.action_space.low, env.action_space.high, SACConfig(**TINY), seed=0)
    assert agent.modalities is None
    agent.learn(env, total_steps=3)  # the env the agent acts on gives them
    assert agent.modalities == ("K", "T", "V")
    agent.save(tmp_path / "checkpoint.pt")
    agent.save_policy(tmp_path / "policy.pt")
    for name in ("checkpoint.pt", "policy.pt"):
        assert read_checkpoint(tmp_path / name)["modalities"] == ["K", "T", "V"]
        assert SAC.load(tmp_path / name).modalities == ("K", "T", "V")
    with pytest.raises(ValueError, match="the agent observes K\\+T\\+V, the env gives K"):
        agent.note_modalities(ReachEnv("K"))
    given = SAC(5, env.action_space.low, env.action_space.high, SACConfig(**TINY), modalities=("K", "T"))
    given.save_policy(tmp_path / "given.pt")
    assert SAC.load(tmp_path / "given.pt").modalities == ("K", "T")


def test_a_checkpoint_from_before_loads_and_its_all_means_k_t_v(tmp_path, monkeypatch):
    """A policy file from before the modalities were stored (as the policy shipped until 2026-12-03): its run's
    config.yaml says "All", which is K+T+V, and the policy node reads it so."""
    pytest.importorskip("rclpy")
    import torch
    from dlo_policy import policy_node
    from dlo_policy.evaluate import load_run_config

    state = read_checkpoint(policy_node.shipped_policy_path())
    del state["modalities"]  # what a file written before them holds
    shipped = tmp_path / "policy.pt"
    torch.save(state, shipped)
    (tmp_path / "config.yaml").write_text(policy_node.shipped_policy_path().with_name("config.yaml").read_text())
    assert "modalities" not in read_checkpoint(shipped) and SAC.load(shipped).modalities is None
    assert load_run_config(shipped).modalities == "All"
    act, trained_on, previous_action = policy_node.load_policy("sac", str(shipped), "K", seed=0)
    assert policy_node.modalities_parameter("modalities", trained_on) == ("K", "T", "V")
    assert act(np.zeros((1, 9), np.float32), True, None).shape == (1, 3) and not previous_action
    monkeypatch.setattr(modalities, "MODALITIES", MODALITIES + (grip_twice(),))  # a modality added later
    assert policy_node.modalities_parameter("modalities", trained_on) == ("K", "T", "V")


def test_a_record_is_checked_when_it_is_made():
    """Modality: one (low, high) per label, and its topic must be one of the registry's (dlo_common.topics)."""
    with pytest.raises(ValueError, match="modality G: one \\(low, high\\) per label"):
        Modality(
            "G", "grip", ("a", "b"), ((0.0, 1.0),), observe=None, columns=None, topic="/dlo/gripper/state", from_message=None
        )
    with pytest.raises(KeyError, match="no topic '/dlo/nosuch'"):
        Modality("G", "grip", ("a",), ((0.0, 1.0),), observe=None, columns=None, topic="/dlo/nosuch", from_message=None)
