"""The paper's experiment grid: which runs (configuration label, modalities, env options, ablation
evaluations, seed), their directories under the grid's output (OUT/<label>/seed<k>) and their
configs. No torch and no Ray: dlo-experiments runs the grid, dlo-report names its figures' groups.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Optional, Sequence

from .config import RunConfig, load_config

GROUPS = ("single", "pairs", "ablation", "sensitivity")
TACTILE_NOISE_LEVELS = ("partial", "full")
SENSITIVITY_PAIRS = (("All", "V+K"), ("T+V", "V"))  # (with tactile, same without tactile): with K, without K


@dataclass(frozen=True)
class RunSpec:
    """One training run of the grid."""

    label: str
    modalities: str
    seed: int
    env_options: tuple[tuple[str, Any], ...] = ()
    eval_without: tuple[str, ...] = ()
    groups: tuple[str, ...] = field(default=(), compare=False)

    def directory(self, out_dir: Path) -> Path:
        return out_dir / re.sub(r"[^A-Za-z0-9+\-]+", "_", self.label) / f"seed{self.seed}"


def sensitivity_label(modalities: str, noise: str) -> str:
    return f"{modalities} tactile-{noise}"


def experiment_grid(groups: Sequence[str], seeds: Sequence[int]) -> list[RunSpec]:
    """The runs of `groups`, each configuration once (shared between groups) for every seed."""
    unknown = set(groups) - set(GROUPS)
    if unknown:
        raise ValueError(f"unknown group(s) {sorted(unknown)}; choose from {', '.join(GROUPS)}")
    configs: dict[str, dict[str, Any]] = {}

    def add(group: str, label: str, modalities: str, env_options=(), eval_without=()) -> None:
        entry = configs.setdefault(
            label, {"modalities": modalities, "env_options": tuple(env_options), "eval_without": (), "groups": ()}
        )
        entry["eval_without"] = tuple(sorted(set(entry["eval_without"]) | set(eval_without)))
        entry["groups"] += (group,)

    if "single" in groups:
        for modalities in ("T", "K", "V", "All"):
            add("single", modalities, modalities)
    if "pairs" in groups:
        for modalities in ("T+K", "V+K", "T+V"):
            add("pairs", modalities, modalities)
    if "ablation" in groups:
        add("ablation", "All", "All", eval_without=("T", "V"))
        add("ablation", "V+K", "V+K")  # trained without T
        add("ablation", "T+K", "T+K")  # trained without V
    if "sensitivity" in groups:
        for modalities, no_tactile in SENSITIVITY_PAIRS:
            add("sensitivity", modalities, modalities)  # tactile noise "none" (the env's default)
            for noise in TACTILE_NOISE_LEVELS:
                add("sensitivity", sensitivity_label(modalities, noise), modalities, env_options=(("tactile_noise", noise),))
            add("sensitivity", no_tactile, no_tactile)
    # seed-major: every configuration's first seed before any second one, so a grid that is
    # stopped part-way leaves the same number of finished seeds per configuration (+- 1)
    return [
        RunSpec(label, c["modalities"], seed, c["env_options"], c["eval_without"], c["groups"])
        for seed in seeds
        for label, c in configs.items()
    ]


def run_config(
    spec: RunSpec, config_path: Optional[Path], overrides: Sequence[str], steps: Optional[int], threads: int
) -> RunConfig:
    values: dict[str, Any] = {
        "modalities": spec.modalities,
        "seed": spec.seed,
        "label": spec.label,
        "train.eval_without": list(spec.eval_without),
        "train.num_threads": threads,
        "train.progress": False,
    }
    values.update({f"env_options.{key}": value for key, value in spec.env_options})
    if steps is not None:
        values["train.total_steps"] = steps
    return load_config(config_path, overrides, values)
