"""Soft Actor-Critic (Haarnoja et al. 2018) for continuous actions, lean and readable, CPU or GPU.

Written in the style of CleanRL's sac_continuous_action.py, with an SB3-like surface:
`SAC(obs_dim, action_low, action_high, config, seed)`, `learn(env, total_steps, callback)`,
`predict(obs, deterministic)`, `save(path)`, `SAC.load(path)`.

The update, per gradient step (defaults from the authors' agent: docs/ARCHITECTURE.md#constants):
  critic:  y = s * r + gamma * (1 - done) * (min_j Q'_j(s', a') - alpha * log pi(a'|s')),  a' ~ pi(s')
           minimise sum_j (Q_j(s, a) - y)^2                                     (s = reward scale)
  every `policy_update_every` steps:
    actor: minimise alpha * log pi(a~|s) - min_j Q_j(s, a~),  a~ ~ pi(s) (critic weights frozen)
    alpha: minimise -alpha * (log pi(a~|s) + target_entropy)    (alpha = exp(log_alpha))
  every `target_update_every` steps: Q'_j <- (1 - tau) Q'_j + tau Q_j
Speed (docs/ARCHITECTURE.md#benchmarks): fp32, no critic weight gradients in the actor loss, fused Adam.
Device (`device`: "cpu", "cuda", "auto" = cuda if available): networks, replay buffer, sampling
and normaliser live there; checkpoints are written with CPU tensors and load on either device.
"""

from __future__ import annotations

import contextlib
import copy
import dataclasses
import math
import os
from pathlib import Path
from typing import Any, Callable, Iterator, NamedTuple, Optional, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from .config import SACConfig
from .replay import ReplayBuffer

CHECKPOINT_FORMAT = "dlo_policy.sac/1"


class CheckpointError(ValueError):
    """A checkpoint file is missing or is not a dlo_policy checkpoint (one-line message)."""


def _not_a_policy_file(path: Path, reason: str) -> CheckpointError:
    return CheckpointError(f"not a dlo-vitac policy file: {path} ({reason})")


def _unreadable_reason(path: Path, error: Exception) -> str:
    """Why torch.load could not read ``path``, in a few words (the file's first bytes tell)."""
    with path.open("rb") as f:
        head = f.read(4096)
    if not head:
        return "empty file"
    if head.startswith(b"PK\x03\x04"):
        return "a zip archive torch cannot read: damaged or not a torch file"
    if b"\0" not in head:
        try:
            head.decode("utf-8")
            return "a text file, not a torch checkpoint"
        except UnicodeDecodeError as decode_error:
            if len(head) == 4096 and decode_error.start >= len(head) - 3:  # a character cut by the read
                return "a text file, not a torch checkpoint"
    return f"binary data torch cannot load ({type(error).__name__})"


def resolve_device(device: str | torch.device = "cpu") -> torch.device:
    """ "auto" -> cuda if available else cpu; "cuda" without a CUDA device -> ValueError (one line)."""
    name = str(device)
    if name == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    if name not in ("cpu", "cuda") and not name.startswith("cuda:"):
        raise ValueError(f"device: expected auto, cpu or cuda, got {name!r}")
    if name.startswith("cuda") and not torch.cuda.is_available():
        raise ValueError(
            f"device {name!r} asked for, but torch {torch.__version__} sees no CUDA device here (use device auto or cpu)"
        )
    return torch.device(name)


def read_checkpoint(path: str | Path) -> dict[str, Any]:
    """The state dict of a `SAC.save` / `save_policy` file (weights_only: never unpickles code)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"checkpoint {path} not found" if not path.exists() else f"checkpoint {path} is not a file")
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as error:  # noqa: BLE001 (torch raises many types for foreign bytes: pickle, zip, EOF, ...)
        raise _not_a_policy_file(path, _unreadable_reason(path, error)) from None
    if not isinstance(state, dict) or "format" not in state:
        raise _not_a_policy_file(path, f"a torch file without the {CHECKPOINT_FORMAT} format tag")
    if state["format"] != CHECKPOINT_FORMAT:
        raise _not_a_policy_file(path, f"format {state['format']!r}, expected {CHECKPOINT_FORMAT!r}")
    return state


LOG_SQRT_2PI = 0.5 * math.log(2 * math.pi)


def mlp(in_dim: int, hidden_sizes: tuple[int, ...], out_dim: int) -> nn.Sequential:
    """Linear-ReLU stack with orthogonal weights and zero biases (the authors' init)."""
    layers: list[nn.Module] = []
    for width in hidden_sizes:
        layers += [nn.Linear(in_dim, width), nn.ReLU()]
        in_dim = width
    layers.append(nn.Linear(in_dim, out_dim))
    for layer in layers:
        if isinstance(layer, nn.Linear):
            nn.init.orthogonal_(layer.weight)
            nn.init.zeros_(layer.bias)
    return nn.Sequential(*layers)


class Actor(nn.Module):
    """Tanh-squashed Gaussian policy; actions in [-1, 1]^act_dim."""

    def __init__(self, obs_dim: int, act_dim: int, config: SACConfig):
        super().__init__()
        self.net = mlp(obs_dim, config.hidden_sizes, 2 * act_dim)
        self.log_std_min, self.log_std_max = config.log_std_min, config.log_std_max

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        mean, log_std = self.net(obs).chunk(2, dim=-1)
        # squash log-std into [log_std_min, log_std_max] smoothly (as the authors' agent does)
        log_std = self.log_std_min + 0.5 * (self.log_std_max - self.log_std_min) * (torch.tanh(log_std) + 1)
        return mean, log_std

    def sample(self, obs: torch.Tensor, generator: torch.Generator) -> tuple[torch.Tensor, torch.Tensor]:
        """Reparameterised action a = tanh(mean + std * eps) and its log-probability, shape (B,)."""
        mean, log_std = self(obs)
        eps = torch.randn(mean.shape, generator=generator, device=mean.device)
        pre_tanh = mean + log_std.exp() * eps
        gaussian_log_prob = (-0.5 * eps.pow(2) - log_std - LOG_SQRT_2PI).sum(-1)
        # log|d tanh(x)/dx| = log(1 - tanh(x)^2) = 2 * (log 2 - x - softplus(-2x)), stable for large |x|
        log_det_jacobian = (2 * (math.log(2) - pre_tanh - F.softplus(-2 * pre_tanh))).sum(-1)
        return torch.tanh(pre_tanh), gaussian_log_prob - log_det_jacobian

    def deterministic(self, obs: torch.Tensor) -> torch.Tensor:
        return torch.tanh(self(obs)[0])


class TwinQ(nn.Module):
    """Two independent Q(s, a) networks (clipped double-Q against overestimation)."""

    def __init__(self, obs_dim: int, act_dim: int, config: SACConfig):
        super().__init__()
        self.q1 = mlp(obs_dim + act_dim, config.hidden_sizes, 1)
        self.q2 = mlp(obs_dim + act_dim, config.hidden_sizes, 1)

    def forward(self, obs: torch.Tensor, actions: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat([obs, actions], dim=-1)
        return self.q1(x).squeeze(-1), self.q2(x).squeeze(-1)


class ObservationNormalizer:
    """Maps observations to clipped z-scores (obs - mean) / std.

    `running` (default): mean / variance of every observation stored so far (parallel Welford);
    `frozen`: the same until `freeze()`, fixed after; `bounds`: fixed mean = (low + high) / 2 and
    std = (high - low) / 2, i.e. the observation box onto [-1, 1] (`from_bounds`).
    """

    def __init__(self, obs_dim: int, clip: float = 10.0):
        self.mean = torch.zeros(obs_dim, dtype=torch.float64)  # statistics on the CPU (float64)
        self.var = torch.ones(obs_dim, dtype=torch.float64)
        self.count = 0
        self.clip = clip
        self.frozen = False
        self._applied: Optional[tuple[torch.Tensor, torch.Tensor]] = None  # (mean, std) as used, cached

    @classmethod
    def from_bounds(cls, low: np.ndarray, high: np.ndarray) -> "ObservationNormalizer":
        low, high = (torch.as_tensor(np.asarray(b, dtype=np.float64)) for b in (low, high))
        if not (torch.isfinite(low).all() and torch.isfinite(high).all() and (high > low).all()):
            raise ValueError("observation_scaling=bounds needs finite observation bounds with high > low")
        normalizer = cls(len(low))
        normalizer.mean, normalizer.var = (low + high) / 2, ((high - low) / 2).pow(2)
        normalizer.frozen = True
        normalizer._applied = None
        return normalizer

    def freeze(self) -> None:
        self.frozen = True

    def update(self, obs: np.ndarray) -> None:
        if self.frozen:
            return
        batch = torch.as_tensor(np.atleast_2d(obs), dtype=torch.float64)
        n = batch.shape[0]
        delta = batch.mean(0) - self.mean
        total = self.count + n
        self.mean += delta * n / total
        self.var = (self.var * self.count + batch.var(0, unbiased=False) * n + delta.pow(2) * self.count * n / total) / total
        self.count = total
        self._applied = None

    def __call__(self, obs: torch.Tensor) -> torch.Tensor:
        if self._applied is None or self._applied[0].device != obs.device:
            std = self.var.sqrt().clamp_min(1e-8)
            self._applied = (self.mean.float().to(obs.device), std.float().to(obs.device))
        mean, std = self._applied
        return ((obs - mean) / std).clamp(-self.clip, self.clip)

    def state_dict(self) -> dict:
        return {"mean": self.mean.clone(), "var": self.var.clone(), "count": self.count, "frozen": self.frozen}

    def load_state_dict(self, state: dict) -> None:
        self.mean, self.var, self.count = state["mean"].clone(), state["var"].clone(), state["count"]
        self.frozen = bool(state.get("frozen", False))
        self._applied = None


@contextlib.contextmanager
def frozen(module: nn.Module) -> Iterator[None]:
    """Gradients still flow through `module` to its inputs, but none are computed for its weights."""
    params = list(module.parameters())
    for p in params:
        p.requires_grad_(False)
    try:
        yield
    finally:
        for p in params:
            p.requires_grad_(True)


class StepResult(NamedTuple):
    """What `learn` passes to its callback after every environment step."""

    reward: float
    terminated: bool
    truncated: bool
    info: dict
    losses: dict  # this step's update (critic_loss, actor_loss, alpha_loss); empty before learning_starts


class SAC:
    """The agent: networks, optimisers, temperature, replay buffer, counters and RNG state."""

    def __init__(
        self,
        obs_dim: int,
        action_low: np.ndarray,
        action_high: np.ndarray,
        config: Optional[SACConfig] = None,
        seed: int = 0,
        observation_low: Optional[np.ndarray] = None,
        observation_high: Optional[np.ndarray] = None,
        device: str | torch.device = "cpu",
        modalities: Optional[Sequence[str]] = None,
    ):
        self.config = config = config or SACConfig()
        # The observation's modalities, expanded ("K", "T", "V"): given, or noted from the first env the agent acts
        # on (`note_modalities`); saved with every checkpoint, None when unknown (a checkpoint from before).
        self.modalities: Optional[tuple[str, ...]] = tuple(modalities) if modalities else None
        self.device = resolve_device(device)
        self.obs_dim, self.act_dim = int(obs_dim), len(action_low)
        self.action_low = np.asarray(action_low, dtype=np.float32)
        self.action_high = np.asarray(action_high, dtype=np.float32)
        self.seed = seed
        torch.manual_seed(seed)  # network initialisation (on the CPU: the same weights on every device)
        self.generator = torch.Generator(self.device).manual_seed(seed)  # every later random draw of the agent

        self.actor = Actor(self.obs_dim, self.act_dim, config).to(self.device)
        self.critic = TwinQ(self.obs_dim, self.act_dim, config).to(self.device)
        self.critic_target = copy.deepcopy(self.critic).requires_grad_(False)
        self.actor_optimizer = torch.optim.Adam(self.actor.parameters(), lr=config.actor_lr, fused=True)
        self.critic_optimizer = torch.optim.Adam(self.critic.parameters(), lr=config.critic_lr, fused=True)

        self.target_entropy = -float(self.act_dim) if config.target_entropy is None else config.target_entropy
        self.log_alpha = torch.tensor(math.log(config.initial_alpha), device=self.device, requires_grad=config.autotune_alpha)
        self.alpha_optimizer = torch.optim.Adam([self.log_alpha], lr=config.alpha_lr, betas=config.alpha_betas)

        self.replay = ReplayBuffer(config.buffer_size, self.obs_dim, self.act_dim, self.device)
        if config.observation_scaling == "bounds":
            if observation_low is None or observation_high is None:
                raise ValueError("observation_scaling=bounds: pass observation_low and observation_high")
            self.normalizer: Optional[ObservationNormalizer] = ObservationNormalizer.from_bounds(
                observation_low, observation_high
            )
        elif config.observation_scaling in ("running", "frozen"):
            self.normalizer = ObservationNormalizer(self.obs_dim)
        else:
            self.normalizer = None
        self.num_env_steps = 0
        self.num_updates = 0
        self.num_episodes = 0
        self.uniform_warmup = True  # uniform actions before learning_starts; False: an agent started from another's

    def note_modalities(self, env: Any) -> None:
        """Note the modalities of the observation this agent acts on: the env's ``modalities`` (the dlo_policy
        envs' expanded tuple, e.g. ("K", "T", "V"); an env without them: nothing), so that its checkpoints
        store them. ValueError when the agent already observes other modalities."""
        theirs = getattr(env, "modalities", None)
        if not isinstance(theirs, (tuple, list)) or not all(isinstance(m, str) for m in theirs):
            return
        if self.modalities is None:
            self.modalities = tuple(theirs)
        elif self.modalities != tuple(theirs):
            raise ValueError(f"the agent observes {'+'.join(self.modalities)}, the env gives {'+'.join(theirs)}")

    # ---------------------------------------------------------------- acting
    @property
    def alpha(self) -> float:
        return self.log_alpha.detach().exp().item()

    def _normalize(self, obs: torch.Tensor) -> torch.Tensor:
        return self.normalizer(obs) if self.normalizer is not None else obs

    def _to_env_action(self, action: np.ndarray) -> np.ndarray:
        """[-1, 1] policy action -> the env's action box."""
        return self.action_low + (action + 1.0) * 0.5 * (self.action_high - self.action_low)

    @torch.inference_mode()
    def policy_action(self, obs: np.ndarray, deterministic: bool) -> np.ndarray:
        """The policy's action in [-1, 1] for one observation (obs_dim,) or a batch (N, obs_dim)."""
        obs_t = self._normalize(torch.as_tensor(np.asarray(obs, dtype=np.float32), device=self.device))
        if deterministic:
            return self.actor.deterministic(obs_t).cpu().numpy()
        return self.actor.sample(obs_t, self.generator)[0].cpu().numpy()

    def predict(self, obs: np.ndarray, deterministic: bool = True) -> np.ndarray:
        """Action in the env's action box for one observation or a batch."""
        return self._to_env_action(self.policy_action(obs, deterministic))

    def explore(self, obs: np.ndarray) -> np.ndarray:
        """Training-time action in [-1, 1]: uniform before `learning_starts` (unless the agent started from another
        agent's networks: `initialise_from`), then sampled from pi."""
        if self.uniform_warmup and self.num_env_steps < self.config.learning_starts:
            return (torch.rand(self.act_dim, generator=self.generator, device=self.device) * 2 - 1).cpu().numpy()
        return self.policy_action(obs, deterministic=False)

    def store(self, obs: np.ndarray, action: np.ndarray, reward: float, next_obs: np.ndarray, terminated: bool) -> None:
        if self.normalizer is not None:
            self.normalizer.update(obs)
            if self.config.observation_scaling == "frozen" and self.num_env_steps + 1 >= self.config.learning_starts:
                self.normalizer.freeze()  # statistics of the random-action phase, fixed from the first update on
        self.replay.add(obs, action, reward, next_obs, terminated)

    def stored_terminal(self, terminated: bool, truncated: bool) -> bool:
        """The done flag a transition is stored with: `terminated`, and with `config.cutoff_as_terminal`
        also a cut-off (`truncated`, not terminated), which then does not bootstrap either."""
        return bool(terminated) or (self.config.cutoff_as_terminal and bool(truncated))

    # ---------------------------------------------------------------- learning
    @torch.no_grad()
    def td_target(
        self, rewards: torch.Tensor, next_obs: torch.Tensor, terminated: torch.Tensor, alpha: torch.Tensor
    ) -> torch.Tensor:
        """Soft Bellman target: s * r + gamma * (1 - done) * (min_j Q'_j(s', a') - alpha * log pi(a'|s'))."""
        next_actions, next_log_pi = self.actor.sample(next_obs, self.generator)
        next_q = torch.min(*self.critic_target(next_obs, next_actions)) - alpha * next_log_pi
        return self.config.reward_scale * rewards + self.config.gamma * (1 - terminated) * next_q

    def update(self) -> dict[str, float]:
        """One gradient step on a replay batch; returns the losses computed this step."""
        cfg = self.config
        batch = self.replay.sample(cfg.batch_size, self.generator)
        obs, next_obs = self._normalize(batch.obs), self._normalize(batch.next_obs)
        alpha = self.log_alpha.detach().exp()

        td_target = self.td_target(batch.rewards, next_obs, batch.terminated, alpha)
        q1, q2 = self.critic(obs, batch.actions)
        critic_loss = F.mse_loss(q1, td_target) + F.mse_loss(q2, td_target)
        self.critic_optimizer.zero_grad()
        critic_loss.backward()
        self.critic_optimizer.step()
        self.num_updates += 1
        losses = {"critic_loss": critic_loss.item()}

        if self.num_updates % cfg.policy_update_every == 0:
            actions, log_pi = self.actor.sample(obs, self.generator)
            with frozen(self.critic):
                q = torch.min(*self.critic(obs, actions))
            actor_loss = (alpha * log_pi - q).mean()
            self.actor_optimizer.zero_grad()
            actor_loss.backward()
            self.actor_optimizer.step()
            losses["actor_loss"] = actor_loss.item()
            if cfg.autotune_alpha:
                alpha_loss = -(self.log_alpha.exp() * (log_pi.detach() + self.target_entropy)).mean()
                self.alpha_optimizer.zero_grad()
                alpha_loss.backward()
                self.alpha_optimizer.step()
                losses["alpha_loss"] = alpha_loss.item()

        if self.num_updates % cfg.target_update_every == 0:
            with torch.no_grad():
                torch._foreach_lerp_(list(self.critic_target.parameters()), list(self.critic.parameters()), cfg.tau)
        return losses

    @torch.no_grad()
    def diagnostics(self, batch_size: int = 1024, seed: int = 0) -> dict[str, float]:
        """Health of the learner on a replay batch, drawn with its own generator (the agent's RNG
        stream, hence training, is untouched): temperature alpha; policy entropy estimate
        E[-log pi(a|s)] [nats]; mean min_j Q_j(s, a~) of the policy's actions (reward-scaled
        units); fraction of deterministic action components with |a| > 0.99 (tanh saturation)."""
        nan = float("nan")
        if len(self.replay) == 0:
            return {"alpha": self.alpha, "entropy": nan, "q_value": nan, "saturated": nan}
        generator = torch.Generator().manual_seed(seed)
        batch = self.replay.sample(min(batch_size, len(self.replay)), generator)
        obs = self._normalize(batch.obs)
        actions, log_pi = self.actor.sample(obs, generator)
        q = torch.min(*self.critic(obs, actions))
        deterministic = self.actor.deterministic(obs)
        return {
            "alpha": self.alpha,
            "entropy": float(-log_pi.mean()),
            "q_value": float(q.mean()),
            "saturated": float((deterministic.abs() > 0.99).float().mean()),
        }

    def episode_seed(self, episode: int) -> int:
        """Seed of the run's `episode`-th training episode (reproducible across resumes)."""
        return int(np.random.SeedSequence([self.seed, episode]).generate_state(1)[0])

    def learn(self, env: Any, total_steps: int, callback: Optional[Callable[["SAC", StepResult], bool]] = None) -> "SAC":
        """Interact with a gymnasium env until `num_env_steps == total_steps`, one update per step.

        Continues from the current counters (after `load`, a fresh episode starts). Truncated
        episodes bootstrap (unless `config.cutoff_as_terminal`); terminated ones do not.
        `callback(agent, result)` runs after every step; returning False stops learning.
        """
        self.note_modalities(env)
        obs, _ = env.reset(seed=self.episode_seed(self.num_episodes))
        while self.num_env_steps < total_steps:
            action = self.explore(obs)
            next_obs, reward, terminated, truncated, info = env.step(self._to_env_action(action))
            self.store(obs, action, reward, next_obs, self.stored_terminal(terminated, truncated))
            self.num_env_steps += 1
            losses = self.update() if self.num_env_steps > self.config.learning_starts else {}
            if terminated or truncated:
                self.num_episodes += 1
                obs, _ = env.reset(seed=self.episode_seed(self.num_episodes))
            else:
                obs = next_obs
            if (
                callback is not None
                and callback(self, StepResult(float(reward), bool(terminated), bool(truncated), info, losses)) is False
            ):
                break
        return self

    # ---------------------------------------------------------------- persistence
    def state_dict(self, include_replay: bool = True) -> dict[str, Any]:
        state = {
            "format": CHECKPOINT_FORMAT,
            "config": _plain_config(self.config),
            "obs_dim": self.obs_dim,
            "modalities": list(self.modalities) if self.modalities else None,
            "action_low": torch.from_numpy(self.action_low),
            "action_high": torch.from_numpy(self.action_high),
            "seed": self.seed,
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            "critic_target": self.critic_target.state_dict(),
            "log_alpha": self.log_alpha.detach().clone(),
            "actor_optimizer": self.actor_optimizer.state_dict(),
            "critic_optimizer": self.critic_optimizer.state_dict(),
            "alpha_optimizer": self.alpha_optimizer.state_dict(),
            "normalizer": self.normalizer.state_dict() if self.normalizer is not None else None,
            "counters": {"env_steps": self.num_env_steps, "updates": self.num_updates, "episodes": self.num_episodes},
            "rng": {"agent": self.generator.get_state(), "agent_device": self.device.type, "torch": torch.get_rng_state()},
        }
        if include_replay:
            state["replay"] = self.replay.state_dict()
        return _to_cpu(state) if self.device.type != "cpu" else state

    def save(self, path: str | Path, include_replay: bool = True, extra: Optional[dict[str, Any]] = None) -> None:
        """Write a checkpoint atomically (a reader never sees a half-written file); `extra`: the
        caller's own state (tensors, numbers, strings, dicts), read back by `extra_state`."""
        state = self.state_dict(include_replay)
        if extra is not None:
            state["extra"] = extra
        _atomic_save(state, Path(path))

    @staticmethod
    def extra_state(path: str | Path) -> dict[str, Any]:
        """The `extra` dict saved with a checkpoint ({} if none)."""
        return read_checkpoint(path).get("extra") or {}

    def policy_state(self) -> dict[str, Any]:
        """Actor, normaliser and config only: what acting needs (small enough to ship)."""
        state = self.state_dict(include_replay=False)
        for training_only in ("critic", "critic_target", "actor_optimizer", "critic_optimizer", "alpha_optimizer"):
            del state[training_only]
        return copy.deepcopy(state)

    def save_policy(self, path: str | Path) -> None:
        """`policy_state` to a file, atomically."""
        _atomic_save(self.policy_state(), Path(path))

    @classmethod
    def load(cls, path: str | Path, device: str | torch.device = "cpu") -> "SAC":
        """Rebuild an agent from `save` (everything) or `save_policy` (acting only) on `device`."""
        state = read_checkpoint(path)
        values = state["config"]
        unknown = sorted(set(values) - {field.name for field in dataclasses.fields(SACConfig)})
        if unknown:  # e.g. normalize_observations, a name from before observation_scaling (never released)
            raise _not_a_policy_file(Path(path), f"unknown SAC config key(s) {', '.join(unknown)}")
        config = SACConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})
        if config.observation_scaling == "bounds":  # the map comes from the saved normaliser state
            config = dataclasses.replace(config, observation_scaling="frozen")
        agent = cls(
            state["obs_dim"], state["action_low"].numpy(), state["action_high"].numpy(), config, seed=state["seed"], device=device
        )
        agent.config = dataclasses.replace(agent.config, observation_scaling=values.get("observation_scaling", "running"))
        agent.modalities = tuple(state["modalities"]) if state.get("modalities") else None  # None: from before
        agent.load_state_dict(state)
        return agent

    def initialise_from(self, path: str | Path) -> dict[str, Any]:
        """Fine-tuning: take the networks, target critics, temperature, optimiser states and observation scaling of
        the full checkpoint at ``path`` (a run's checkpoint.pt); this agent's counters, replay buffer, random streams
        and hyperparameters stay its own (the optimisers run at this agent's learning rates), and it acts with the
        policy it took from its first step (``uniform_warmup`` off). ValueError (one line) when the file is a policy
        file without critics or its agent is not this one's shape. Returns what it took: {"env_steps", "seed",
        "modalities"} of the checkpoint."""
        state = read_checkpoint(path)
        if "critic" not in state:
            raise ValueError(f"{path}: a policy file (actor only); fine-tuning needs a run's checkpoint.pt")
        theirs = tuple(state.get("modalities") or ()) or None
        if theirs and self.modalities and theirs != self.modalities:
            raise ValueError(f"{path}: its agent observes {'+'.join(theirs)}, this run {'+'.join(self.modalities)}")
        if int(state["obs_dim"]) != self.obs_dim:
            raise ValueError(f"{path}: its agent takes observations of {state['obs_dim']} entries, this run {self.obs_dim}")
        if not (
            np.array_equal(state["action_low"].numpy(), self.action_low)
            and np.array_equal(state["action_high"].numpy(), self.action_high)
        ):
            raise ValueError(f"{path}: its agent acts in another action box than this run's")
        hidden = tuple(state["config"].get("hidden_sizes", ()))
        if hidden != tuple(self.config.hidden_sizes):
            mine = list(self.config.hidden_sizes)
            raise ValueError(f"{path}: its networks have hidden sizes {list(hidden)}, this run's sac.hidden_sizes {mine}")
        if (state.get("normalizer") is None) != (self.normalizer is None):
            theirs_scaling, mine_scaling = state["config"].get("observation_scaling"), self.config.observation_scaling
            raise ValueError(f"{path}: its observation scaling is {theirs_scaling}, this run's {mine_scaling}")
        self._load_learner(state)
        for optimizer, lr in (
            (self.actor_optimizer, self.config.actor_lr),
            (self.critic_optimizer, self.config.critic_lr),
            (self.alpha_optimizer, self.config.alpha_lr),
        ):
            for group in optimizer.param_groups:
                group["lr"] = lr
        self.alpha_optimizer.param_groups[0]["betas"] = tuple(self.config.alpha_betas)
        self.uniform_warmup = False
        if theirs and self.modalities is None:
            self.modalities = theirs
        return {"env_steps": int(state["counters"]["env_steps"]), "seed": int(state["seed"]), "modalities": theirs}

    def _load_learner(self, state: dict[str, Any]) -> None:
        """The actor, temperature and observation scaling of a saved state, and (a full checkpoint) the critics,
        target critics and optimiser states: what `load_state_dict` and `initialise_from` both take."""
        self.actor.load_state_dict(state["actor"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        if "critic" in state:
            self.critic.load_state_dict(state["critic"])
            self.critic_target.load_state_dict(state["critic_target"])
            self.actor_optimizer.load_state_dict(state["actor_optimizer"])
            self.critic_optimizer.load_state_dict(state["critic_optimizer"])
            self.alpha_optimizer.load_state_dict(state["alpha_optimizer"])
        if self.normalizer is not None:
            self.normalizer.load_state_dict(state["normalizer"])

    def load_state_dict(self, state: dict[str, Any]) -> None:
        self._load_learner(state)
        counters = state["counters"]
        self.num_env_steps, self.num_updates = counters["env_steps"], counters["updates"]
        self.num_episodes = counters["episodes"]
        if state["rng"].get("agent_device", "cpu") == self.device.type:
            self.generator.set_state(state["rng"]["agent"])
        else:  # CPU and CUDA generators have different states: a new, still reproducible stream
            self.generator.manual_seed(int(np.random.SeedSequence([self.seed, self.num_updates]).generate_state(1)[0]))
        torch.set_rng_state(state["rng"]["torch"])
        if "replay" in state:
            self.replay.load_state_dict(state["replay"])


def _to_cpu(value: Any) -> Any:
    """Copy every tensor of a nested state (dicts, lists, tuples) to the CPU."""
    if isinstance(value, torch.Tensor):
        return value.detach().cpu()
    if isinstance(value, dict):
        return {k: _to_cpu(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(_to_cpu(v) for v in value)
    return value


def _atomic_save(state: dict[str, Any], path: Path) -> None:
    tmp = path.with_name(path.name + ".tmp")
    torch.save(state, tmp)
    os.replace(tmp, path)


def _plain_config(config: SACConfig) -> dict[str, Any]:
    return {k: list(v) if isinstance(v, tuple) else v for k, v in vars(config).items()}
