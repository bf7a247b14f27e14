"""Shipped policies by name: policies/<name>/ in the installed share dir or the source tree, picked wherever a
checkpoint is taken as ``shipped`` / ``shipped:NAME`` (dlo-evaluate and dlo-robustness --checkpoint, the policy
node's checkpoint parameter; the launcher's in dlo_bringup's tests), the default unchanged (policies/all), an
unknown name one line listing the shipped ones, and setup.py installing every directory under policies/.
A second policy is a copy of the All policy in a temporary share dir or install prefix."""

import json
import os
import runpy
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from dlo_policy import rundir

SOURCE = Path(rundir.__file__).resolve().parents[1] / rundir.SHIPPED_DIR
PACKAGE = SOURCE.parent


def add_policy(directory: Path, horizon=None) -> Path:
    """A copy of the All policy (policy.pt, config.yaml) in ``directory``; episodes of ``horizon`` steps if given."""
    directory.mkdir(parents=True)
    shutil.copy(SOURCE / "all" / rundir.POLICY_FILE, directory / rundir.POLICY_FILE)
    config = yaml.safe_load((SOURCE / "all" / rundir.CONFIG_FILE).read_text())
    if horizon is not None:
        config["env_options"]["horizon"] = horizon
    (directory / rundir.CONFIG_FILE).write_text(yaml.safe_dump(config))
    return directory / rundir.POLICY_FILE


@pytest.fixture
def installed(monkeypatch, tmp_path):
    """An installed share dir that holds a second shipped policy, all_robust (and not the All one)."""
    import ament_index_python.packages as index

    share = tmp_path / "share"
    robust = add_policy(share / rundir.SHIPPED_DIR / "all_robust")
    monkeypatch.setattr(index, "get_package_share_directory", lambda package: str(share))
    return robust


def test_the_default_is_the_all_policy_whichever_way_it_is_named():
    assert rundir.SHIPPED_POLICY == "policies/all/policy.pt"
    default = rundir.shipped_policy_path()
    assert default.is_file() and default.parent.name == "all" and default == rundir.shipped_policy_path("all")
    for spec in ("", None, "shipped", "shipped:all"):
        assert rundir.checkpoint_path(spec) == default
    assert "all" in rundir.shipped_names()


def test_a_second_policy_is_found_by_name_and_the_all_policy_still_from_the_source_tree(installed):
    assert rundir.shipped_names() == ["all", "all_robust"]
    assert rundir.checkpoint_path("shipped:all_robust") == installed == rundir.shipped_policy_path("all_robust")
    assert rundir.shipped_policy_path() == SOURCE / "all" / rundir.POLICY_FILE  # not in that share dir: the source's
    assert rundir.shipped_name("shipped:all_robust") == "all_robust" and rundir.shipped_name("runs/x/policy.pt") is None


@pytest.mark.parametrize("spec", ["shipped:nope", "shipped:", "shipped:../all", "shipped:all/policy.pt"])
def test_an_unknown_name_is_one_line_listing_the_shipped_ones(installed, spec):
    with pytest.raises(ValueError) as error:
        rundir.checkpoint_path(spec)
    assert str(error.value) == f"no shipped policy {spec.partition(':')[2]!r}; shipped: all, all_robust"


def test_anything_else_is_a_path_as_given():
    for spec in ("runs/x/policy.pt", "shippedx", "./shipped", "other:all"):
        assert rundir.checkpoint_path(spec) == Path(spec)


def test_setup_installs_every_directory_under_policies(tmp_path, monkeypatch):
    import setuptools

    for name in ("all", "all_robust"):
        (tmp_path / "policies" / name).mkdir(parents=True)
        for file in ("policy.pt", "config.yaml", "README.md"):
            (tmp_path / "policies" / name / file).write_text("")
    (tmp_path / "policies" / "notes.txt").write_text("")  # a file beside them: not a policy directory
    shutil.copy(PACKAGE / "setup.py", tmp_path / "setup.py")
    seen = {}
    monkeypatch.setattr(setuptools, "setup", lambda **kwargs: seen.update(kwargs))
    monkeypatch.chdir(tmp_path)
    runpy.run_path("setup.py")
    installs = {target: files for target, files in seen["data_files"] if "/policies" in target}
    assert installs == {
        f"share/dlo_policy/policies/{name}": [f"policies/{name}/{file}" for file in ("README.md", "config.yaml", "policy.pt")]
        for name in ("all", "all_robust")
    }


def test_the_policy_node_takes_a_shipped_name(installed):
    from dlo_common.params import ParameterError
    from dlo_policy.policy_node import load_policy, policy_record

    _, modalities, _ = load_policy("sac", "shipped:all_robust", "All", 0)
    assert list(modalities) == ["K", "T", "V"]
    record = policy_record("sac", "shipped:all_robust", modalities)
    assert record["checkpoint"] == str(installed.resolve()) and record["shipped"] is True
    assert policy_record("sac", "", modalities)["shipped"] is True
    with pytest.raises(ParameterError, match="parameter 'checkpoint': no shipped policy 'nope'; shipped: all, all_robust"):
        load_policy("sac", "shipped:nope", "All", 0)


def test_dlo_robustness_names_a_shipped_policys_envelope_by_it(installed):
    from argparse import Namespace

    from dlo_policy.robustness import _policy_name, _shipped_of

    source = SOURCE / "all" / rundir.POLICY_FILE
    assert _shipped_of(installed) == "all_robust" and _shipped_of(source) == "all"
    assert _policy_name(Namespace(name=None), installed, "all_robust") == "shipped_all_robust"
    assert _policy_name(Namespace(name=None), source, "all") == "shipped"
    assert _shipped_of(Path("/elsewhere/policy.pt")) is None


@pytest.mark.parametrize("command", ["dlo_policy.evaluate", "dlo_policy.robustness"])
def test_an_unknown_shipped_name_on_the_command_line_is_one_line_and_exit_2(command):
    result = subprocess.run(
        [sys.executable, "-m", command, "--checkpoint", "shipped:nope", "--episodes", "1"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2 and result.stdout == "" and "Traceback" not in result.stderr
    assert result.stderr.count("\n") == 1
    assert "argument --checkpoint: no shipped policy 'nope'; shipped: all" in result.stderr


def test_evaluate_and_robustness_run_a_policy_installed_under_a_name(tmp_path):
    """An install prefix (AMENT_PREFIX_PATH) whose dlo_policy share dir holds all_robust, its episodes 4 steps long:
    dlo-evaluate and dlo-robustness take --checkpoint shipped:all_robust; the envelope is shipped_all_robust."""
    prefix = tmp_path / "install"
    (prefix / "share/ament_index/resource_index/packages").mkdir(parents=True)
    (prefix / "share/ament_index/resource_index/packages/dlo_policy").write_text("")
    robust = add_policy(prefix / "share/dlo_policy" / rundir.SHIPPED_DIR / "all_robust", horizon=4)
    env = {**os.environ, "AMENT_PREFIX_PATH": os.pathsep.join(filter(None, [str(prefix), os.environ.get("AMENT_PREFIX_PATH")]))}
    spec = ["--checkpoint", "shipped:all_robust", "--episodes", "2", "--num-envs", "2", "--quiet"]

    def run(*args):
        result = subprocess.run([sys.executable, "-m", *args], capture_output=True, text=True, timeout=300, env=env)
        assert result.returncode == 0, result.stderr[-3000:]
        return result

    run("dlo_policy.evaluate", *spec, "--seed", "3", "--json", tmp_path / "eval.json")
    assert json.loads((tmp_path / "eval.json").read_text())["checkpoint"] == str(robust)
    out = tmp_path / "robustness"
    run("dlo_policy.robustness", *spec, "--family", "velocity_gain", "--grid", "velocity_gain=1.5", "--out", out)
    summary = json.loads((out / "shipped_all_robust" / "robustness.json").read_text())
    assert summary["checkpoint"] == "shipped: dlo_policy/policies/all_robust/policy.pt"
    assert summary["env_options"]["horizon"] == 4  # its own config.yaml, not the All policy's
