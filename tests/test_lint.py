"""The linter and the formatter, as tests: ruff check (E, F, W, B, import order, McCabe complexity <= 15) and
`ruff format --check` with the committed ruff.toml pass on the whole repository."""

import pathlib
import shutil
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUTSIDE = ("DESIGN" + ".md", "../" + "shared")  # spelled apart: this file names them without citing them


def ruff(*args: str) -> subprocess.CompletedProcess:
    executable = shutil.which("ruff") or str(pathlib.Path(sys.executable).parent / "ruff")
    return subprocess.run(
        [executable, *args, "--config", str(ROOT / "ruff.toml"), str(ROOT)], capture_output=True, text=True, timeout=300, cwd=ROOT
    )


def test_ruff_passes_with_the_committed_config():
    result = ruff("check", "--output-format", "concise")
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def test_the_config_sorts_imports_and_limits_complexity():
    """The selection the tree is kept to: a config that dropped import sorting or the complexity limit would pass
    the test above without checking them."""
    text = (ROOT / "ruff.toml").read_text()
    assert 'select = ["E", "F", "W", "B", "I", "C90"]' in text and "max-complexity = 15" in text


def test_the_tree_is_formatted():
    """`ruff format --check`: every file as `ruff format` writes it (run `ruff format --config ruff.toml FILE`)."""
    result = ruff("format", "--check")
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def test_nothing_in_the_repository_refers_to_files_outside_it():
    """The repository stands alone (docs/ARCHITECTURE.md): no tracked file cites the design notes or the paper copy
    that live beside the development checkout (a user's clone has neither)."""
    tracked = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    offenders = []
    for name in tracked:
        path = ROOT / name
        if path.suffix not in (".py", ".md", ".sh", ".yaml", ".txt", ".cfg", ".xml", ".toml") or not path.is_file():
            continue
        text = path.read_text(errors="replace")
        if any(outside in text for outside in OUTSIDE):
            offenders.append(name)
    assert offenders == [], offenders
