"""tools/mutation.toml stays in step with the code it mutates: every module's file and listed tests
exist (a test id names a test function of that file), every hand-made bug's text occurs exactly once
in its module's file, and every equivalent mutant names a listed module. A refactor that moves code
fails here, not hours into a mutation run."""

from __future__ import annotations

import ast
import pathlib
import tomllib

ROOT = pathlib.Path(__file__).resolve().parents[1]
CONFIG = tomllib.loads((ROOT / "tools" / "mutation.toml").read_text())
MODULES = {m["name"]: m for m in CONFIG["module"]}


def test_every_module_file_and_listed_test_exists():
    for module in CONFIG["module"]:
        assert (ROOT / module["file"]).is_file(), module["name"]
        for test in module["tests"]:
            path, _, function = test.partition("::")
            assert (ROOT / path).is_file(), f"{module['name']}: {path}"
            if function:
                names = {
                    node.name for node in ast.walk(ast.parse((ROOT / path).read_text())) if isinstance(node, ast.FunctionDef)
                }
                assert function.split("[")[0] in names, f"{module['name']}: {test}"


def test_every_hand_made_bug_finds_its_text_once():
    for bug in CONFIG["named"]:
        text = (ROOT / MODULES[bug["module"]]["file"]).read_text()
        assert text.count(bug["find"]) == 1, f"{bug['name']}: {bug['find']!r} occurs {text.count(bug['find'])} times"
        assert bug["replace"] != bug["find"], bug["name"]


def test_every_equivalent_mutant_names_a_listed_module():
    for equivalent in CONFIG.get("equivalent", []):
        assert equivalent["module"] in MODULES and equivalent["reason"].strip(), equivalent
