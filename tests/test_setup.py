"""scripts/setup.sh is idempotent and fails with a clear message, not a stack trace."""

import os
import pathlib
import subprocess

ROOT = pathlib.Path(__file__).resolve().parents[1]
SETUP = ROOT / "scripts" / "setup.sh"


def run_setup(**env):
    return subprocess.run(["bash", str(SETUP)], capture_output=True, text=True, env={**os.environ, **env}, timeout=1800)


def snapshot(path):
    return {p: p.stat().st_mtime_ns for p in path.rglob("*") if p.is_file()}


def test_second_run_changes_nothing():
    first = run_setup()
    assert first.returncode == 0, first.stderr
    install = ROOT / "ros_ws" / "install"
    before = snapshot(install)
    env_sh = (ROOT / "scripts" / "env.sh").read_text()
    second = run_setup()
    assert second.returncode == 0, second.stderr
    out = second.stdout
    assert "packages up to date" in out and "workspace up to date" in out and "env.sh up to date" in out
    assert "installing" not in out and "building" not in out and "rewriting" not in out
    assert snapshot(install) == before
    assert (ROOT / "scripts" / "env.sh").read_text() == env_sh


def test_missing_python_is_a_clear_error():
    result = run_setup(DLO_PYTHON="python3.11-that-does-not-exist")
    assert result.returncode == 1
    assert "ERROR: no 'python3.11-that-does-not-exist'" in result.stderr
    assert "fix:" in result.stderr and "Traceback" not in result.stderr


def test_wrong_python_version_is_a_clear_error(tmp_path):
    fake = tmp_path / "python3.10"
    fake.write_text("#!/bin/sh\necho 3.10\n")
    fake.chmod(0o755)
    result = run_setup(DLO_PYTHON=str(fake))
    assert result.returncode == 1
    assert "is Python 3.10" in result.stderr and "fix:" in result.stderr


def test_env_sh_works_from_any_directory(tmp_path):
    script = (
        f"source {ROOT / 'scripts' / 'env.sh'} && dlo-bag-info --help >/dev/null && dlo-analyze --help >/dev/null"
        " && ros2run --list >/dev/null && python -c 'import rclpy, dlo_msgs.msg, taichi, torch; print(\"ok\")'"
    )
    result = subprocess.run(
        ["bash", "-c", script],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={
            k: v
            for k, v in os.environ.items()
            if k not in ("PYTHONPATH", "LD_LIBRARY_PATH", "AMENT_PREFIX_PATH", "_ROS_WHEELS_BOOTSTRAP_COMPLETE", "VIRTUAL_ENV")
        },
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().endswith("ok")


def test_a_training_leaves_nothing_in_tmpdir(tmp_path):
    """torch's compile cache (torchinductor_$USER, made by the first optimiser) goes under ~/.cache with the
    other caches, not into TMPDIR: env.sh points TORCHINDUCTOR_CACHE_DIR there."""
    tmp, home = tmp_path / "tmp", tmp_path / "home"
    tmp.mkdir(), home.mkdir()
    script = (
        f"source {ROOT / 'scripts' / 'env.sh'} && python -c 'import torch; "
        'torch.optim.Adam(torch.nn.Linear(2, 2).parameters()); print("ok")\''
    )
    env = {k: v for k, v in os.environ.items() if k not in ("TORCHINDUCTOR_CACHE_DIR", "XDG_CACHE_HOME")}
    result = subprocess.run(
        ["bash", "-c", script], capture_output=True, text=True, env={**env, "TMPDIR": str(tmp), "HOME": str(home)}, timeout=300
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().endswith("ok")
    assert sorted(p.name for p in tmp.iterdir()) == []


def prerequisites_only(tmp_path, headers=True, tools=()):
    """A PATH holding a fake python3.11 (3.11 with venv; Python.h present or not), dirname and ``tools``:
    the set-up's first checks see a machine that lacks what is left out."""
    import shutil

    bin_dir = tmp_path / "bin"
    bin_dir.mkdir(parents=True)
    fake = bin_dir / "python3.11"
    fake.write_text(
        '#!/bin/sh\ncase "$2" in *version_info*) echo 3.11 ;; *Python.h*) exit %d ;; esac\nexit 0\n' % (0 if headers else 1)
    )
    fake.chmod(0o755)
    for tool in ("dirname", *tools):
        (bin_dir / tool).symlink_to(shutil.which(tool))
    return {"PATH": str(bin_dir), "DLO_PYTHON": "python3.11", "DLO_VENV": str(tmp_path / "venv")}


def test_missing_headers_or_compiler_is_a_clear_error(tmp_path):
    """README (The two commands): set-up stops with a one-line reason and a fix when Python 3.11's headers
    or a C/C++ compiler are missing (before it creates or installs anything)."""
    result = subprocess.run(
        ["/bin/bash", str(SETUP)],
        capture_output=True,
        text=True,
        timeout=120,
        env=prerequisites_only(tmp_path / "a", headers=False),
    )
    assert result.returncode == 1 and result.stdout == ""
    assert result.stderr.splitlines() == [
        "[setup] ERROR: Python 3.11 development headers (Python.h) are missing; building dlo_msgs needs them",
        "[setup] fix: install python3.11-dev",
    ]
    for present, missing in (((), "cc"), (("cc",), "c++"), (("cc", "c++"), "make")):
        env = prerequisites_only(tmp_path / missing, tools=present)
        result = subprocess.run(["/bin/bash", str(SETUP)], capture_output=True, text=True, timeout=120, env=env)
        assert result.returncode == 1 and result.stderr.splitlines() == [
            f"[setup] ERROR: no '{missing}' on PATH; building the dlo_msgs interfaces needs a C/C++ toolchain",
            "[setup] fix: install one, e.g. 'apt install build-essential'",
        ], result.stderr
        assert not (tmp_path / missing / "venv").exists()
