"""The launcher's --checkpoint takes a shipped policy by name (shipped / shipped:NAME, dlo_policy.rundir): the sim
settings come from that policy's config.yaml, the policy node gets the name; an unknown name is one line listing
the shipped policies; no --checkpoint is the shipped All policy, as before. A second shipped policy: a copy of the
All one, trained (its config.yaml says) under other task rules, in a temporary share dir."""

import shutil
from pathlib import Path

import pytest
import yaml
from dlo_bringup.graph import graph_nodes
from dlo_bringup.options import UsageError, parse_args, resolve
from dlo_policy import rundir


@pytest.fixture
def installed(monkeypatch, tmp_path):
    import ament_index_python.packages as index

    source = rundir.shipped_policy_path().parent
    robust = tmp_path / "share" / rundir.SHIPPED_DIR / "all_robust"
    robust.mkdir(parents=True)
    shutil.copy(source / rundir.POLICY_FILE, robust / rundir.POLICY_FILE)
    config = yaml.safe_load((source / rundir.CONFIG_FILE).read_text())
    config["env_options"].update(task_rules="paper_text", single_particle_grip=False)
    (robust / rundir.CONFIG_FILE).write_text(yaml.safe_dump(config))
    monkeypatch.setattr(index, "get_package_share_directory", lambda package: str(tmp_path / "share"))
    return robust / rundir.POLICY_FILE


def policy_parameters(options, tmp_path: Path) -> dict:
    return dict(next(spec for spec in graph_nodes(options, tmp_path) if spec.name == "policy").parameters)


def test_a_shipped_name_gives_its_training_settings_and_goes_to_the_policy_node(installed, tmp_path):
    options = resolve(parse_args(["--checkpoint", "shipped:all_robust"]))
    assert (options.task_rules, options.single_particle_grip) == ("paper_text", "false")
    assert policy_parameters(options, tmp_path)["checkpoint"] == "shipped:all_robust"


def test_the_default_is_still_the_shipped_all_policy(installed, tmp_path):
    for argv in ([], ["--checkpoint", "shipped"], ["--checkpoint", "shipped:all"]):
        options = resolve(parse_args(argv))
        assert (options.task_rules, options.single_particle_grip) == ("authors_code", "true")  # policies/all's training
    assert "checkpoint" not in policy_parameters(resolve(parse_args([])), tmp_path)


def test_an_unknown_name_is_one_line_listing_the_shipped_ones(installed):
    with pytest.raises(UsageError) as error:
        parse_args(["--checkpoint", "shipped:nope"])
    assert str(error.value) == "--checkpoint: no shipped policy 'nope'; shipped: all, all_robust"
