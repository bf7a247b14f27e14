"""Domain randomisation (env option ``randomise``, dlo_policy.perturbations.parse_ranges / randomised): ranges read
one way with one-line errors, each episode's magnitudes drawn from its seed alone (reproducible, the same in any
batch), physics drawn by the simulator inside the range, a randomised camera rendering as the fixed one does,
only the training env randomised (config.make_env), and a short dlo-train run that records the ranges in
config.yaml and each episode's magnitudes in randomised.csv."""

import csv
import json
import math
from pathlib import Path

import numpy as np
import pytest
import yaml
from dlo_interface.world import CONTROL_PERIOD
from dlo_policy import perturbations as P
from dlo_policy import train
from dlo_policy.config import RunConfig, make_env
from dlo_policy.env import check_options, make_vec_env
from dlo_policy.grid import GROUPS, ROBUST_LABEL, ROBUST_RANGES, RunSpec, experiment_grid, run_config

RANGES = {
    "observation_delay": [0, 2],
    "velocity_gain": [0.5, 2.0],
    "closure_lag": [0.0, 0.32],
    "friction": [0.02, 1.2],
    "cable_length": [20, 60],
    "camera_yaw": [0.0, 4.0],
}


# ------------------------------------------------------------------------------------------------ reading
def test_ranges_are_read_one_way_from_text_or_mapping():
    text = "observation_delay=0:2,friction=0.02:1.2,velocity_gain=0.5:2"
    parsed = P.parse_ranges(text)
    assert parsed == {"observation_delay": (0, 2), "velocity_gain": (0.5, 2.0), "friction": (0.02, 1.2)}  # registry order
    assert P.parse_ranges(P.range_text(parsed)) == parsed == P.parse_ranges({k: list(v) for k, v in parsed.items()})
    assert P.parse_ranges(None) == P.parse_ranges("") == P.parse_ranges({}) == {}
    assert isinstance(P.parse_ranges("cable_length=20:60")["cable_length"][0], int)


@pytest.mark.parametrize(
    "value, expected",
    [
        ("obsrvation_delay=0:2", "randomise: unknown perturbation 'obsrvation_delay'; did you mean 'observation_delay'?"),
        ({"fricton": [0, 1]}, "did you mean 'friction'?"),
        ("friction=0.6", "randomise: friction: expected a range [low, high] (as text friction=low:high), got '0.6'"),
        ({"friction": 0.6}, "a fixed magnitude is a perturbation: env_options.perturbations"),
        ({"friction": [0.6, 0.1]}, "randomise: friction: expected low <= high, got [0.6, 0.1]"),
        ({"observation_delay": [0, 1.5]}, "randomise: observation_delay: expected an integer in [0, 50]"),
        ({"vision_dropout": [0, 2]}, "randomise: vision_dropout: expected a number in [0, 1]"),
        ("velocity_gain=x:2", "randomise: velocity_gain: expected a number in [0, 10] (x commanded), got 'x'"),
        ("friction", "randomise: expected name=low:high pairs"),
        ("friction=0:1,friction=0:2", "randomise: friction given twice"),
    ],
)
def test_a_bad_range_is_one_line_naming_the_family(value, expected):
    with pytest.raises(ValueError) as error:
        P.parse_ranges(value)
    assert expected in str(error.value) and "\n" not in str(error.value)
    with pytest.raises(ValueError):  # what dlo-train checks env_options with
        check_options({"randomise": value})


def test_a_family_is_fixed_or_randomised_not_both_and_physics_not_with_one_physics_draw():
    with pytest.raises(ValueError, match="randomise: friction also fixed in perturbations"):
        check_options({"randomise": "friction=0:1", "perturbations": "friction=0.5"})
    check_options({"randomise": "friction=0:1", "perturbations": "observation_delay=1"})
    with pytest.raises(ValueError, match="randomise: friction cannot be drawn per episode with physics_seed 3"):
        check_options({"randomise": "friction=0:1", "physics_seed": 3})
    check_options({"randomise": "observation_delay=0:1", "physics_seed": 3})


# ------------------------------------------------------------------------------------------------ drawing
def test_each_episode_draws_from_its_seed_alone_uniformly_in_the_range():
    ranges = P.parse_ranges(RANGES)
    draws = [P.randomised(ranges, seed, "all") for seed in range(400)]
    assert draws[7] == P.randomised(ranges, 7, "all")  # reproducible
    assert all(set(d) == {"observation_delay", "velocity_gain", "closure_lag", "camera_yaw"} for d in draws)  # physics: the sim
    delays = [d["observation_delay"] for d in draws]
    assert set(delays) == {0, 1, 2} and all(isinstance(x, int) for x in delays)  # each whole number, both ends
    assert min(delays.count(k) for k in (0, 1, 2)) > 100
    gains = np.array([d["velocity_gain"] for d in draws])
    assert 0.5 <= gains.min() < 0.55 and 1.95 < gains.max() <= 2.0 and abs(gains.mean() - 1.25) < 0.06
    alone = P.parse_ranges({"velocity_gain": [0.5, 2.0]})  # whichever other families are randomised
    assert [P.randomised(alone, s, "all")["velocity_gain"] for s in range(400)] == list(gains)
    # a fixed range is its one magnitude; an episode's perturbation noise is untouched by its draws
    assert {P.randomised(P.parse_ranges({"closure_lag": [0.1, 0.1]}), s, "all")["closure_lag"] for s in range(20)} == {0.1}
    assert P.episode_rng(5).random() == P.episode_rng(5).random()


# today's draws (randomise_draw "all"), pinned from the code before the "one" draw existed: they must never change
PINNED = {
    0: {
        "observation_delay": 0,
        "vision_false_visible": 0.01590360807923727,
        "gripper_position_bias": 13.49464514913153,
        "action_delay": 0,
        "velocity_gain": 1.0938604159417813,
        "closure_lag": 0.15021886163758985,
        "camera_offset": 0.35924037349064797,
        "camera_yaw": 1.7854237037989376,
    },
    7: {
        "observation_delay": 0,
        "vision_false_visible": 0.014323904344795942,
        "gripper_position_bias": 16.982260258854037,
        "action_delay": 0,
        "velocity_gain": 0.756811617325186,
        "closure_lag": 0.15008102135619822,
        "camera_offset": 8.794420725597776,
        "camera_yaw": 2.775760665960525,
    },
    12345: {
        "observation_delay": 0,
        "vision_false_visible": 0.003915408726819394,
        "gripper_position_bias": 7.134884674712163,
        "action_delay": 0,
        "velocity_gain": 0.7994838800196667,
        "closure_lag": 0.017437669487262043,
        "camera_offset": 3.9589742530694383,
        "camera_yaw": 3.7476802911753375,
    },
}
# the first episodes of make_vec_env(2, "All", seed=11, randomise=ROBUST_RANGES): their non-physics draws, pinned so
PINNED_ENV = [
    {
        "observation_delay": 1,
        "vision_false_visible": 0.01377180972112275,
        "gripper_position_bias": 18.111911246107912,
        "action_delay": 0,
        "velocity_gain": 0.6880491517044236,
        "closure_lag": 0.26984419004783916,
        "camera_offset": 3.1513773790985034,
        "camera_yaw": 1.6778751044320201,
    },
    {
        "observation_delay": 1,
        "vision_false_visible": 0.00010060695094084693,
        "gripper_position_bias": 9.165291966492436,
        "action_delay": 0,
        "velocity_gain": 1.0266926437237678,
        "closure_lag": 0.2941936613236041,
        "camera_offset": 3.5063597839390424,
        "camera_yaw": 1.0457530333620322,
    },
]


def test_the_all_draw_is_todays_to_the_last_bit():
    ranges = P.parse_ranges(ROBUST_RANGES)
    for seed, pinned in PINNED.items():
        assert P.randomised(ranges, seed, "all") == pinned
    env = make_vec_env(2, "All", seed=11, horizon=4, randomise=ROBUST_RANGES)
    env.reset()
    physics = set(P.names(P.PHYSICS))
    assert [{k: v for k, v in r.items() if k not in physics} for r in env.randomised] == PINNED_ENV
    for i, pinned in enumerate(PINNED_ENV):  # the Perturber runs each episode under them
        assert env.perturber.episodes[i].m.gain == pinned["velocity_gain"]
        assert env.perturber.episodes[i].m.obs_delay == pinned["observation_delay"]


# ------------------------------------------------------------------------------------------------ the "one" draw
# ranges whose magnitudes are never the family's off value: the one family an episode perturbs is the one not off
ONE_RANGES = {
    "observation_delay": [1, 3],
    "vision_dropout": [0.1, 0.5],
    "velocity_gain": [0.5, 0.9],
    "closure_lag": [0.1, 0.3],
    "friction": [0.02, 1.2],
    "cable_length": [20, 60],
    "camera_offset": [2.0, 6.0],
    "camera_yaw": [1.0, 4.0],
}
ONE_DRAWN = ["observation_delay", "vision_dropout", "velocity_gain", "closure_lag", "camera_offset", "camera_yaw"]


def chosen(drawn: dict) -> list:
    """The families a draw perturbs (not at their off value)."""
    return [name for name, m in drawn.items() if m != P.family(name).off]


def test_the_one_draw_takes_one_family_or_none_each_alike_at_a_magnitude_in_its_range():
    ranges = P.parse_ranges(ONE_RANGES)
    seeds = range(7000)
    draws = [P.randomised(ranges, seed, "one") for seed in seeds]
    assert draws[123] == P.randomised(ranges, 123, "one") and draws[0] != draws[1]  # the episode's seed alone
    assert all(list(d) == ONE_DRAWN for d in draws)  # every randomised family recorded, physics: the simulator's
    picks = [chosen(d) for d in draws]
    assert all(len(c) <= 1 for c in picks)  # one family or none
    counts = {name: sum(c == [name] for c in picks) for name in ONE_DRAWN}
    counts["none"] = sum(c == [] for c in picks)
    assert all(abs(n - 1000) < 150 for n in counts.values()), counts  # 7 choices alike (each about 1000 +- 30)
    for seed, drawn, pick in zip(seeds, draws, picks, strict=True):
        if pick:  # at the magnitude the "all" draw gives it, so in its range; the others off
            (name,) = pick
            assert drawn[name] == P.randomised(ranges, seed, "all")[name]
            low, high = ranges[name]
            assert low <= drawn[name] <= high
        assert isinstance(drawn["observation_delay"], int)
    delays = [d["observation_delay"] for d, c in zip(draws, picks, strict=True) if c == ["observation_delay"]]
    assert min(delays.count(k) for k in (1, 2, 3)) > 250  # each whole number alike (about 333 each)
    assert {d["velocity_gain"] for d, c in zip(draws, picks, strict=True) if c != ["velocity_gain"]} == {1.0}
    # the ROBUST_RANGES: 8 observation, action and camera families, 9 choices; the physics ones never chosen
    robust = P.parse_ranges(ROBUST_RANGES)
    drawn = [P.randomised(robust, seed, "one") for seed in range(900)]
    assert all(set(d) == set(robust) - {"friction", "cable_length"} and len(chosen(d)) <= 1 for d in drawn)
    assert all(sum(chosen(d) == [name] for d in drawn) > 20 for name in drawn[0])  # (a delay's 0 is its off too)


def test_a_bad_draw_is_one_line_and_a_draw_needs_a_randomisation(tmp_path, capsys):
    for bad in ("some", "ALL", 1, None):
        with pytest.raises(ValueError) as error:
            check_options({"randomise": RANGES, "randomise_draw": bad})
        assert str(error.value) == f"randomise_draw: expected all or one, got {bad!r}"
        with pytest.raises(ValueError, match="randomise_draw: expected all or one"):
            P.randomised(P.parse_ranges(RANGES), 0, bad)
    for without in ({}, {"randomise": ""}, {"randomise": {}}):
        with pytest.raises(ValueError, match=r"^randomise_draw: one without randomise \(it says how randomise's families"):
            check_options({**without, "randomise_draw": "one"})
        with pytest.raises(ValueError, match="randomise_draw: all without randomise"):
            make_vec_env(1, "K", **without, randomise_draw="all")
    check_options({"randomise": RANGES, "randomise_draw": "one"})
    from dlo_policy.train import main

    assert main(["--modalities", "K", "--out", str(tmp_path / "run"), "env_options.randomise_draw=one"]) == 2
    said = capsys.readouterr().err.strip()
    assert said.startswith("dlo-train: error: env_options: randomise_draw: one without randomise") and "\n" not in said
    assert not (tmp_path / "run").exists()


def test_in_the_one_draw_the_cameras_the_perturber_and_info_randomised_agree(monkeypatch):
    """Every consumer of an episode's draw sees the same "one" draw: the per-env camera it renders through, the
    Perturber's magnitudes and info "randomised" (and randomised.csv with it). Fails if one of them draws "all"."""
    env = make_vec_env(4, "All", seed=21, horizon=3, randomise=ONE_RANGES, randomise_draw="one")
    assert env.randomise_draw == "one"
    ranges = P.parse_ranges(ONE_RANGES)
    cameras = {}  # episode seed -> (offset along y [mm], yaw [deg]) it renders through
    set_camera = env.sim.set_camera

    def spy(env_ids, offsets, yaws):
        seeds = env.next_seed - len(env_ids) + np.arange(len(env_ids))  # _start_episodes has taken them
        for seed, offset, yaw in zip(seeds, offsets, yaws, strict=True):
            cameras[int(seed)] = (1000.0 * offset[1], np.degrees(yaw))
        return set_camera(env_ids, offsets, yaws)

    monkeypatch.setattr(env.sim, "set_camera", spy)
    env.reset()
    rng = np.random.default_rng(3)
    ended, perturbed = {}, {}
    for _ in range(10):
        for i, seed in enumerate(env.episode_seed):  # the episode each env runs now, as the Perturber runs it
            m = env.perturber.episodes[i].m
            perturbed[int(seed)] = (m.obs_delay, m.dropout, m.gain, m.closure_rate)
        ended.update(episodes(env, 1, rng))
    assert len(ended) >= 10 and set(ended) <= set(perturbed) <= set(cameras)
    differs = set()
    for seed in cameras:
        one, every = P.randomised(ranges, seed, "one"), P.randomised(ranges, seed, "all")
        differs |= {name for name in one if one[name] != every[name]}
        assert cameras[seed] == pytest.approx((one["camera_offset"], one["camera_yaw"]), abs=1e-6)
        if seed in perturbed:
            rate = -math.expm1(-CONTROL_PERIOD / one["closure_lag"]) if one["closure_lag"] else 1.0
            assert perturbed[seed] == (one["observation_delay"], one["vision_dropout"], one["velocity_gain"], rate)
        if seed in ended:
            assert {name: ended[seed][name] for name in one} == one
            assert 0.02 <= ended[seed]["friction"] <= 1.2 and 20 <= ended[seed]["cable_length"] <= 60  # every episode
    assert differs == set(ONE_DRAWN)  # each consumer's families: the "all" draw would have failed it
    assert len({tuple(chosen({n: r[n] for n in ONE_DRAWN})) for r in ended.values()}) >= 3


def episodes(env, steps, rng):
    """{episode seed: its info["randomised"]} of every episode that ended in ``steps`` random steps."""
    ended = {}
    for _ in range(steps):
        _, _, _, _, info = env.step(rng.uniform(-1, 1, (env.num_envs, 3)).astype(np.float32))
        if "randomised" in info:
            for i in np.flatnonzero(info["_randomised"]):
                ended[int(info["episode_seed"][i])] = info["randomised"][i]
    return ended


def test_the_env_runs_each_episode_under_its_draws_and_reports_them():
    env = make_vec_env(3, "All", seed=11, horizon=4, randomise=RANGES)
    env.reset()
    params = env.sim.params
    first = {int(s): r for s, r in zip(env.episode_seed, env.randomised, strict=True)}
    for i, seed in enumerate(env.episode_seed):  # physics as the simulator drew it, in the range
        assert first[int(seed)]["friction"] == pytest.approx(float(params["friction"][i]))
        assert first[int(seed)]["cable_length"] == int(params["num_particles"][i])
        assert env.perturber.episodes[i].m.obs_delay == first[int(seed)]["observation_delay"]
        assert env.perturber.episodes[i].m.gain == first[int(seed)]["velocity_gain"]
    ended = episodes(env, 12, np.random.default_rng(0))
    assert len(ended) >= 9 and all(set(r) == set(RANGES) for r in ended.values())
    for name, (low, high) in RANGES.items():
        values = [r[name] for r in ended.values()]
        assert all(low <= v <= high for v in values), (name, values)
        assert len(set(values)) > 1, (name, values)  # they differ across episodes
    assert env.sim.config.friction_range == (0.02, 1.2) and env.sim.config.num_particles_range == (20, 60)
    # the same episodes in a batch of one: the same draws (the episode's seed alone)
    single = make_vec_env(1, "All", seed=11, horizon=4, randomise=RANGES)
    single.reset()
    again = episodes(single, 30, np.random.default_rng(1))
    common = set(again) & set(ended)
    assert len(common) >= 5 and all(again[s] == ended[s] for s in common)


def test_no_randomisation_draws_nothing_and_reports_nothing():
    env = make_vec_env(2, "All", seed=11, horizon=2)
    env.reset()
    assert env.randomise == {} and not env.perturber.active and not env.camera_per_env
    _, _, _, _, info = env.step(np.zeros((2, 3), np.float32))
    _, _, _, _, info = env.step(np.zeros((2, 3), np.float32))
    assert "outcome" in info and "randomised" not in info


def test_a_randomised_camera_renders_as_the_fixed_one_of_the_same_magnitude():
    """The per-env camera (dlo_sim RopeSim.set_camera) against the one camera of a fixed perturbation: the same
    observation to the last bit, and not the unperturbed one."""
    rng = np.random.default_rng(2)
    sequence = rng.uniform(-0.3, 1.0, (6, 2, 3)).astype(np.float32)

    def run(**options):
        env = make_vec_env(2, "V+K", seed=4, autoreset=False, **options)
        seen = [env.reset(seed=4)[0]]
        seen += [env.step(a)[0] for a in sequence]
        return np.array(seen)

    fixed = run(perturbations={"camera_yaw": 3.0, "camera_offset": 6.0})
    randomised = run(randomise={"camera_yaw": [3.0, 3.0], "camera_offset": [6.0, 6.0]})
    mixed = run(perturbations={"camera_offset": 6.0}, randomise={"camera_yaw": [3.0, 3.0]})
    np.testing.assert_array_equal(randomised, fixed)
    np.testing.assert_array_equal(mixed, fixed)
    assert not np.array_equal(fixed, run())


def test_only_the_training_env_is_randomised():
    config = RunConfig(modalities="K", seed=1, env_options={"randomise": {"observation_delay": [1, 1]}, "horizon": 3})
    assert make_env(config, training=True).vec.randomise == {"observation_delay": (1, 1)}
    evaluation = make_env(config, 2)
    assert evaluation.randomise == {} and evaluation.sim.config.friction_range == (0.04, 0.3)


# ------------------------------------------------------------------------------------------------ training
ENVELOPE = Path(__file__).resolve().parents[4] / "results" / "robustness" / "shipped" / "robustness.json"


def test_the_robust_group_trains_All_with_ranges_up_to_twice_the_shipped_policys_tolerances():
    """dlo-experiments --groups robust: All with ROBUST_RANGES, never in the paper's default groups. Each range
    goes from the nominal at most twice as far as the shipped policy's 80% tolerance (authors' rule, the committed
    envelope) on each side, and beyond the tolerance itself for at least 6 families."""
    (spec,) = experiment_grid(["robust"], [1])
    assert (spec.label, spec.modalities, spec.groups) == (ROBUST_LABEL, "All", ("robust",))
    assert dict(spec.env_options) == {"randomise": ROBUST_RANGES, "randomise_draw": "one"}
    check_options(dict(spec.env_options))
    assert ROBUST_LABEL not in {s.label for s in experiment_grid(GROUPS, [1])}
    families = json.loads(ENVELOPE.read_text())["families"]
    beyond = set()
    for name, (low, high) in P.parse_ranges(ROBUST_RANGES).items():
        f = P.family(name)
        nominal_low, nominal_high = (f.off, f.off) if f.off is not None else f.training
        tolerance = families[name]["tolerance"]["authors"]
        for side, reach, distance in (("above", high, high - nominal_high), ("below", low, nominal_low - low)):
            limit = tolerance.get(side)
            if limit is None or distance <= 0:
                continue
            allowed = abs(limit - (nominal_high if side == "above" else nominal_low))
            assert distance <= 2 * allowed + 1e-9, (name, side, reach, limit)
            beyond |= {name} if distance >= allowed - 1e-9 else set()
    assert len(beyond) >= 6, beyond


@pytest.fixture
def restore_threads():
    """Gives back torch's thread count, which a dlo-train run in this process sets (train.num_threads)."""
    import torch  # noqa: PLC0415 (torch: only for the tests that train)

    previous = torch.get_num_threads()
    yield
    torch.set_num_threads(previous)


def test_a_short_training_run_records_the_ranges_and_every_episodes_draws(tmp_path, capsys, restore_threads):
    """dlo-train with env_options.randomise: config.yaml holds the ranges, randomised.csv one row per training
    episode with the magnitudes it ran under (different across episodes, in the ranges, the env's for its seed),
    and the evaluations run without them."""
    out = tmp_path / "run"
    ranges = "observation_delay=0:2,velocity_gain=0.5:2,friction=0.02:1.2,camera_yaw=0:4"
    steps = 150  # 72 training episodes: the untrained policy drops the cable within a few steps
    args = [
        "--modalities",
        "All",
        "--seed",
        "3",
        "--steps",
        str(steps),
        "--out",
        str(out),
        "--no-progress",
        "sac.hidden_sizes=[32,32]",
        "sac.learning_starts=100",
        "sac.batch_size=32",
        "train.eval_every=150",
        "train.eval_episodes=1",
        "train.test_episodes=1",
        "train.num_threads=1",
        "train.checkpoint_every=100000",
        f"env_options.randomise={ranges}",
    ]
    assert train.main(args) == 0
    config = yaml.safe_load((out / "config.yaml").read_text())
    assert P.parse_ranges(config["env_options"]["randomise"]) == P.parse_ranges(ranges)
    with open(out / "randomised.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    summary = json.loads(capsys.readouterr().out)
    assert len(rows) == summary["episodes"] >= 3
    assert list(rows[0]) == ["step", "episode", "episode_seed", "observation_delay", "velocity_gain", "friction", "camera_yaw"]
    assert [int(r["episode"]) for r in rows] == list(range(len(rows)))
    ends = [int(r["step"]) for r in rows]
    assert ends == sorted(set(ends)) and ends[-1] <= steps
    for name, (low, high) in P.parse_ranges(ranges).items():
        values = [float(r[name]) for r in rows]
        assert all(low <= v <= high for v in values) and len(set(values)) > 1, (name, values)
    for row in rows:  # each the draw of its episode's seed (the physics one drawn by the simulator)
        drawn = P.randomised(P.parse_ranges(ranges), int(row["episode_seed"]), "all")
        assert (
            float(row["velocity_gain"]) == drawn["velocity_gain"] and int(row["observation_delay"]) == drawn["observation_delay"]
        )
    test = json.loads((out / "test.json").read_text())
    assert test["episodes"] == 1


def test_the_robust_group_draws_one_family_and_an_override_gives_the_earlier_group_back(tmp_path):
    """dlo-experiments --groups robust: randomise_draw one; the command line's env_options.randomise_draw=all (an
    override, applied after the group's env_options, the grid's modalities and seed after it) trains the earlier
    group: its training env draws today's magnitudes and gives the same observations to the last bit."""
    (spec,) = experiment_grid(["robust"], [1])
    grid = run_config(spec, None, [], steps=None, threads=1)
    assert grid.env_options == {"randomise": ROBUST_RANGES, "randomise_draw": "one"}
    overridden = run_config(spec, None, ["env_options.randomise_draw=all", "modalities=K", "seed=9"], None, 1)
    assert overridden.env_options == {"randomise": ROBUST_RANGES, "randomise_draw": "all"}
    assert (overridden.modalities, overridden.seed, overridden.label) == ("All", 1, ROBUST_LABEL)  # the grid's own
    mine = tmp_path / "mine.yaml"  # a --config file: the group's env_options after it, the overrides after both
    mine.write_text("env_options: {randomise_draw: all, tactile_noise: partial}\n")
    assert run_config(spec, mine, [], None, 1).env_options == {**grid.env_options, "tactile_noise": "partial"}
    assert run_config(spec, mine, ["env_options.tactile_noise=full"], None, 1).env_options["tactile_noise"] == "full"
    other = RunSpec("All tactile-partial", "All", 4, (("tactile_noise", "partial"),))
    assert run_config(other, None, ["env_options.tactile_noise=full"], None, 1).env_options == {"tactile_noise": "full"}

    earlier = RunConfig(modalities="All", seed=1, env_options={"randomise": ROBUST_RANGES})  # the group before
    physics = set(P.names(P.PHYSICS))
    runs = {}
    for name, config in (("earlier", earlier), ("overridden", overridden), ("grid", grid)):
        env = make_env(config, 2, seed=11, training=True)
        seen = [env.reset()[0]]
        first = [{k: v for k, v in r.items() if k not in physics} for r in env.randomised]
        seen += [env.step(np.full((2, 3), 0.3, np.float32))[0] for _ in range(3)]
        runs[name] = (first, np.array(seen))
    assert runs["earlier"][0] == runs["overridden"][0] == PINNED_ENV
    np.testing.assert_array_equal(runs["overridden"][1], runs["earlier"][1])
    ranges = P.parse_ranges(ROBUST_RANGES)
    assert runs["grid"][0] == [P.randomised(ranges, seed, "one") for seed in (11, 12)] != PINNED_ENV
    for config in (grid, overridden):  # evaluations run the task without either option
        evaluation = make_env(config, 2)
        assert evaluation.randomise == {} and evaluation.randomise_draw == "all"


def test_a_run_with_the_one_draw_records_it_and_its_resume_draws_the_same(tmp_path, restore_threads):
    """dlo-train env_options.randomise_draw=one: config.yaml records it, randomised.csv's rows are each episode's
    "one" draw (one family or none perturbed, every randomised family recorded), and --resume (the saved config)
    goes on drawing so."""
    out = tmp_path / "run"
    ranges = "observation_delay=1:2,velocity_gain=0.5:0.9,friction=0.02:1.2,camera_yaw=1:4"
    tiny = [
        "sac.hidden_sizes=[32,32]",
        "sac.learning_starts=100",
        "sac.batch_size=32",
        "train.eval_every=150",
        "train.eval_episodes=1",
        "train.test_episodes=1",
        "train.num_threads=1",
        "train.checkpoint_every=150",
        "env_options.horizon=15",
    ]
    args = ["--modalities", "All", "--seed", "3", "--steps", "150", "--out", str(out), "--no-progress", *tiny]
    args += [f"env_options.randomise={ranges}", "env_options.randomise_draw=one"]

    def run(*given):
        assert train.main(list(given)) == 0
        assert yaml.safe_load((out / "config.yaml").read_text())["env_options"]["randomise_draw"] == "one"
        with open(out / "randomised.csv", newline="") as f:
            return list(csv.DictReader(f))

    first = run(*args)  # 55 episodes, 23 more in the resumed part: the untrained policy drops the cable early
    rows = run("--out", str(out), "--resume", "--steps", "225")
    assert int(rows[-1]["step"]) > 150 and len(rows) > len(first) >= 15
    assert rows[: len(first)] == first  # (the first run ended at its checkpoint: the resume rewrote nothing)
    assert list(rows[0])[3:] == ["observation_delay", "velocity_gain", "friction", "camera_yaw"]
    picks = set()
    for row in rows:
        drawn = P.randomised(P.parse_ranges(ranges), int(row["episode_seed"]), "one")
        assert {"observation_delay": int(row["observation_delay"]), "velocity_gain": float(row["velocity_gain"])} | {
            "camera_yaw": float(row["camera_yaw"])
        } == drawn
        assert 0.02 <= float(row["friction"]) <= 1.2  # the physics family: every episode
        picks.add(tuple(chosen(drawn)))
    assert len(picks) >= 3  # (4 choices: each family, or none)
