"""config/sac_default.yaml states the built-in defaults (dlo_policy.config), every key and every value: the file a
user copies for `dlo-train --config` must train exactly what `dlo-train` without it trains."""

from pathlib import Path

import yaml
from dlo_policy.config import load_config

DEFAULTS_FILE = Path(__file__).resolve().parents[1] / "config" / "sac_default.yaml"


def flat(data, prefix=""):
    out = {}
    for key, value in data.items():
        if isinstance(value, dict) and value:
            out.update(flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


def test_the_defaults_file_names_every_key_with_the_built_in_value():
    from dataclasses import asdict

    built_in = flat(asdict(load_config(None, [])))
    written = flat(yaml.safe_load(DEFAULTS_FILE.read_text()))
    assert sorted(written) == sorted(built_in)  # every key, no other
    from_file = flat(asdict(load_config(DEFAULTS_FILE, [])))
    assert from_file == built_in
    for key, value in written.items():  # and the file's own text is the value (no key relies on a default)
        expected = built_in[key]
        assert (list(expected) if isinstance(expected, tuple) else expected) == value, key
