"""Run configuration: every SAC and training hyperparameter, loadable from YAML with overrides.

A run is described by a `RunConfig`: the agent's `SACConfig`, the protocol's `TrainConfig`, and
what to train on (modalities, env options, seed). `load_config(path, overrides)` reads a YAML
file shaped like `config/sac_default.yaml` and applies `key=value` overrides such as
`sac.batch_size=256` or `env_options.tactile_noise=partial`. Unknown keys and values of the
wrong type raise `ConfigError` naming the key.

The defaults live here, once: each key is declared with its default and its description (`_key`), and
`config/sac_default.yaml` is generated from them (`defaults_yaml`, written by tools/gen_node_configs.py).
"""

from __future__ import annotations

import dataclasses
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional

import yaml
from dlo_common.params import yaml_problem


class ConfigError(ValueError):
    """A configuration key is unknown or its value is invalid."""


def _key(default: Any, doc: str) -> Any:
    """A configuration key: its default and its description (the comment of config/sac_default.yaml)."""
    return field(default=default, metadata={"doc": doc})


@dataclass
class SACConfig:
    """Soft Actor-Critic hyperparameters (defaults: the authors' agent, docs/ARCHITECTURE.md#constants)."""

    hidden_sizes: tuple[int, ...] = _key((1024, 1024), "MLP widths of the actor and of each of the twin critics")
    actor_lr: float = _key(1e-3, "Adam learning rate of the actor")
    critic_lr: float = _key(1e-3, "Adam learning rate of the twin critics")
    alpha_lr: float = _key(1e-4, "temperature (entropy coefficient) learning rate")
    alpha_betas: tuple[float, float] = _key((0.5, 0.999), "Adam betas of the temperature")
    initial_alpha: float = _key(0.1, "initial temperature")
    autotune_alpha: bool = _key(True, "automatic entropy tuning")
    target_entropy: Optional[float] = _key(None, "null: -|A|")
    gamma: float = _key(0.99, "discount factor")
    tau: float = _key(0.01, "polyak factor of the target critics")
    policy_update_every: int = _key(2, "actor + temperature update every N gradient steps")
    target_update_every: int = _key(2, "target critic (polyak) update every N gradient steps")
    log_std_min: float = _key(-10.0, "lower clip of the actor's log standard deviation")
    log_std_max: float = _key(2.0, "upper clip of the actor's log standard deviation")
    buffer_size: int = _key(100_000, "replay buffer capacity [transitions]")
    batch_size: int = _key(128, "transitions per gradient step")
    learning_starts: int = _key(1000, "uniform random actions and no updates before this env step")
    reward_scale: float = _key(50.0, "rewards are multiplied by this inside the agent")
    observation_scaling: str = _key(
        "running",
        "how observations are scaled before the networks: running (mean/std z-scores updated every step) | frozen "
        "(the same, fixed once learning starts) | bounds (a fixed affine map of the observation bounds onto [-1, 1]) "
        "| none (raw SI values: the authors had none; our SI observations span 1e-3 (y_T, m) to 1 (flags)). "
        'docs/RESULTS.md "Training that holds its level" compares them.',
    )
    cutoff_as_terminal: bool = _key(
        False,
        "true: store horizon cut-offs (truncated, not terminated) as terminal, no bootstrap: the authors' agent's quirk "
        "(docs/FIDELITY.md row 7); false: cut-offs bootstrap",
    )

    def __post_init__(self) -> None:
        _require(
            len(self.hidden_sizes) >= 1 and all(h > 0 for h in self.hidden_sizes),
            "sac.hidden_sizes",
            "a non-empty list of positive ints",
        )
        for name in ("actor_lr", "critic_lr", "alpha_lr", "initial_alpha", "reward_scale"):
            _require(getattr(self, name) > 0, f"sac.{name}", "> 0")
        _require(all(0 <= b < 1 for b in self.alpha_betas), "sac.alpha_betas", "two values in [0, 1)")
        _require(0 < self.gamma <= 1, "sac.gamma", "in (0, 1]")
        _require(0 < self.tau <= 1, "sac.tau", "in (0, 1]")
        for name in ("policy_update_every", "target_update_every", "buffer_size", "batch_size"):
            _require(getattr(self, name) >= 1, f"sac.{name}", ">= 1")
        _require(self.learning_starts >= 0, "sac.learning_starts", ">= 0")
        _require(self.log_std_min < self.log_std_max, "sac.log_std_min", "< sac.log_std_max")
        _require(
            self.observation_scaling in OBSERVATION_SCALINGS,
            "sac.observation_scaling",
            f"one of {', '.join(OBSERVATION_SCALINGS)}",
        )


OBSERVATION_SCALINGS = ("running", "frozen", "bounds", "none")


@dataclass
class TrainConfig:
    """Training and evaluation protocol (defaults: the paper's)."""

    total_steps: int = _key(50_000, "env steps of the run")
    eval_every: int = _key(200, "env steps between evaluations")
    eval_episodes: int = _key(10, "seeded episodes per evaluation, deterministic actions")
    eval_seed: int = _key(
        1_000_000,
        "evaluations draw fresh episodes: evaluation k of run seed s uses seeds eval_seed + 100000 s + 10 k + (0..9), "
        "never reused (dlo_policy.train)",
    )
    test_episodes: int = _key(100, "held-out test of the best evaluation's policy after training (test.json)")
    test_seed: int = _key(5_000, "held-out test seeds test_seed .. test_seed + test_episodes - 1")
    eval_without: tuple[str, ...] = _key((), "also evaluate with these modalities blanked (ablation), e.g. [T, V]")
    checkpoint_every: int = _key(
        0, "env steps between full checkpoints (replay buffer included); 0: a tenth of the run, between 100 and 5,000"
    )
    num_threads: int = _key(0, "torch threads; 0: every core this process may use")
    progress: bool = _key(True, "tqdm progress bar")
    device: str = _key("auto", "SAC's device: auto (cuda if available), cpu or cuda")
    sim_arch: str = _key("cpu", "the simulator's Taichi backend: cpu or cuda")
    init_from: str = _key(
        "",
        "fine-tuning: a run's checkpoint.pt whose networks, temperature, optimiser states and observation scaling this "
        "run starts from (its steps, replay buffer and random draws are its own; it acts with that policy from its "
        "first step, without uniform actions); '': a new agent",
    )

    def __post_init__(self) -> None:
        for name in ("total_steps", "eval_every", "eval_episodes", "test_episodes"):
            _require(getattr(self, name) >= 1, f"train.{name}", ">= 1")
        _require(self.checkpoint_every >= 0, "train.checkpoint_every", ">= 0 (0: a tenth of the run)")
        _require(self.num_threads >= 0, "train.num_threads", ">= 0")
        _require(self.device in ("auto", "cpu", "cuda") or self.device.startswith("cuda:"), "train.device", "auto, cpu or cuda")
        _require(self.sim_arch in ("cpu", "cuda"), "train.sim_arch", "cpu or cuda")
        _require(
            self.test_seed >= 0 and self.test_seed + self.test_episodes <= self.eval_seed,
            "train.test_seed",
            "in [0, train.eval_seed - train.test_episodes] (held-out test seeds lie below every evaluation seed)",
        )
        if self.eval_without:
            check_modalities("+".join(self.eval_without), "train.eval_without")


def check_modalities(modalities: str, key: str = "modalities") -> tuple[str, ...]:
    """The modalities of `modalities` ('All', 'T+K', ...) in observation order, or a ConfigError."""
    from .observation import parse_modalities  # noqa: PLC0415 (it imports the perception stack: only when needed)

    try:
        return parse_modalities(modalities)
    except ValueError as error:
        raise ConfigError(f"{key}: {error}") from error


@dataclass
class RunConfig:
    """One training run: what to train on, the agent, and the protocol."""

    modalities: str = _key("All", "All, or a '+'-joined subset of K (kinematic), T (tactile), V (visual)")
    seed: int = _key(0, "network init, exploration and training-episode seeds")
    label: str = _key("", "experiment name dlo-report groups seeds by ('': the modalities)")
    env_module: str = _key("dlo_policy.env", "provides make_env(modalities, seed, **env_options) and make_vec_env(num_envs, ...)")
    env_options: dict[str, Any] = field(default_factory=dict, metadata={"doc": "passed to make_env / make_vec_env"})
    sac: SACConfig = field(default_factory=SACConfig)
    train: TrainConfig = field(default_factory=TrainConfig)

    def __post_init__(self) -> None:
        _require(self.seed >= 0, "seed", ">= 0")
        present = check_modalities(self.modalities)
        for removed in self.train.eval_without:
            _require(removed in present, "train.eval_without", f"modalities that the run observes ({self.modalities})")

    @property
    def name(self) -> str:
        return self.label or self.modalities

    def to_dict(self) -> dict[str, Any]:
        """Plain YAML-safe dict (tuples as lists)."""
        return _plain(dataclasses.asdict(self))

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "RunConfig":
        return _build(cls, data, prefix="")


def env_module(config: RunConfig) -> Any:
    """The run's env module (`config.env_module`), imported: it provides make_env(modalities, seed, **options),
    make_vec_env(num_envs, modalities, seed, **options) and optionally check_options(options)."""
    import importlib  # noqa: PLC0415 (the env module imports the simulator: only when asked)

    return importlib.import_module(config.env_module)


TRAINING_ONLY = ("randomise", "randomise_draw")  # env options only a training env gets (domain randomisation)


def make_env(config: RunConfig, num_envs: Optional[int] = None, seed: Optional[int] = None, training: bool = False) -> Any:
    """The run's environment (its env module, modalities and options): one env, or with `num_envs` a
    vector env; seeded with `seed` (default: the run's seed). Without `training` the options of
    TRAINING_ONLY are left out: every evaluation, test and robustness point of a run trained with
    `env_options.randomise` (and `randomise_draw`) runs on the task without it."""
    module = env_module(config)
    seed = config.seed if seed is None else seed
    options = {k: v for k, v in config.env_options.items() if training or k not in TRAINING_ONLY}
    if num_envs is None:
        return module.make_env(modalities=config.modalities, seed=seed, **options)
    return module.make_vec_env(num_envs, modalities=config.modalities, seed=seed, **options)


def check_env_options(config: RunConfig) -> None:
    """ConfigError for env_options the run's env module rejects (its `check_options`, if it has one)."""
    try:
        module = env_module(config)
    except ImportError as error:
        raise ConfigError(f"env_module: cannot import {config.env_module!r} ({error})") from None
    check = getattr(module, "check_options", None)
    if check is not None:
        try:
            check(config.env_options)
        except ValueError as error:
            raise ConfigError(f"env_options: {error}") from None


CABLE_ENV = "dlo_policy.env"  # the env module whose options include task_rules


def record_task_rules(config: RunConfig, rules: str) -> RunConfig:
    """``config`` with ``env_options.task_rules`` set to ``rules`` if the cable env's options do not name
    them: a new run records the default it trains on (so that a later change of the default never
    changes what its config means); a run directory from before the option existed reads as the
    rules it was trained on (``dlo_interface.task.LEGACY_TASK_RULES``)."""
    if config.env_module == CABLE_ENV and "task_rules" not in config.env_options:
        config.env_options = {**config.env_options, "task_rules": rules}
    return config


def _yaml(text: str, what: str) -> Any:
    """yaml.safe_load(text), or a one-line ConfigError naming `what` and where the YAML breaks."""
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as error:
        found = yaml_problem(error, text)
        where = "" if found.line is None else f" (line {found.line}, column {found.column})"
        raise ConfigError(f"{what}: not valid YAML{where}: {found.problem}") from None


def load_config(
    path: Optional[str | Path] = None,
    overrides: typing.Sequence[str] = (),
    values: Optional[typing.Mapping[str, Any]] = None,
    presets: Optional[typing.Mapping[str, Any]] = None,
) -> RunConfig:
    """Defaults, then the YAML file (if any), then `presets` (dotted key -> Python value: what the overrides may
    change, e.g. an experiment group's env_options), then `key=value` overrides (values parsed as YAML), then
    `values` (dotted key -> Python value)."""
    data: dict[str, Any] = {}
    if path is not None:
        loaded = _yaml(Path(path).read_text(), str(path))
        if loaded is not None and not isinstance(loaded, dict):
            raise ConfigError(f"{path}: expected a mapping at the top level")
        data = loaded or {}
    for key, value in (presets or {}).items():
        _set_dotted(data, key, value)
    for override in overrides:
        key, sep, text = override.partition("=")
        if not sep or not key:
            raise ConfigError(f"override {override!r}: expected key=value, e.g. sac.batch_size=256")
        _set_dotted(data, key.strip(), _yaml(text, f"override {override!r}") if text.strip() else "")
    for key, value in (values or {}).items():
        _set_dotted(data, key, value)
    return RunConfig.from_dict(data)


def save_config(config: RunConfig, path: str | Path) -> None:
    Path(path).write_text(yaml.safe_dump(config.to_dict(), sort_keys=False))


DEFAULTS_HEADER = """\
dlo-train defaults: the authors' SAC (docs/ARCHITECTURE.md#constants) and the paper's protocol.
Generated by tools/gen_node_configs.py from dlo_policy.config, where each default is declared once: do not edit
here. Copy it and use the copy with `dlo-train --config FILE`; override any key on the command line, e.g.
  dlo-train --out runs/x sac.batch_size=256 train.eval_every=500 env_options.tactile_noise=partial"""


def defaults_yaml() -> str:
    """config/sac_default.yaml: every key of `RunConfig` at its default, its description as a comment."""
    lines = [f"# {line}".rstrip() for line in DEFAULTS_HEADER.splitlines()] + [""]
    lines += _yaml_block(RunConfig(), "")
    for section in ("sac", "train"):
        lines += ["", f"{section}:"] + _yaml_block(getattr(RunConfig(), section), "  ")
    return "\n".join(lines) + "\n"


def _yaml_block(config: Any, indent: str) -> list[str]:
    """The scalar keys of one dataclass, `key: value  # description`, the comments in one column."""
    import textwrap  # noqa: PLC0415

    rows = [
        (f"{indent}{f.name}: {_yaml_value(getattr(config, f.name))}", f.metadata.get("doc", ""))
        for f in dataclasses.fields(config)
        if not dataclasses.is_dataclass(getattr(config, f.name))
    ]
    column = max(len(text) for text, _ in rows) + 2
    lines = []
    for text, doc in rows:
        wrapped = textwrap.wrap(doc, 118 - column) or [""]
        lines.append(f"{text.ljust(column)}# {wrapped[0]}" if doc else text)
        lines += [f"{' ' * column}# {more}" for more in wrapped[1:]]
    return lines


def _yaml_value(value: Any) -> str:
    """One value in YAML flow style, as `load_config` reads it back."""
    text = yaml.safe_dump(_plain(value), default_flow_style=True, width=10_000).strip()
    return text[: -len("...")].strip() if text.endswith("\n...") else text


def _require(condition: bool, key: str, expectation: str) -> None:
    if not condition:
        raise ConfigError(f"{key}: must be {expectation}")


def _set_dotted(data: dict[str, Any], key: str, value: Any) -> None:
    parts = key.split(".")
    node = data
    for part in parts[:-1]:
        child = node.setdefault(part, {})
        if not isinstance(child, dict):
            raise ConfigError(f"override {key}: {part} is not a section")
        node = child
    node[parts[-1]] = value


def _build(cls: type, data: Any, prefix: str) -> Any:
    if not isinstance(data, dict):
        raise ConfigError(f"{prefix.rstrip('.') or 'config'}: expected a mapping, got {data!r}")
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls)}
    unknown = sorted(set(data) - known)
    if unknown:
        raise ConfigError(
            f"unknown key(s) {', '.join(prefix + k for k in unknown)}; known: {', '.join(prefix + k for k in sorted(known))}"
        )
    kwargs = {name: _coerce(value, hints[name], prefix + name) for name, value in data.items()}
    try:
        return cls(**kwargs)
    except TypeError as error:  # a nested dataclass given a bad shape
        raise ConfigError(f"{prefix or 'config'}: {error}") from error


def _coerce(value: Any, annotation: Any, key: str) -> Any:
    """Check `value` against a field's type annotation, converting lists to tuples and ints to floats."""
    if dataclasses.is_dataclass(annotation):
        return _build(annotation, value, key + ".")
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Union:  # Optional[X]
        if value is None:
            return None
        return _coerce(value, next(a for a in args if a is not type(None)), key)
    if origin is tuple:
        return _coerce_tuple(value, args, key)
    if origin is dict:
        if not isinstance(value, dict):
            raise ConfigError(f"{key}: expected a mapping, got {value!r}")
        return dict(value)
    return _coerce_scalar(value, annotation, key)


def _coerce_tuple(value: Any, args: tuple, key: str) -> tuple:
    """A list (or tuple) as ``tuple[X, ...]`` or ``tuple[X, Y, ...]`` of a fixed length, each item checked."""
    if not isinstance(value, (list, tuple)):
        raise ConfigError(f"{key}: expected a list, got {value!r}")
    if len(args) == 2 and args[1] is Ellipsis:
        return tuple(_coerce(v, args[0], key) for v in value)
    if len(value) != len(args):
        raise ConfigError(f"{key}: expected {len(args)} values, got {value!r}")
    return tuple(_coerce(v, a, key) for v, a in zip(value, args))


def _coerce_scalar(value: Any, annotation: Any, key: str) -> Any:
    """``value`` as a bool, int, float (also from YAML's string '1e-3') or str field; any other type as it is."""
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{key}: expected true or false, got {value!r}")
        return value
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{key}: expected an integer, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, str):  # YAML reads 1e-3 (no dot) as a string
            try:
                return float(value)
            except ValueError:
                pass
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        return float(value)
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{key}: expected a string, got {value!r}")
        return value
    return value


def _plain(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    return value
