"""The training defaults live in one place, dlo_policy.config (each key declared once with its default and its
description); config/sac_default.yaml is generated from them (tools/gen_node_configs.py) and states every key and
every value: the file a user copies for `dlo-train --config` trains exactly what `dlo-train` without it trains."""

from dataclasses import asdict
from pathlib import Path

import yaml
from dlo_policy.config import defaults_yaml, load_config

DEFAULTS_FILE = Path(__file__).resolve().parents[1] / "config" / "sac_default.yaml"


def flat(data, prefix=""):
    out = {}
    for key, value in data.items():
        if isinstance(value, dict) and value:
            out.update(flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_the_defaults_file_is_generated_from_the_declarations():
    assert DEFAULTS_FILE.read_text() == defaults_yaml(), "run python tools/gen_node_configs.py"


def test_the_defaults_file_names_every_key_with_the_built_in_value():
    built_in = flat(asdict(load_config(None, [])))
    written = flat(yaml.safe_load(defaults_yaml()))
    assert sorted(written) == sorted(built_in)  # every key, no other
    assert flat(asdict(load_config(DEFAULTS_FILE, []))) == built_in
    for key, value in written.items():  # and the file's own text is the value (no key relies on a default)
        expected = built_in[key]
        assert (list(expected) if isinstance(expected, tuple) else expected) == value, key


def test_every_key_has_its_description_as_its_comment():
    text = defaults_yaml()
    assert all("#" in line for line in text.splitlines() if ":" in line and not line.endswith(":"))
    assert "  tau: 0.01                     # polyak factor of the target critics\n" in text
    assert "  sim_arch: cpu        # the simulator's Taichi backend: cpu or cuda\n" in text
