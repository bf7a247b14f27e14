"""Shared by the graph == env tests: replay a graph's episodes in the in-process env, exactly."""


def replay_and_compare(env, agent, episodes) -> list:
    """Run ``agent`` deterministically in ``env`` on each graph episode's seed and assert the env's episode equals the
    graph's (outcomes under both rules, return to the last bit, length). Returns the env's final infos."""
    infos = []
    for live in episodes:
        observation, _ = env.reset(seed=live["seed"])
        done, info = False, {}
        while not done:
            observation, _, terminated, truncated, info = env.step(agent.predict(observation[None], deterministic=True)[0])
            done = terminated or truncated
        assert (info["outcome"], info["outcome_authors"]) == (live["outcome"], live["outcome_authors"]), live["seed"]
        assert info["episode_return"] == live["episode_return"], live["seed"]  # exactly: same code, same numbers
        assert info["episode_length"] == live["episode_length"]
        infos.append(info)
    return infos
