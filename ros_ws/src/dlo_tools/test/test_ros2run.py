"""scripts/ros2run finds every console script every ament_python package declares."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))  # --import-mode=importlib

from dlo_tools_testutil import REPO, ROS2RUN  # noqa: E402

SRC = REPO / "ros_ws" / "src"


def declared_executables() -> dict[str, list[str]]:
    """package -> console_scripts names, read from each ros_ws/src/*/setup.py."""
    out: dict[str, list[str]] = {}
    for setup in sorted(SRC.glob("*/setup.py")):
        names: list[str] = []
        for node in ast.walk(ast.parse(setup.read_text())):
            if isinstance(node, ast.Dict):
                for key, value in zip(node.keys, node.values):
                    if isinstance(key, ast.Constant) and key.value == "console_scripts":
                        names += [e.value.split("=")[0].strip() for e in value.elts
                                  if isinstance(e, ast.Constant)]
        out[setup.parent.name] = names
    return out


def run(env, *args):
    return subprocess.run([str(ROS2RUN), *args], env=env, capture_output=True, text=True,
                          timeout=60)


def test_finds_every_declared_executable(ros_env):
    declared = declared_executables()
    assert "recorder_node" in declared["dlo_tools"]
    listing = run(ros_env, "--list")
    assert listing.returncode == 0, listing.stderr
    pairs = set(listing.stdout.split("\n"))
    for pkg, exes in declared.items():
        for exe in exes:
            assert f"{pkg} {exe}" in pairs, (
                f"ros2run cannot find {pkg} {exe}: rebuild with scripts/setup.sh")
            per_pkg = run(ros_env, pkg)
            assert f"{pkg} {exe}" in per_pkg.stdout.split("\n")


def test_runs_with_arguments_and_explains_misses(ros_env):
    res = run(ros_env, "dlo_tools", "dlo-bag-info", "--help")
    assert res.returncode == 0 and "usage: dlo-bag-info" in res.stdout
    res = run(ros_env, "dlo_tools", "no_such_exe")
    assert res.returncode == 1
    assert "no executable 'no_such_exe'" in res.stderr and "recorder_node" in res.stderr
    res = run(ros_env, "no_such_pkg", "x")
    assert res.returncode == 1 and "dlo_tools" in res.stderr


def test_sources_env_sh_when_not_sourced():
    clean = {"PATH": "/usr/bin:/bin", "HOME": "/tmp"}
    res = subprocess.run([str(ROS2RUN), "dlo_tools"], env=clean, capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0, res.stderr
    assert "dlo_tools recorder_node" in res.stdout.split("\n")


def test_list_shows_the_projects_executables_and_all_of_them_with_all(ros_env):
    own = {line.split()[0] for line in run(ros_env, "--list").stdout.splitlines() if line}
    assert own == {pkg for pkg, exes in declared_executables().items() if exes}
    assert not any(p.startswith(("rosidl", "tracetools")) for p in own)
    every = {line.split()[0] for line in run(ros_env, "--list", "--all").stdout.splitlines() if line}
    assert own < every and any(p.startswith("rosidl") for p in every)
    bad = run(ros_env, "--list", "--bogus")
    assert bad.returncode == 2 and "unknown option '--bogus'" in bad.stderr
