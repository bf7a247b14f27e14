"""A dlo-train run directory: the names of its files, and the small helpers that read and write them.

    config.yaml      the resolved run configuration (dlo_policy.config)
    eval.csv         one row per evaluation and tested input set (EVAL_COLUMNS; dlo_policy.train)
    best.json        {"step", "hold_the_end", "episode_reward"} of the best evaluation so far
    best_policy.pt   that evaluation's policy
    checkpoint.pt    everything, replay buffer included (resume; written every train.checkpoint_every steps)
    policy.pt        the actor only, at the end
    test.json        the held-out test of best_policy.pt (dlo-evaluate's JSON); test_without_X.json:
                     the same with modality X blanked
    done.json        the completion marker, with the run's summary
    init_from.json   with train.init_from only (fine-tuning): the checkpoint the run started from (its path, sha256,
                     step, seed and modalities)
    randomised.csv   with env_options.randomise only: one row per training episode, the magnitudes it ran under
                     (RANDOMISED_COLUMNS, then one column per randomised family; dlo_policy.train)
    tb/              TensorBoard event files
    train.log        stdout and stderr of a run that dlo-experiments started
    .lock            held (flock) by the one process training into the directory; holds its pid

No torch and no Ray here: dlo-report, the dlo-experiments driver and the tools read runs through
this module without loading the learner.
"""

from __future__ import annotations

import contextlib
import csv
import fcntl
import json
import os
from pathlib import Path
from typing import Any, Optional

from dlo_interface.sim_config import SimConfig
from dlo_interface.task import DEFAULT_MOVE_SPACING, LEGACY_TASK_RULES, recorded_task_rules
from dlo_perception.vision_source import DEFAULT_VISION_SOURCE

from .config import RunConfig, load_config, record_task_rules

CONFIG_FILE = "config.yaml"
EVAL_FILE = "eval.csv"
BEST_FILE = "best.json"
BEST_POLICY_FILE = "best_policy.pt"
CHECKPOINT_FILE = "checkpoint.pt"
POLICY_FILE = "policy.pt"
TEST_FILE = "test.json"
TEST_PATTERN = "test*.json"  # test.json and every test_without_X.json
DONE_FILE = "done.json"
RANDOMISED_FILE = "randomised.csv"
INIT_FILE = "init_from.json"
RANDOMISED_COLUMNS = ("step", "episode", "episode_seed")  # then the randomised families, in registry order
TB_DIR = "tb"
LOG_FILE = "train.log"
LOCK_FILE = ".lock"
SHIPPED_DIR = "policies"  # every shipped policy: policies/<name>/ (policy.pt, config.yaml, README.md)
SHIPPED_DEFAULT = "all"  # the one taken when none is named
SHIPPED_POLICY = f"{SHIPPED_DIR}/{SHIPPED_DEFAULT}/{POLICY_FILE}"  # the bundled All policy, its run's config.yaml beside it
SHIPPED_SPEC = "shipped"  # a checkpoint spec "shipped" or "shipped:<name>" names a shipped policy


class RunInUse(RuntimeError):
    """Another process is training into this run directory."""


@contextlib.contextmanager
def lock(run_dir: Path):
    """Hold the run directory for one training process; a second one (a second dlo-train, a second
    dlo-experiments on the same --out) gets RunInUse instead of writing the same files. The kernel
    drops the lock when the holder exits, however it exits, so a killed run leaves nothing to clean."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    fd = os.open(run_dir / LOCK_FILE, os.O_RDWR | os.O_CREAT, 0o644)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
            raise RunInUse(
                f"{run_dir} is in use by another training (pid {holder}): wait for it to end or stop it, then resume"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


# a run's record, a few kB: what dlo-experiments --collect copies (and test*.json)
RECORD_FILES = (CONFIG_FILE, EVAL_FILE, DONE_FILE, BEST_FILE, RANDOMISED_FILE, INIT_FILE)  # (the last two: where they exist)
# what a run on a Ray worker sends back (and test*.json before done.json): never checkpoint.pt (replay buffer)
RESULT_FILES = (CONFIG_FILE, EVAL_FILE, BEST_FILE, RANDOMISED_FILE, INIT_FILE, BEST_POLICY_FILE, POLICY_FILE, LOG_FILE, DONE_FILE)

OUTCOMES = ("hold_the_end", "stop_before", "reach_end_but_drop", "drop_before")  # paper-text rule (dlo_interface.task)
AUTHORS_SUFFIX = "_authors"
OUTCOMES_AUTHORS = tuple(name + AUTHORS_SUFFIX for name in OUTCOMES)  # authors'-code rule (dlo_interface.task)
EVAL_COLUMNS = (
    "step",
    "tested_without",
    "episodes",
    "eval_seed",
    *OUTCOMES,
    *OUTCOMES_AUTHORS,
    "episode_reward",
    "time_at_end",
    "how_far",
    "train_episodes",
    "wall_time_s",
    "alpha",
    "entropy",
    "q_value",
    "saturated",
)


def test_file(without: str = "") -> str:
    """Name of the held-out test's JSON (all inputs, or with one modality blanked)."""
    return f"test_without_{without}.json" if without else TEST_FILE


def test_names(run_dir: Path) -> list[str]:
    """Names of the held-out test JSONs in `run_dir`, sorted."""
    return sorted(path.name for path in Path(run_dir).glob(TEST_PATTERN))


def record_names(run_dir: Path) -> list[str]:
    """The run's record present in `run_dir` (RECORD_FILES, then test*.json): what --collect copies."""
    run_dir = Path(run_dir)
    return [name for name in [*RECORD_FILES, *test_names(run_dir)] if (run_dir / name).is_file()]


def result_names(run_dir: Path) -> list[str]:
    """The result files present in `run_dir` that a remote run sends back, done.json last."""
    run_dir = Path(run_dir)
    names = [*RESULT_FILES[:-1], *test_names(run_dir), DONE_FILE]
    return [name for name in names if (run_dir / name).is_file()]


def is_done(run_dir: Path) -> bool:
    """Whether the run finished (its done.json exists)."""
    return (Path(run_dir) / DONE_FILE).exists()


def run_status(run_dir: Path) -> str:
    """'done' (done.json), 'partial' (a checkpoint to resume from) or 'todo'."""
    if is_done(run_dir):
        return "done"
    return "partial" if (Path(run_dir) / CHECKPOINT_FILE).exists() else "todo"


def read_config(run_dir: Path) -> RunConfig:
    """config.yaml as written (ConfigError, OSError when it cannot be read)."""
    return load_config(Path(run_dir) / CONFIG_FILE)


def read_trained_config(run_dir: Path) -> RunConfig:
    """config.yaml read as the run was trained: a run from before task_rules existed was trained on the
    paper-text rules (dlo_interface.task.LEGACY_TASK_RULES) and reads so."""
    return record_task_rules(read_config(run_dir), LEGACY_TASK_RULES)


def _shipped_roots() -> list[Path]:
    """Where shipped policies lie, first found first: the installed share dir's policies/, the source tree's."""
    roots = []
    try:
        from ament_index_python.packages import get_package_share_directory

        roots.append(Path(get_package_share_directory("dlo_policy")) / SHIPPED_DIR)
    except (ImportError, LookupError):
        pass
    return roots + [Path(__file__).resolve().parents[1] / SHIPPED_DIR]


def shipped_names() -> list[str]:
    """The names of the shipped policies (the directories under policies/ that hold a policy.pt), sorted."""
    return sorted({d.name for root in _shipped_roots() if root.is_dir() for d in root.iterdir() if (d / POLICY_FILE).is_file()})


def shipped_policy_path(name: str = SHIPPED_DEFAULT) -> Path:
    """The shipped policy ``name`` (policies/<name>/policy.pt; default the All policy): installed share dir first,
    then the source tree. ValueError in one line, listing the shipped names, when there is none of that name."""
    if name and "/" not in name and name not in (".", ".."):
        for root in _shipped_roots():
            if (root / name / POLICY_FILE).is_file():
                return root / name / POLICY_FILE
    raise ValueError(f"no shipped policy {name!r}; shipped: {', '.join(shipped_names()) or 'none'}")


def shipped_name(spec) -> Optional[str]:
    """The shipped policy a checkpoint spec names: ``""``/None and ``shipped`` the default, ``shipped:NAME`` NAME;
    None for anything else (a file path)."""
    spec = "" if spec is None else str(spec)
    if spec in ("", SHIPPED_SPEC):
        return SHIPPED_DEFAULT
    prefix, sep, name = spec.partition(":")
    return name if sep and prefix == SHIPPED_SPEC else None


def checkpoint_path(spec) -> Path:
    """A checkpoint as every command and node takes it (``--checkpoint``, the policy node's ``checkpoint``): a
    policy file's path, or ``shipped`` / ``shipped:NAME`` (``""``: the default shipped policy). ValueError in one
    line for an unknown shipped name; a path is returned as given (whether it exists is the caller's check)."""
    name = shipped_name(spec)
    return Path(spec) if name is None else shipped_policy_path(name)


def trained_sim_settings(policy_file: Path) -> Optional[dict[str, Any]]:
    """The simulator settings a policy file (policy.pt, best_policy.pt, checkpoint.pt) learned its task
    under, from its run's config.yaml: ``{"task_rules", "single_particle_grip", "carry_law", "contact_radius",
    "vision_source", "start_pose", "move_spacing"}`` (what the sim and vision nodes must run for the policy to meet the
    task and the observation it was trained on); None when no config.yaml is beside the file.
    ConfigError or OSError when that config.yaml cannot be read."""
    run_dir = Path(policy_file).parent
    if not (run_dir / CONFIG_FILE).exists():
        return None
    options = read_trained_config(run_dir).env_options
    return {
        "task_rules": recorded_task_rules(options.get("task_rules")).name,
        "single_particle_grip": bool(options.get("single_particle_grip", False)),
        "carry_law": options.get("carry_law", SimConfig.carry_law),
        "contact_radius": float(options.get("contact_radius", SimConfig.contact_radius)),
        "vision_source": options.get("vision_source", DEFAULT_VISION_SOURCE),
        "start_pose": options.get("start_pose", SimConfig.start_pose),
        "move_spacing": float(options.get("move_spacing", DEFAULT_MOVE_SPACING)),
    }


def read_eval_rows(run_dir: Path) -> list[dict[str, str]]:
    """eval.csv's rows as text (csv.DictReader)."""
    with (Path(run_dir) / EVAL_FILE).open(newline="") as f:
        return list(csv.DictReader(f))


def read_done(run_dir: Path) -> dict[str, Any]:
    return json.loads((Path(run_dir) / DONE_FILE).read_text())


def write_done(run_dir: Path, summary: dict[str, Any]) -> None:
    _write_json(Path(run_dir) / DONE_FILE, summary, indent=2)


def write_best(run_dir: Path, best: Optional[dict[str, Any]]) -> None:
    """best.json (one line)."""
    _write_json(Path(run_dir) / BEST_FILE, best, indent=None)


def write_test(run_dir: Path, without: str, payload: dict[str, Any]) -> None:
    """test.json, or test_without_X.json for `without` = X."""
    _write_json(Path(run_dir) / test_file(without), payload, indent=2)


def _write_json(path: Path, data: Any, indent: Optional[int]) -> None:
    path.write_text(json.dumps(data, indent=indent) + "\n")


class EvalLog:
    """eval.csv of a run directory: appends rows and keeps only rows up to the checkpoint step on resume."""

    def __init__(self, run_dir: Path, resume_step: Optional[int]):
        self.path = Path(run_dir) / EVAL_FILE
        kept: list[dict[str, str]] = []
        if resume_step is not None and self.path.exists():
            kept = [row for row in read_eval_rows(run_dir) if int(row["step"]) <= resume_step]
        with self.path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=EVAL_COLUMNS)
            writer.writeheader()
            writer.writerows(kept)
        self.wall_time_offset = float(kept[-1]["wall_time_s"]) if kept else 0.0

    def append(self, rows: list[dict[str, Any]]) -> None:
        with self.path.open("a", newline="") as f:
            csv.DictWriter(f, fieldnames=EVAL_COLUMNS).writerows(rows)


class RandomisedLog:
    """randomised.csv of a run trained with env_options.randomise: one row per finished training episode (the env
    step it ended at, its index, its seed, each randomised family's magnitude); on resume only the rows up to the
    checkpoint step are kept (the episodes after it run again, with the same magnitudes)."""

    def __init__(self, run_dir: Path, families: list, resume_step: Optional[int]):
        self.path = Path(run_dir) / RANDOMISED_FILE
        self.columns = [*RANDOMISED_COLUMNS, *families]
        kept: list[dict[str, str]] = []
        if resume_step is not None and self.path.exists():
            with self.path.open(newline="") as f:
                kept = [row for row in csv.DictReader(f) if int(row["step"]) <= resume_step]
        with self.path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=self.columns)
            writer.writeheader()
            writer.writerows(kept)

    def append(self, step: int, episode: int, seed: int, magnitudes: dict) -> None:
        with self.path.open("a", newline="") as f:
            row = {"step": step, "episode": episode, "episode_seed": seed, **magnitudes}
            csv.DictWriter(f, fieldnames=self.columns).writerow(row)
