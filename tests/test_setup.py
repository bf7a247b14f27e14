"""scripts/setup.sh is idempotent and fails with a clear message, not a stack trace."""

import os
import pathlib
import subprocess

ROOT = pathlib.Path(__file__).resolve().parents[1]
SETUP = ROOT / "scripts" / "setup.sh"


def run_setup(**env):
    return subprocess.run(["bash", str(SETUP)], capture_output=True, text=True,
                          env={**os.environ, **env}, timeout=1800)


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
    script = (f"source {ROOT / 'scripts' / 'env.sh'} && dlo-bag-info --help >/dev/null && dlo-analyze --help >/dev/null"
              " && ros2run --list >/dev/null && python -c 'import rclpy, dlo_msgs.msg, taichi, torch; print(\"ok\")'")
    result = subprocess.run(["bash", "-c", script], cwd=tmp_path, capture_output=True, text=True,
                            env={k: v for k, v in os.environ.items()
                                 if k not in ("PYTHONPATH", "LD_LIBRARY_PATH", "AMENT_PREFIX_PATH",
                                              "_ROS_WHEELS_BOOTSTRAP_COMPLETE", "VIRTUAL_ENV")},
                            timeout=300)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip().endswith("ok")
