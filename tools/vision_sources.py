"""Where the two vision sources disagree: the shipped policy (or a checkpoint) run in-process with V from the image,
and in every state both readings, the image's (``visual_pose``, what the policy saw) and the particles'
(``visual_pose_particles``, the authors' index walk on the task rules' held set), against how far the authors'
narrow held set's mean index is from the cable's end.

    python tools/vision_sources.py [--checkpoint PATH] [--episodes 100] [--seed 7000] [--json OUT]

Prints, per distance from the end (in particles, rounded), the share of states in which each source says
"visible", and the median distance at which each source's v first turns off in an episode; a JSON line last.
docs/FIDELITY.md row 11 cites it.
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default="", help="policy file (default: the shipped policy)")
    parser.add_argument("--episodes", type=int, default=100)
    parser.add_argument("--seed", type=int, default=7000)
    parser.add_argument("--json", default="", help="also write the result here")
    args = parser.parse_args(argv)

    from dlo_perception.vision import visual_pose_particles
    from dlo_policy.env import make_vec_env
    from dlo_policy.observation import observation_labels, takes_previous_action
    from dlo_policy.policy_node import shipped_policy_path
    from dlo_policy.rundir import trained_sim_settings
    from dlo_policy.sac import SAC

    path = args.checkpoint or shipped_policy_path()
    agent = SAC.load(path)
    settings = trained_sim_settings(path) or {"task_rules": "authors_code", "single_particle_grip": False}
    num_envs = min(args.episodes, 20)
    env = make_vec_env(
        num_envs,
        agent.modalities,
        seed=args.seed,
        task_rules=settings["task_rules"],
        single_particle_grip=settings["single_particle_grip"],
        # a policy trained with env_options.previous_action takes 3 more entries (dlo_policy.observation)
        previous_action=takes_previous_action(agent.obs_dim, agent.modalities),
    )
    if "V" not in agent.modalities:
        print("the policy does not observe V", file=sys.stderr)
        return 2
    v_start = observation_labels(agent.modalities).index("v_V")
    observation, _ = env.reset(seed=args.seed)
    rows = []  # (episode seed, distance of the narrow set's mean from the end, image v, particles v)
    finished = 0
    while finished < args.episodes:
        task = env.task
        particles = visual_pose_particles(task.state.positions, task.held_task, env.sim.num_particles, task.state.gripper[:, :2])
        distance = env.sim.num_particles - 1 - task.mean_held_index_authors
        for i in range(num_envs):
            if env.episode_seed[i] < args.seed + args.episodes and task.mean_held_index_authors[i] >= 0:
                rows.append(
                    (
                        int(env.episode_seed[i]),
                        float(distance[i]),
                        bool(observation[i, v_start] > 0.5),
                        bool(particles.visible[i]),
                    )
                )
        observation, _, terminated, truncated, _ = env.step(agent.predict(observation, deterministic=True))
        finished += int(np.sum(terminated | truncated))
    data = np.array(rows, dtype=float)
    result = {"policy": str(path), "episodes": args.episodes, "seed": args.seed, "states": len(rows), "by_distance": {}}
    for d in range(0, 16):
        near = np.abs(data[:, 1] - d) < 0.5
        if near.any():
            result["by_distance"][d] = {
                "states": int(near.sum()),
                "image_visible": float(data[near, 2].mean()),
                "particles_visible": float(data[near, 3].mean()),
            }
    first_off = {"image": [], "particles": []}
    for seed in np.unique(data[:, 0]):
        episode = data[data[:, 0] == seed]
        for name, column in (("image", 2), ("particles", 3)):
            off = np.flatnonzero(episode[:, column] == 0)
            if len(off):
                first_off[name].append(episode[off[0], 1])
    result["median_distance_first_off"] = {k: (float(np.median(v)) if v else None) for k, v in first_off.items()}
    print("distance  states  image v  particles v")
    for d, row in result["by_distance"].items():
        print(f"{d:8d}  {row['states']:6d}  {row['image_visible']:7.0%}  {row['particles_visible']:11.0%}")
    print(
        f"median distance where v first turns off: image {result['median_distance_first_off']['image']}, "
        f"particles {result['median_distance_first_off']['particles']}"
    )
    if args.json:
        with open(args.json, "w") as f:
            json.dump(result, f, indent=2)
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
