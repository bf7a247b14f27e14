"""Step-locked graph == in-process gym env, to the last bit, with perturbations on (each family in the node that
owns it: dlo_interface.perturbations.OWNERS).

- Observation and action families: the policy node's ``perturbations`` parameter, the same Perturber as the env's
  option, its noise seeded from the episode's seed that /dlo/task/state carries.
- Physics and camera families: the sim node's ``perturbations`` parameter, the same SimConfig ranges and the same
  rendering camera as the env's option (dlo_interface.perturbations.sim_config, cameras), camera_info staying the
  nominal camera's. A family the sim node ignored would give the env's episodes without it, which differ.

The nodes are started here one by one with scripts/ros2run, as launch_graph.sh starts them. The shipped SAC policy
acts; the episodes' returns, lengths and outcomes must equal the env's. A family given to the node that does not own
it, or a bad setting, is one line and exit 2.
"""

import json
import pathlib
import subprocess
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


# a physics family beyond the training friction range (0.04-0.3) and a camera family, on the sim node
SIM_PERTURBATIONS = "friction=0.6,camera_yaw=2"
SIM_SEED, SIM_EPISODES = 7105, 3


def node(package, executable, *parameters):
    return [str(ROS2RUN), package, executable, "--ros-args", *[a for p in parameters for a in ("-p", p)]]


def run_graph(outcomes, seed, episodes, sim_parameters=(), policy_parameters=()):
    """The step-locked graph of the shipped policy (its training's sim settings) for ``episodes`` episodes from
    ``seed``, with these extra parameters of the sim and the policy node: (settings, the sim's outcome lines, the
    sim's output, the policy's output)."""
    from dlo_policy.policy_node import shipped_policy_path
    from dlo_policy.rundir import trained_sim_settings

    settings = trained_sim_settings(shipped_policy_path())
    env = package_test_env("dlo_policy", "policy_node")
    with Procs(env) as procs:
        sim = procs(
            "sim",
            node(
                "dlo_sim",
                "sim_node",
                "mode:=step_locked",
                f"seed:={seed}",
                f"episodes:={episodes}",
                "min_subscribers:=3",
                f"summary_file:={outcomes}",
                f"task_rules:={settings['task_rules']}",
                f"single_particle_grip:={str(settings['single_particle_grip']).lower()}",
                *sim_parameters,
            ),
        )
        sim.wait_line("alone on ROS_DOMAIN_ID", timeout=120)  # it looks for another simulator first (as the launcher)
        procs("tactile", node("dlo_perception", "tactile_node", f"seed:={seed}"))
        procs("vision", node("dlo_perception", "vision_node"))
        policy = procs("policy", node("dlo_policy", "policy_node", "policy:=sac", *policy_parameters))
        assert sim.wait(timeout=900) == 0, sim.output()[-3000:] + policy.output()[-2000:]
        sim_output, policy_output = sim.output(), policy.output()
    return settings, [json.loads(line) for line in outcomes.read_text().splitlines()], sim_output, policy_output


def shipped_env(settings, seed, perturbations=None, **options):
    from dlo_policy.env import make_env

    return make_env(
        "All",
        seed=seed,
        task_rules=settings["task_rules"],
        single_particle_grip=settings["single_particle_grip"],
        perturbations=perturbations,
        **options,
    )


def env_returns(env, agent, seeds) -> list:
    """The deterministic shipped policy's return in ``env`` on each of these episode seeds."""
    returns = []
    for seed in seeds:
        observation, _ = env.reset(seed=seed)
        done, info = False, {}
        while not done:
            observation, _, terminated, truncated, info = env.step(agent.predict(observation[None], deterministic=True)[0])
            done = terminated or truncated
        returns.append(info["episode_return"])
    return returns


@pytest.fixture(scope="module")
def graph_episodes(tmp_path_factory):
    outcomes = tmp_path_factory.mktemp("graph_perturbed") / "outcomes.jsonl"
    settings, episodes, _, policy_output = run_graph(
        outcomes, SEED, EPISODES, policy_parameters=(f"perturbations:={PERTURBATIONS}",)
    )
    assert "perturbations observation_delay=1," in policy_output
    return settings, episodes


@pytest.fixture(scope="module")
def sim_perturbed_episodes(tmp_path_factory):
    outcomes = tmp_path_factory.mktemp("graph_sim_perturbed") / "outcomes.jsonl"
    settings, episodes, sim_output, _ = run_graph(
        outcomes, SIM_SEED, SIM_EPISODES, sim_parameters=(f"perturbations:={SIM_PERTURBATIONS}",)
    )
    assert f"perturbations {SIM_PERTURBATIONS}," in sim_output  # its start line says what it runs under
    return settings, episodes


@pytest.fixture(scope="module")
def previous_action_policy(tmp_path_factory):
    """A policy that takes its previous action (env option previous_action): the shipped policy's network with three
    inputs added for it (weights drawn as large as the others; normalised as they come), so it follows the cable for a
    while and its actions depend on all 12 entries, saved as dlo-train saves one with its run's config.yaml."""
    import torch
    from dlo_policy.config import save_config
    from dlo_policy.policy_node import shipped_policy_path
    from dlo_policy.rundir import read_trained_config
    from dlo_policy.sac import read_checkpoint

    run_dir = tmp_path_factory.mktemp("previous_action_run")
    config = read_trained_config(shipped_policy_path().parent)
    config.env_options["previous_action"] = True
    save_config(config, run_dir / "config.yaml")
    state = read_checkpoint(shipped_policy_path())
    weight, normalizer = state["actor"]["net.0.weight"], state["normalizer"]
    added = weight.std() * torch.randn(weight.shape[0], 3, generator=torch.Generator().manual_seed(3), dtype=weight.dtype)
    state["actor"]["net.0.weight"] = torch.cat([weight, added], 1)
    normalizer["mean"] = torch.cat([normalizer["mean"], torch.zeros(3, dtype=normalizer["mean"].dtype)])
    normalizer["var"] = torch.cat([normalizer["var"], torch.ones(3, dtype=normalizer["var"].dtype)])
    state["obs_dim"] = 12
    torch.save(state, run_dir / "policy.pt")
    return run_dir / "policy.pt"


def test_a_policy_that_takes_its_previous_action_runs_in_the_graph_as_in_the_env(previous_action_policy, tmp_path):
    """The policy node appends the previous action as the env does (after the observation perturbations, the action
    as the policy gave it, before the action ones): the perturbed episodes equal the env's with previous_action."""
    from dlo_policy.sac import SAC

    settings, episodes, _, policy_output = run_graph(
        tmp_path / "outcomes.jsonl",
        SEED,
        1,  # an episode of 19 steps whose return changes when the node keeps another action
        policy_parameters=(f"perturbations:={PERTURBATIONS}", f"checkpoint:={previous_action_policy}"),
    )
    assert "perturbations observation_delay=1," in policy_output
    agent = SAC.load(previous_action_policy)
    replay_and_compare(shipped_env(settings, SEED, PERTURBATIONS, previous_action=True), agent, episodes)


def test_perturbed_episodes_in_the_graph_equal_the_in_process_env(graph_episodes):
    from dlo_policy.policy_node import shipped_policy_path
    from dlo_policy.sac import SAC

    settings, episodes = graph_episodes
    agent = SAC.load(shipped_policy_path())
    env = shipped_env(settings, SEED, PERTURBATIONS)
    assert [e["seed"] for e in episodes] == list(range(SEED, SEED + EPISODES))
    plain_returns = [info["episode_return"] for info in replay_and_compare(env, agent, episodes)]
    # the perturbations did act: the unperturbed env gives other episodes
    assert env_returns(shipped_env(settings, SEED), agent, [SEED]) != plain_returns[:1]


def test_physics_and_camera_perturbations_of_the_sim_node_equal_the_in_process_env(sim_perturbed_episodes):
    """friction (physics: the SimConfig range every episode draws from) and camera_yaw (the camera that renders,
    the vision assuming the nominal one) on the sim node: the graph's episodes are the env's with both families,
    and the env's with either family left out are other episodes (so the graph applied each of them)."""
    from dlo_policy.policy_node import shipped_policy_path
    from dlo_policy.sac import SAC

    settings, episodes = sim_perturbed_episodes
    agent = SAC.load(shipped_policy_path())
    seeds = list(range(SIM_SEED, SIM_SEED + SIM_EPISODES))
    assert [e["seed"] for e in episodes] == seeds
    replay_and_compare(shipped_env(settings, SIM_SEED, SIM_PERTURBATIONS), agent, episodes)
    graph = [e["episode_return"] for e in episodes]
    for family in ("friction", "camera_yaw"):  # the sim node ignoring either would equal the env without it
        rest = ",".join(p for p in SIM_PERTURBATIONS.split(",") if not p.startswith(family + "="))
        assert env_returns(shipped_env(settings, SIM_SEED, rest), agent, seeds) != graph, family


@pytest.mark.parametrize(
    "value, message",
    [
        (
            "observation_delay=1",
            "observation_delay: observation and action perturbations belong to the policy node, not the simulator "
            "(here: friction, stretch_stiffness, bending_stiffness, cable_length, particle_mass, camera_offset, "
            "camera_yaw)",
        ),
        ("frction=0.6", "unknown perturbation 'frction'; did you mean 'friction'?"),
        ("camera_yaw=100", "camera_yaw: expected a number in [0, 90] (deg), got 100"),
    ],
)
def test_a_perturbation_the_sim_node_does_not_own_or_cannot_read_is_one_line(value, message, tmp_path):
    env = package_test_env("dlo_sim", "sim_node")  # skips without the workspace
    result = subprocess.run(
        node("dlo_sim", "sim_node", f"perturbations:={value}"), env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 2 and "Traceback" not in result.stderr, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"[sim_node] bad parameter: parameter 'perturbations': {message}"), lines
