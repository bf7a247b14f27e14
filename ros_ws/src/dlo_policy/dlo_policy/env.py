"""Gymnasium environments of the cable-following benchmark (paper's task, our Taichi simulator).

``make_vec_env(num_envs, modalities, seed, **options)``: a ``gymnasium.vector.VectorEnv`` running
N environments batched in ONE simulator, with same-step auto-reset of finished envs. The simulator is a backend
of ``dlo_interface.simulator`` (option ``simulator``; default the Taichi rope of ``dlo_sim``): this module
imports none.
``make_env(modalities, seed, **options)``: a single ``gymnasium.Env`` (passes ``check_env``).

Action: [-1, 1]^3 = [dx, dy, c] (dx, dy x 0.0025 m per 0.01 s step, closure c = (a2 + 1) / 2),
held for one control step of 8 x 0.01 s. Observation: ``dlo_policy.observation`` (the modalities of
``dlo_policy.modalities``, K, T, V in that order, each read from the simulator by its record's
``observe``). Reward, ending and outcomes: ``dlo_interface.task``. An episode ends when the cable is
dropped (terminated) or after ``horizon`` control steps (truncated).

Seeds: ``reset(seed=s)`` starts env i on episode seed s + i; every later episode (auto-reset or
``reset()`` without seed) takes the next unused seed s + N, s + N + 1, ... in order, so the same
seed and actions give the same episodes. The tactile noise generator is seeded from s as well.

Options (keywords of both entry points):
    without=()            modalities zeroed at test time (ablation), e.g. ("T",)
    tactile_noise="none"  "none" | "partial" | "full" | a pair [sigma_theta [rad], sigma_y [m]] (also as
                          text "0.1,0.001"): read by dlo_perception.tactile.noise_setting, as the tactile
                          node's tactile_noise parameter and launch_graph.sh --tactile-noise are
    horizon=150           control steps per episode
    end_particles=10      "at the end" = holding one of the last this-many particles
    task_rules="authors_code"  "authors_code" | "paper_text": the held set, reward and termination the
                          episode uses, and the held set the tactile input is fitted to (dlo_interface.task;
                          default dlo_interface.task.DEFAULT_TASK_RULES, docs/FIDELITY.md)
    move_spacing=0.0      m, the particle spacing of the move reward under either task rule: 0 = the cable's own
                          (L_c / n_c, or L_c / (n_c - 1) under authors_code); 0.004 = the authors' fixed 4 mm
                          (their rope_length = segment x 0.004, dlo_interface.task, docs/FIDELITY.md); up to 0.01
    camera_resolution=128 top-view image size [px]
    sim_config=None       a dlo_interface.sim_config.SimConfig
    single_particle_grip=False  true: the grip carries ONE particle, the held one nearest the finger axis
                          (never particle 0), as the authors' code did (dlo_interface.grip, docs/FIDELITY.md
                          row 5); false: every held particle (or what a given sim_config says)
    carry_law="paper"     "paper": the paper's grip law on the held set (and the finite grip); "authors": their
                          carry law, one particle moved by the whole displacement above c 0.5, cancelled
                          beyond 10 mm from a neighbour (dlo_interface.grip, docs/FIDELITY.md rows 5-6)
    contact_radius=0.004  m, the cable's contact half-thickness (dlo_interface.sim_config.SimConfig); above 0.00425
                          (half the finger gap) the fingers pinch the cable, as Flex's 5 mm collision distance does
    start_pose="ours"     "ours": the gripper starts 5 mm behind the fixed end, at its height; "authors": 8 mm
                          behind and 2.25 mm lower, as their Picker.reset (dlo_interface.world.START_POSES)
    vision_source="image" "image": V from the rendered top view (what a camera gives); "particles": the
                          paper's simplified scalars, by the authors' index walk on the task rules' held set
                          (dlo_perception.vision.visual_pose_particles, docs/FIDELITY.md row 11); no rendering
    physics_seed=-1       >= 0: every episode gets the stretch, bending and friction drawn from this seed
                          (the authors' one physics draw, docs/FIDELITY.md row 8; particle count and start
                          shape still per episode); -1: drawn per episode (or what a given sim_config says)
    perturbations=None    robustness perturbations, each off by default (dlo_policy.perturbations: the families, their
                          units and what each does): {name: magnitude} or text "observation_delay=2,friction=0.6".
                          Observation and action families go through a Perturber over the observation vector and the
                          action (the policy node runs the same one), physics families through the SimConfig ranges,
                          camera families through the camera that renders (the vision assumes the nominal one). Their
                          noise is drawn per episode from the episode's seed (the same in any batch and in the graph)
    randomise=None        domain randomisation for training (dlo_policy.perturbations.parse_ranges): {name: [low, high]}
                          or text "observation_delay=0:2,friction=0.02:1.2"; every episode takes each family's
                          magnitude uniformly from its range, from the episode's seed (reproducible, the same in any
                          batch); a physics range replaces the training range, a camera family renders each env
                          through a camera of its own. A family is in perturbations or here, not both. dlo-train
                          builds only its training env with it (evaluation and test run without: config.make_env)
    randomise_draw="all"  with randomise only: how its observation, action and camera families are drawn
                          (dlo_interface.perturbations.DRAWS): "all", every one every episode; "one", each episode
                          ONE of them or none (each of the n + 1 choices alike, from the episode's seed), the others
                          off. Its physics families are drawn every episode either way (by the simulator)
    previous_action=False true: the observation ends with the action the env got at the step before, as the policy
                          gave it (before the action perturbations), zeros at an episode's first step
                          (dlo_policy.observation.with_previous_action): the policy's memory of the commands in flight
    simulator="taichi"    the simulator backend: a name registered in the entry point group dlo_interface.simulators
                          (dlo_interface.simulator; "taichi": dlo_sim's rope) or, in code, a factory of one

Info: every step carries "n_held" and "mean_held_index"; an env whose episode ended in this step
has "outcome" (name; paper-text rule), "outcome_code", "outcome_authors" (name; the authors'-code
rule, ``dlo_interface.task``), "time_at_end", "how_far", "episode_return",
"episode_length", "episode_seed", "unstable" (the simulator had to reset it; the episode is cut and
counted as truncated), "randomised" (with ``randomise`` only: {family: the magnitude the episode ran under},
physics families as the simulator drew them; under ``randomise_draw="one"`` the families not chosen at their off
value), and, in the vector env, "final_obs" (the last observation of that episode, the returned one is already the
next episode's first). Vector infos follow gymnasium's
dict-of-arrays layout with "_key" masks.
"""

from __future__ import annotations

import dataclasses

import gymnasium
import numpy as np
from dlo_interface import task
from dlo_interface.camera import TopCamera
from dlo_interface.grip import CARRY_LAWS
from dlo_interface.sim_config import MAX_CONTACT_RADIUS, SimConfig
from dlo_interface.simulator import DEFAULT_SIMULATOR, check_simulator, simulator_factory
from dlo_interface.world import START_POSES
from dlo_perception.tactile import noise_sigma
from dlo_perception.vision_source import DEFAULT_VISION_SOURCE, check_vision_source
from gymnasium.vector import AutoresetMode, VectorEnv

from dlo_policy import perturbations as perturbation_families
from dlo_policy.modalities import VISION_PLANE_Z, by_name  # noqa: F401 (VISION_PLANE_Z: its old home)
from dlo_policy.observation import PreviousAction, build_observation, observation_bounds, parse_modalities


def check_options(options) -> None:
    """Raise ValueError with a one-line reason for an unknown option or a bad value (module
    docstring), before any simulator is built: what dlo-train checks its ``env_options`` with."""
    known = (
        "without",
        "tactile_noise",
        "horizon",
        "end_particles",
        "camera_resolution",
        "sim_config",
        "task_rules",
        "move_spacing",
        "single_particle_grip",
        "physics_seed",
        "vision_source",
        "carry_law",
        "contact_radius",
        "start_pose",
        "perturbations",
        "randomise",
        "randomise_draw",
        "previous_action",
        "simulator",
    )
    unknown = sorted(set(options) - set(known))
    if unknown:
        raise ValueError(f"unknown option(s) {', '.join(unknown)}; known: {', '.join(known)}")
    _check_observation_options(options)
    _check_variant_options(options)
    _check_sim_options(options)


def _check_observation_options(options) -> None:
    """tactile_noise, without, perturbations, randomise (not a physics family with a fixed physics_seed) and
    randomise_draw (with randomise only)."""
    if "tactile_noise" in options:
        try:
            noise_sigma(options["tactile_noise"])
        except (TypeError, ValueError) as error:
            raise ValueError(f"tactile_noise: {error}") from None
    if options.get("without"):
        parse_modalities(options["without"])
    if "perturbations" in options:
        perturbation_families.parse(options["perturbations"])
    if "randomise" in options:
        ranges = perturbation_families.parse_ranges(options["randomise"], options.get("perturbations"))
        physics = perturbation_families.of_side(ranges, perturbation_families.PHYSICS)
        if physics and options.get("physics_seed", -1) >= 0:
            raise ValueError(
                f"randomise: {', '.join(physics)} cannot be drawn per episode with physics_seed "
                f"{options['physics_seed']} (one physics draw for every episode): leave one of them out"
            )
    if "randomise_draw" in options:
        draw = perturbation_families.check_draw(options["randomise_draw"])
        if not perturbation_families.parse_ranges(options.get("randomise")):
            raise ValueError(f"randomise_draw: {draw} without randomise (it says how randomise's families are drawn)")


def _check_variant_options(options) -> None:
    """The task rules and the authors' variants: move_spacing, vision_source, single_particle_grip, physics_seed."""
    if "task_rules" in options:
        task.check_task_rules(options["task_rules"])
    if "move_spacing" in options:
        task.check_move_spacing(options["move_spacing"])
    if "vision_source" in options:
        check_vision_source(options["vision_source"])
    for name in ("single_particle_grip", "previous_action"):
        if not isinstance(options.get(name, False), bool):
            raise ValueError(f"{name}: expected true or false, got {options[name]!r}")
    seed = options.get("physics_seed", -1)
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < -1:
        raise ValueError(f"physics_seed: expected an integer >= 0 (or -1: drawn per episode), got {seed!r}")


def _check_sim_options(options) -> None:
    """simulator, carry_law, start_pose, contact_radius and the integer options (horizon, end_particles,
    camera_resolution)."""
    if "simulator" in options:
        check_simulator(options["simulator"])
    if "carry_law" in options and options["carry_law"] not in CARRY_LAWS:
        raise ValueError(f"carry_law: expected one of {', '.join(CARRY_LAWS)}, got {options['carry_law']!r}")
    if "start_pose" in options and options["start_pose"] not in START_POSES:
        raise ValueError(f"start_pose: expected one of {', '.join(START_POSES)}, got {options['start_pose']!r}")
    if "contact_radius" in options:
        radius = options["contact_radius"]
        if isinstance(radius, bool) or not isinstance(radius, (int, float)) or not 0 < radius <= MAX_CONTACT_RADIUS:
            raise ValueError(f"contact_radius: expected a number in (0, {MAX_CONTACT_RADIUS}] m, got {radius!r}")
    for name, low in (("horizon", 1), ("end_particles", 1), ("camera_resolution", 16)):
        value = options.get(name, low)
        if isinstance(value, bool) or not isinstance(value, int) or value < low:
            raise ValueError(f"{name}: expected an integer >= {low}, got {value!r}")


class CableFollowingVecEnv(VectorEnv):
    """N cable-following environments in one batched simulator (gymnasium 1.x VectorEnv)."""

    def __init__(
        self,
        num_envs,
        modalities="All",
        seed=0,
        without=(),
        tactile_noise="none",
        horizon=task.HORIZON,
        end_particles=task.END_PARTICLES,
        camera_resolution=128,
        sim_config=None,
        autoreset=True,
        task_rules=task.DEFAULT_TASK_RULES,
        move_spacing=task.DEFAULT_MOVE_SPACING,
        single_particle_grip=False,
        physics_seed=-1,
        vision_source=DEFAULT_VISION_SOURCE,
        carry_law=None,
        contact_radius=None,
        start_pose=None,
        perturbations=None,
        randomise=None,
        randomise_draw=None,
        previous_action=False,
        simulator=DEFAULT_SIMULATOR,
    ):
        check_options(
            {
                "previous_action": previous_action,
                "move_spacing": move_spacing,
                "single_particle_grip": single_particle_grip,
                "physics_seed": physics_seed,
                "vision_source": vision_source,
                **({} if randomise is None else {"randomise": randomise, "perturbations": perturbations}),
                **({} if randomise_draw is None else {"randomise": randomise, "randomise_draw": randomise_draw}),
                **({} if carry_law is None else {"carry_law": carry_law}),
                **({} if contact_radius is None else {"contact_radius": contact_radius}),
                **({} if start_pose is None else {"start_pose": start_pose}),
            }
        )
        if start_pose is not None:
            sim_config = dataclasses.replace(sim_config or SimConfig(), start_pose=start_pose)
        if carry_law is not None:
            sim_config = dataclasses.replace(sim_config or SimConfig(), carry_law=carry_law)
        if contact_radius is not None:
            sim_config = dataclasses.replace(sim_config or SimConfig(), contact_radius=float(contact_radius))
        self.vision_source = vision_source
        if single_particle_grip:
            sim_config = dataclasses.replace(sim_config or SimConfig(), single_particle_grip=True)
        if physics_seed >= 0:
            sim_config = dataclasses.replace(sim_config or SimConfig(), physics_seed=physics_seed)
        self.perturbations = perturbation_families.parse(perturbations)  # {family: magnitude}, those that are on
        self.randomise = perturbation_families.parse_ranges(randomise, self.perturbations)  # {family: (low, high)}
        self.randomise_draw = randomise_draw or perturbation_families.DEFAULT_DRAW  # how its families are drawn
        sim_config = perturbation_families.sim_config(self.perturbations, sim_config, self.randomise)
        camera = TopCamera.covering_workspace(int(camera_resolution))
        # a randomised camera family: every env renders through its own camera (set per episode, _start_episodes)
        self.camera_per_env = bool(perturbation_families.of_side(self.randomise, perturbation_families.CAMERA))
        rendering, self.vision_camera = (
            (camera, camera) if self.camera_per_env else perturbation_families.cameras(self.perturbations, camera)
        )
        self.num_envs = int(num_envs)
        self.modalities = parse_modalities(modalities)
        self.without = parse_modalities(without) if without else ()
        self.tactile_sigma = noise_sigma(tactile_noise)
        self.autoreset = bool(autoreset)
        self.metadata = {"autoreset_mode": AutoresetMode.SAME_STEP if autoreset else AutoresetMode.DISABLED}
        # previous_action: the observation ends with each env's previous action (None: off)
        self.previous_action = PreviousAction(self.num_envs) if previous_action else None
        low, high = observation_bounds(self.modalities, bool(previous_action))
        self.single_observation_space = gymnasium.spaces.Box(low, high, dtype=np.float32)
        self.single_action_space = gymnasium.spaces.Box(-1.0, 1.0, (3,), dtype=np.float32)
        self.observation_space = gymnasium.vector.utils.batch_space(self.single_observation_space, self.num_envs)
        self.action_space = gymnasium.vector.utils.batch_space(self.single_action_space, self.num_envs)
        self.task = simulator_factory(simulator)(
            self.num_envs,
            horizon=horizon,
            end_particles=end_particles,
            config=sim_config,
            camera=rendering,
            **({"camera_per_env": True} if self.camera_per_env else {}),
            render=vision_source == "image" and any(by_name(m).renders for m in self._observed()),
            task_rules=task_rules,
            move_spacing=float(move_spacing),
        )
        self.sim, self.tracker = self.task.sim, self.task.tracker
        self.default_seed = int(seed)
        self.next_seed = None  # next unused episode seed; None until the first reset
        self.episode_seed = np.full(self.num_envs, -1, np.int64)
        self.noise_rng = np.random.default_rng(self.default_seed)
        self.last_observation = None
        # the observation and action families (dlo_policy.perturbations.Perturber), as the policy node runs them
        self.perturber = perturbation_families.Perturber(
            self.perturbations, self.modalities, self.without, self.num_envs, ranges=self.randomise, draw=self.randomise_draw
        )
        self.randomised = [None] * self.num_envs  # randomise: each env's episode magnitudes (info "randomised")

    # ------------------------------------------------------------------ gymnasium API
    def reset(self, *, seed=None, options=None):
        """Start new episodes in all envs; ``seed`` restarts the seed sequence (see module doc)."""
        super().reset(seed=seed)
        if seed is not None or self.next_seed is None:
            base = self.default_seed if seed is None else int(seed)
            self.next_seed = base
            self.noise_rng = np.random.default_rng(base)
        self._start_episodes(np.arange(self.num_envs))
        observation, state = self._observe()
        if self.perturber.observes:
            observation = self.perturber.observe(observation)
        if self.previous_action is not None:
            self.previous_action.start()
            observation = self.previous_action.append(observation)
        self.last_observation = observation
        return observation, {"n_held": state["n_held"], "mean_held_index": state["p_i"], "episode_seed": self.episode_seed.copy()}

    def step(self, actions):
        """Advance every env by one control step (8 x 0.01 s); finished envs auto-reset in the same step."""
        actions = np.asarray(actions, dtype=np.float32).reshape(self.num_envs, 3)
        if self.previous_action is not None:
            self.previous_action.took(actions)  # as the policy gave them (before the action perturbations)
        if self.perturber.acts:
            actions = self.perturber.act(actions)
        reward, terminated, truncated, unstable = self.task.step(actions)
        observation, state = self._observe()
        if self.perturber.observes:
            observation = self.perturber.observe(observation)
        if self.previous_action is not None:
            observation = self.previous_action.append(observation)
        done = terminated | truncated
        info = {"n_held": state["n_held"], "mean_held_index": state["p_i"]}
        if done.any():
            info.update(self._episode_end_info(done, unstable))
            if self.autoreset:
                info["final_obs"] = np.array([observation[i] if done[i] else None for i in range(self.num_envs)], dtype=object)
                info["_final_obs"] = done.copy()
                self._start_episodes(np.flatnonzero(done))
                fresh, _ = self._observe()
                if self.perturber.observes:
                    fresh[done] = self.perturber.observe(fresh[done], np.flatnonzero(done))
                if self.previous_action is not None:
                    self.previous_action.start(done)  # a new episode's first step
                    fresh = self.previous_action.append(fresh)
                observation = np.where(done[:, None], fresh, observation)
        self.last_observation = observation
        return observation, reward.astype(np.float64), terminated, truncated, info

    def close_extras(self, **kwargs):
        """Nothing to release: the Taichi rope's fields live as long as the process, and its simulator gives them
        and their compiled kernels back for reuse once it is gone (dlo_sim.kernels.kernels_for)."""

    # ------------------------------------------------------------------ internals
    def _start_episodes(self, env_ids):
        """Reset the simulator and the task tracker of ``env_ids`` with the next episode seeds."""
        seeds = self.next_seed + np.arange(len(env_ids))
        self.next_seed += len(env_ids)
        # each new episode's randomised magnitudes: its camera and info "randomised" (the Perturber's, drawn alike)
        draws = (
            [perturbation_families.randomised(self.randomise, int(s), self.randomise_draw) for s in seeds]
            if self.randomise
            else []
        )
        if self.camera_per_env:
            self._set_cameras(env_ids, draws)
        self.task.reset(seeds, env_ids)
        self.episode_seed[env_ids] = seeds
        if self.perturber.active:
            self.perturber.start(env_ids, seeds)
        if self.randomise:
            self._note_randomised(env_ids, draws)

    def _set_cameras(self, env_ids, draws):
        """Each env's rendering camera for its new episode: the fixed camera families with its randomised ones."""
        offsets, yaws = [], []
        for drawn in draws:
            m = {**self.perturbations, **drawn}
            offsets.append((0.0, 0.001 * m.get("camera_offset", 0.0)))
            yaws.append(np.radians(m.get("camera_yaw", 0.0)))
        self.sim.set_camera(env_ids, offsets, yaws)

    def _note_randomised(self, env_ids, draws):
        """The randomised magnitudes of the new episodes in ``env_ids`` (physics ones as the simulator drew them)."""
        params = self.sim.params
        for i, drawn in zip(env_ids, draws, strict=True):
            drawn = dict(drawn)
            for name in self.randomise:
                f = perturbation_families.family(name)
                if f.side == perturbation_families.PHYSICS:
                    value = params[f.sim_param][i]
                    drawn[name] = int(value) if f.integer else float(value)
            self.randomised[int(i)] = {name: drawn[name] for name in self.randomise}

    def _observed(self) -> tuple:
        """The modalities the observation computes (selected and not ablated), in registry order."""
        return tuple(m for m in self.modalities if m not in self.without)

    def _observe(self):
        """Observation (N, D) of the current simulator state (the task's snapshot) and the held-particle summary:
        each observed modality's reading from its record's ``observe`` (dlo_policy.modalities), in order."""
        state = {"n_held": self.task.n_held, "p_i": self.task.mean_held_index}
        readings = {by_name(m).title: by_name(m).observe(self) for m in self._observed()}
        observation = build_observation(self.modalities, without=self.without, **readings)
        return observation, state

    def _episode_end_info(self, done, unstable):
        """Episode-end metrics of the envs in ``done`` as gymnasium vector infos (arrays + masks)."""
        values = {
            "outcome": np.array([task.OUTCOME_NAMES[int(c)] for c in self.tracker.outcome], dtype=object),
            "outcome_code": self.tracker.outcome.copy(),
            "outcome_authors": np.array([task.OUTCOME_NAMES[int(c)] for c in self.tracker.outcome_authors], dtype=object),
            "time_at_end": self.tracker.time_at_end.copy(),
            "how_far": self.tracker.how_far(),
            "episode_return": self.tracker.episode_return.copy(),
            "episode_length": self.tracker.steps.copy(),
            "episode_seed": self.episode_seed.copy(),
            "unstable": unstable.copy(),
        }
        if self.randomise:
            values["randomised"] = np.array([dict(r) if r is not None else None for r in self.randomised], dtype=object)
        info = dict(values)
        info.update({"_" + key: done.copy() for key in values})
        return info


class CableFollowingEnv(gymnasium.Env):
    """One cable-following environment (a ``CableFollowingVecEnv`` of 1 without auto-reset)."""

    metadata = {"render_modes": []}

    def __init__(self, modalities="All", seed=0, **options):
        self.vec = CableFollowingVecEnv(1, modalities=modalities, seed=seed, autoreset=False, **options)
        self.observation_space = self.vec.single_observation_space
        self.action_space = self.vec.single_action_space

    @property
    def sim(self):
        """The underlying batched simulator (one environment)."""
        return self.vec.sim

    @property
    def modalities(self) -> tuple:
        """The observed modalities, expanded and in order (e.g. ("K", "T", "V"))."""
        return self.vec.modalities

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        observation, info = self.vec.reset(seed=seed, options=options)
        return observation[0], unbatch_info(info)

    def step(self, action):
        observation, reward, terminated, truncated, info = self.vec.step(np.asarray(action)[None])
        return observation[0], float(reward[0]), bool(terminated[0]), bool(truncated[0]), unbatch_info(info)


def unbatch_info(info) -> dict:
    """Env 0's entries of a vector info dict, as plain Python values."""
    single = {}
    for key, value in info.items():
        if key.startswith("_") or (("_" + key) in info and not info["_" + key][0]):
            continue
        item = value[0]
        single[key] = item.item() if isinstance(item, np.generic) else item
    return single


def make_env(modalities="All", seed=0, **options) -> CableFollowingEnv:
    """A single cable-following ``gymnasium.Env``; options: see the module docstring."""
    return CableFollowingEnv(modalities=modalities, seed=seed, **options)


def make_vec_env(num_envs, modalities="All", seed=0, **options) -> CableFollowingVecEnv:
    """N cable-following envs batched in one simulator (``gymnasium.vector.VectorEnv``)."""
    return CableFollowingVecEnv(num_envs, modalities=modalities, seed=seed, **options)
