"""Step-locked graph == in-process gym env, to the last bit, with observation- and action-side perturbations on.

The policy node owns them in the graph (its ``perturbations`` parameter; the launcher passes none, so the nodes are
started here one by one with scripts/ros2run, as launch_graph.sh starts them): the same Perturber as the env's option,
its noise seeded from the episode's seed that /dlo/task/state carries. The shipped SAC policy acts; the episodes'
returns, lengths and outcomes must equal the env's. Physics and camera families belong to the simulator and the
vision, which take no such parameter yet (the env has them; dlo_policy.perturbations).
"""

import json
import pathlib
import sys

import pytest
from harness import ROS2RUN, Procs, package_test_env

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))  # --import-mode=importlib: tests/ helpers
from env_replay import replay_and_compare  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
SEED, EPISODES = 7005, 4
# both delays, noise on every modality, a false detection, the actuator: every observation and action family kind
PERTURBATIONS = (
    "observation_delay=1,tactile_angle_noise=5,vision_offset_noise=2,vision_false_visible=0.05,"
    "gripper_position_noise=1,gripper_position_bias=2,action_delay=1,velocity_gain=0.9,closure_lag=0.08"
)


def node(package, executable, *parameters):
    return [str(ROS2RUN), package, executable, "--ros-args", *[a for p in parameters for a in ("-p", p)]]


@pytest.fixture(scope="module")
def graph_episodes(tmp_path_factory):
    from dlo_policy.policy_node import shipped_policy_path
    from dlo_policy.rundir import trained_sim_settings

    settings = trained_sim_settings(shipped_policy_path())
    outcomes = tmp_path_factory.mktemp("graph_perturbed") / "outcomes.jsonl"
    env = package_test_env("dlo_policy", "policy_node")
    with Procs(env) as procs:
        sim = procs(
            "sim",
            node(
                "dlo_sim",
                "sim_node",
                "mode:=step_locked",
                f"seed:={SEED}",
                f"episodes:={EPISODES}",
                "min_subscribers:=3",
                f"summary_file:={outcomes}",
                f"task_rules:={settings['task_rules']}",
                f"single_particle_grip:={str(settings['single_particle_grip']).lower()}",
            ),
        )
        sim.wait_line("alone on ROS_DOMAIN_ID", timeout=120)  # it looks for another simulator first (as the launcher)
        procs("tactile", node("dlo_perception", "tactile_node", f"seed:={SEED}"))
        procs("vision", node("dlo_perception", "vision_node"))
        policy = procs("policy", node("dlo_policy", "policy_node", "policy:=sac", f"perturbations:={PERTURBATIONS}"))
        assert sim.wait(timeout=900) == 0, sim.output()[-3000:] + policy.output()[-2000:]
        assert "perturbations observation_delay=1," in policy.output()
    return settings, [json.loads(line) for line in outcomes.read_text().splitlines()]


def test_perturbed_episodes_in_the_graph_equal_the_in_process_env(graph_episodes):
    from dlo_policy.env import make_env
    from dlo_policy.policy_node import shipped_policy_path
    from dlo_policy.sac import SAC

    settings, episodes = graph_episodes
    agent = SAC.load(shipped_policy_path())
    env = make_env(
        "All",
        seed=SEED,
        task_rules=settings["task_rules"],
        single_particle_grip=settings["single_particle_grip"],
        perturbations=PERTURBATIONS,
    )
    assert [e["seed"] for e in episodes] == list(range(SEED, SEED + EPISODES))
    plain_returns = [info["episode_return"] for info in replay_and_compare(env, agent, episodes)]
    # the perturbations did act: the unperturbed env gives other episodes
    plain = make_env("All", seed=SEED, task_rules=settings["task_rules"], single_particle_grip=settings["single_particle_grip"])
    observation, _ = plain.reset(seed=SEED)
    done, info = False, {}
    while not done:
        observation, _, terminated, truncated, info = plain.step(agent.predict(observation[None], deterministic=True)[0])
        done = terminated or truncated
    assert info["episode_return"] != plain_returns[0]
