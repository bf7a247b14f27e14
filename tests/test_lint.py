"""The linter, as a test: ruff with the committed ruff.toml passes on the whole repository."""

import pathlib
import shutil
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
OUTSIDE = ("DESIGN" + ".md", "../" + "shared")  # spelled apart: this file names them without citing them


def test_ruff_passes_with_the_committed_config():
    ruff = shutil.which("ruff") or str(pathlib.Path(sys.executable).parent / "ruff")
    result = subprocess.run(
        [ruff, "check", "--output-format", "concise", "--config", str(ROOT / "ruff.toml"), str(ROOT)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=ROOT,
    )
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
