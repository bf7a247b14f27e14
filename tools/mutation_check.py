"""Mutation testing of the result- and safety-critical code (issue 14): do the tests notice a bug?

Each mutant is one small, realistic bug (a comparison flipped, an operator swapped, a constant
changed, a guard or a statement removed, a keyword argument dropped, min <-> max, ...) applied to
ONE function of a COPY of the source tree; the module's fast unit tests run against that copy and
the mutant is *killed* when they fail (or hang past the time limit), *survived* when they pass.
The live tree is never written: other work can go on in it meanwhile.

    tools/mutation_check.sh                       # every module of tools/mutation.toml
    tools/mutation_check.sh --module dlo_interface.task --module dlo_interface.command
    tools/mutation_check.sh --list                # the mutants, nothing run
    tools/mutation_check.sh --fresh               # forget earlier verdicts

Configuration: ``tools/mutation.toml`` (modules: file, functions, tests; equivalent mutants with
the reason). Output: one line per module (killed / mutants, score), then every surviving mutant
``file:line  function  original -> mutated``; exit 0 when every module reaches ``target`` (default
0.9) counting equivalent mutants as not killable, else 1. Verdicts are kept in
``$DLO_MUTATION_DIR/verdicts.json`` (default ``/tmp/dlo-mutation``): a mutant killed before is not
run again while its mutated source is byte-identical; survivors always run again.

Speed: a fork server imports numpy, torch, taichi and rclpy once; each mutant runs pytest in a
forked child (``-x``, the module's listed tests only), its own process group, killed at the limit.
Not in CI: it takes minutes to hours (Taichi kernels recompile for every kernel mutant).
"""

from __future__ import annotations

import argparse
import ast
import copy
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("dlo_common", "dlo_interface", "dlo_sim", "dlo_perception", "dlo_policy", "dlo_bag", "dlo_viz", "dlo_driver_kit")
LOG_CALLS = {"debug", "info", "warning", "warn", "error", "fatal", "print", "exception"}

# ---------------------------------------------------------------- mutation operators
COMPARE_SWAP = {
    ast.Lt: ast.LtE,
    ast.LtE: ast.Lt,
    ast.Gt: ast.GtE,
    ast.GtE: ast.Gt,
    ast.Eq: ast.NotEq,
    ast.NotEq: ast.Eq,
    ast.In: ast.NotIn,
    ast.NotIn: ast.In,
    ast.Is: ast.IsNot,
    ast.IsNot: ast.Is,
}
BINOP_SWAP = {
    ast.Add: ast.Sub,
    ast.Sub: ast.Add,
    ast.Mult: ast.Div,
    ast.Div: ast.Mult,
    ast.FloorDiv: ast.Mult,
    ast.Pow: ast.Mult,
    ast.BitAnd: ast.BitOr,
    ast.BitOr: ast.BitAnd,
    ast.Mod: ast.FloorDiv,
}
AUG_SWAP = {
    ast.Add: ast.Sub,
    ast.Sub: ast.Add,
    ast.Mult: ast.Div,
    ast.Div: ast.Mult,
    ast.BitOr: ast.BitAnd,
    ast.BitAnd: ast.BitOr,
}
NAME_SWAP = {
    "min": "max",
    "max": "min",
    "minimum": "maximum",
    "maximum": "minimum",
    "any": "all",
    "all": "any",
    "argmin": "argmax",
    "argmax": "argmin",
    "floor": "ceil",
    "ceil": "floor",
}
UNWRAP = {"abs", "clip"}  # f(x, ...) -> x
KEEP_KEYWORDS = {"dtype"}  # dropping np.asarray(x, dtype=...) is nearly always equivalent on these inputs


@dataclass
class Mutant:
    module: str
    path: str  # relative to ROOT
    function: str
    line: int
    operator: str
    original: str
    mutated: str
    source: str = field(repr=False)  # the whole mutated file
    key: str = ""

    def describe(self) -> str:
        return f"{self.path}:{self.line}  {self.function}  [{self.operator}]  {self.original}  ->  {self.mutated}"


def _short(text: str, width: int = 90) -> str:
    text = " ".join(text.split())
    return text if len(text) <= width else text[: width - 3] + "..."


def _offsets(source: str) -> list[int]:
    starts, total = [], 0
    for line in source.splitlines(keepends=True):
        starts.append(total)
        total += len(line)
    starts.append(total)
    return starts


class _Collector(ast.NodeVisitor):
    """Yields (node, operator, replacement text, description) for one function's body."""

    def __init__(self):
        self.found: list[tuple[ast.AST, str, str, str]] = []

    # nodes never mutated (messages, annotations, docstrings, log calls)
    def visit_JoinedStr(self, node):
        return

    def visit_FunctionDef(self, node):
        body = node.body
        if (
            body
            and isinstance(body[0], ast.Expr)
            and isinstance(body[0].value, ast.Constant)
            and isinstance(body[0].value.value, str)
        ):
            body = body[1:]
        for statement in body:
            self.visit(statement)

    visit_AsyncFunctionDef = visit_FunctionDef

    def visit_Lambda(self, node):
        self.visit(node.body)

    def visit_AnnAssign(self, node):
        if node.value is not None:
            self.visit(node.value)

    def add(self, node, operator, replacement):
        self.found.append((node, operator, replacement))

    def visit_Call(self, node):
        func = node.func
        name = func.attr if isinstance(func, ast.Attribute) else func.id if isinstance(func, ast.Name) else ""
        if name in LOG_CALLS or (
            isinstance(func, ast.Attribute)
            and isinstance(func.value, ast.Call)
            and getattr(func.value.func, "attr", "") == "get_logger"
        ):
            return
        if name in NAME_SWAP:
            new = copy.deepcopy(node)
            if isinstance(new.func, ast.Attribute):
                new.func.attr = NAME_SWAP[name]
            else:
                new.func.id = NAME_SWAP[name]
            self.add(node, "call", ast.unparse(new))
        if name in UNWRAP and node.args and not isinstance(node.args[0], ast.Starred):
            self.add(node, "unwrap", ast.unparse(node.args[0]))
        for i, keyword in enumerate(node.keywords):
            if keyword.arg is not None and keyword.arg not in KEEP_KEYWORDS:
                new = copy.deepcopy(node)
                del new.keywords[i]
                self.add(node, "drop keyword", ast.unparse(new))
        self.generic_visit(node)

    def visit_Compare(self, node):
        for i, op in enumerate(node.ops):
            if type(op) in COMPARE_SWAP:
                new = copy.deepcopy(node)
                new.ops[i] = COMPARE_SWAP[type(op)]()
                self.add(node, "compare", ast.unparse(new))
        self.generic_visit(node)

    def visit_BinOp(self, node):
        if type(node.op) in BINOP_SWAP and not (isinstance(node.left, ast.Constant) and isinstance(node.left.value, str)):
            new = copy.deepcopy(node)
            new.op = BINOP_SWAP[type(node.op)]()
            self.add(node, "arithmetic", ast.unparse(new))
        self.generic_visit(node)

    def visit_BoolOp(self, node):
        new = copy.deepcopy(node)
        new.op = ast.Or() if isinstance(node.op, ast.And) else ast.And()
        self.add(node, "boolean", ast.unparse(new))
        self.generic_visit(node)

    def visit_UnaryOp(self, node):
        if isinstance(node.op, (ast.Not, ast.USub)):
            self.add(node, "unary", ast.unparse(node.operand))
        if not (isinstance(node.op, ast.USub) and isinstance(node.operand, ast.Constant)):
            self.generic_visit(node)

    def visit_Constant(self, node):
        value = node.value
        if isinstance(value, bool):
            self.add(node, "constant", repr(not value))
        elif isinstance(value, int):
            self.add(node, "constant", repr(1 if value == 0 else 0 if value == 1 else value + 1))
        elif isinstance(value, float):
            self.add(node, "constant", repr(1.0 if value == 0.0 else value * 2.0))

    def visit_IfExp(self, node):
        self.add(node, "condition", ast.unparse(node.orelse))
        self.add(node, "condition", ast.unparse(node.body))
        self.generic_visit(node)

    # statements
    def visit_If(self, node):
        self.add(node.test, "branch", "False")
        self.generic_visit(node)

    def visit_While(self, node):
        self.generic_visit(node)

    def visit_Expr(self, node):
        if isinstance(node.value, ast.Call):
            self.visit(node.value)
            if not self._is_log(node.value):
                self.add(node, "delete", "pass")
        else:
            self.generic_visit(node)

    @staticmethod
    def _is_log(call):
        func = call.func
        name = func.attr if isinstance(func, ast.Attribute) else getattr(func, "id", "")
        return name in LOG_CALLS or (
            isinstance(func, ast.Attribute)
            and isinstance(func.value, ast.Call)
            and getattr(func.value.func, "attr", "") == "get_logger"
        )

    def visit_Assign(self, node):
        if all(isinstance(t, (ast.Attribute, ast.Subscript)) for t in node.targets):
            self.add(node, "delete", "pass")
        self.visit(node.value)

    def visit_AugAssign(self, node):
        if type(node.op) in AUG_SWAP:
            new = copy.deepcopy(node)
            new.op = AUG_SWAP[type(node.op)]()
            self.add(node, "arithmetic", ast.unparse(new))
        self.add(node, "delete", "pass")
        self.visit(node.value)


def _functions(tree: ast.Module, wanted: list[str] | None):
    """(qualname, FunctionDef) of the module's functions and methods, filtered by ``wanted``."""
    found = []

    def walk(body, prefix):
        for node in body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + node.name
                found.append((name, node))
            elif isinstance(node, ast.ClassDef):
                walk(node.body, prefix + node.name + ".")

    walk(tree.body, "")
    if not wanted:
        return found
    names = {name for name, _ in found}
    missing = [w for w in wanted if w not in names]
    if missing:
        raise SystemExit(f"mutation_check: {', '.join(missing)} not found in the module (see tools/mutation.toml)")
    return [(name, node) for name, node in found if name in wanted]


def generate(module: str, path: str, functions: list[str] | None) -> list[Mutant]:
    source = (ROOT / path).read_text()
    tree = ast.parse(source)
    starts = _offsets(source)
    mutants, seen = [], set()
    for qualname, function in _functions(tree, functions):
        collector = _Collector()
        collector.visit(function)
        counts: dict[str, int] = {}
        for node, operator, replacement in collector.found:
            begin = starts[node.lineno - 1] + _col(source, starts, node.lineno, node.col_offset)
            end = starts[node.end_lineno - 1] + _col(source, starts, node.end_lineno, node.end_col_offset)
            original = source[begin:end]
            if operator in ("delete",) or isinstance(node, ast.stmt):
                text = replacement
            else:
                text = "(" + replacement + ")"
            mutated = source[:begin] + text + source[end:]
            if mutated == source or mutated in seen:
                continue
            try:
                compile(mutated, path, "exec")
            except SyntaxError:
                continue
            seen.add(mutated)
            label = f"{qualname}|{operator}|{_short(original, 200)}|{_short(replacement, 200)}"
            counts[label] = counts.get(label, 0) + 1
            mutants.append(
                Mutant(
                    module,
                    path,
                    qualname,
                    node.lineno,
                    operator,
                    _short(original),
                    _short(replacement),
                    mutated,
                    key=f"{label}|#{counts[label]}",
                )
            )
    return mutants


def named_mutants(module: str, path: str, entries: list[dict]) -> list[Mutant]:
    """The configuration's [[named]] bugs of this module: an exact text replaced (it must occur once)."""
    source = (ROOT / path).read_text()
    mutants = []
    for entry in entries:
        find, replace = entry["find"], entry["replace"]
        if source.count(find) != 1:
            raise SystemExit(
                f"mutation_check: named bug {entry['name']!r}: its text occurs {source.count(find)} "
                f"times in {path} (must be once): {find!r}"
            )
        begin = source.index(find)
        mutated = source[:begin] + replace + source[begin + len(find) :]
        compile(mutated, path, "exec")
        line = source.count("\n", 0, begin) + 1
        mutants.append(
            Mutant(
                module, path, entry["name"], line, "named", _short(find), _short(replace), mutated, key=f"named|{entry['name']}"
            )
        )
    return mutants


def _col(source: str, starts: list[int], line: int, col: int) -> int:
    """ast column offsets count UTF-8 bytes: convert to characters."""
    text = source[starts[line - 1] : starts[line]]
    return len(text.encode()[:col].decode(errors="ignore"))


# ---------------------------------------------------------------- running
def copy_tree(work: Path) -> None:
    """The source tree, tests and pytest.ini into ``work`` (which mirrors ROOT's layout)."""
    (work / "ros_ws").mkdir(parents=True, exist_ok=True)
    for src, dst in ((ROOT / "ros_ws" / "src", work / "ros_ws" / "src"), (ROOT / "tests", work / "tests")):
        if dst.exists():
            shutil.rmtree(dst)
        shutil.copytree(src, dst, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
    shutil.copy2(ROOT / "pytest.ini", work / "pytest.ini")
    for name in ("scripts", "tools", "benchmarks"):  # the tests run scripts/ros2run and load tools/gen_*.py
        link = work / name
        if not link.exists():
            link.symlink_to(ROOT / name)


def redirect_paths(work: Path) -> None:
    """Point sys.path and PYTHONPATH at the copy's packages instead of the live ones."""
    live = {str(ROOT / "ros_ws" / "src" / p) for p in PACKAGES}
    sys.path[:] = [str(work / "ros_ws" / "src" / Path(p).name) if p in live else p for p in sys.path]
    parts = os.environ.get("PYTHONPATH", "").split(os.pathsep)
    os.environ["PYTHONPATH"] = os.pathsep.join(str(work / "ros_ws" / "src" / Path(p).name) if p in live else p for p in parts)
    for p in PACKAGES:  # even where env.sh was not the one to set it up
        entry = str(work / "ros_ws" / "src" / p)
        if entry not in sys.path:
            sys.path.insert(0, entry)


def preload() -> None:
    """Import the heavy third-party modules once, before forking (not the project's own)."""
    import numpy  # noqa: F401
    import pytest  # noqa: F401

    for name in (
        "_pytest.python",
        "_pytest.fixtures",
        "_pytest.assertion.rewrite",
        "_pytest.runner",
        "_pytest.main",
        "_pytest.terminal",
        "_pytest.capture",
        "_pytest.monkeypatch",
        "_pytest.tmpdir",
        "pytest_timeout",
        "torch",
        "taichi",
        "gymnasium",
        "rclpy",
        "rclpy.node",
        "rosbags.typesys",
        "yaml",
        "scipy",
    ):
        try:
            __import__(name)
        except ImportError:
            pass


def run_tests(work: Path, tests: list[str], timeout: float, log: Path, fork: bool) -> tuple[str, float]:
    """('passed' | 'failed' | 'timeout' | 'error:<rc>', seconds) of pytest on ``tests`` in ``work``."""
    args = [
        *tests,
        "-x",
        "-q",
        "-p",
        "pytest_timeout",
        "-c",
        str(work / "pytest.ini"),
        "--rootdir",
        str(work),
        "-o",
        "addopts=--import-mode=importlib -p no:cacheprovider",
        "--timeout",
        str(int(timeout) + 5),
    ]
    start = time.monotonic()
    if fork:
        pid = os.fork()
        if pid == 0:  # child: its own process group, output to the log, pytest, exit
            rc = 3
            try:
                os.setpgid(0, 0)
                fd = os.open(log, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
                os.dup2(fd, 1)
                os.dup2(fd, 2)
                os.chdir(work)
                import pytest

                rc = int(pytest.main(args))
            except BaseException:  # noqa: BLE001
                import traceback

                traceback.print_exc()
            finally:
                sys.stdout.flush()
                sys.stderr.flush()
                os._exit(rc)
        try:
            os.setpgid(pid, pid)
        except OSError:
            pass
        status = None
        while time.monotonic() - start < timeout:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                break
            time.sleep(0.05)
        else:
            _kill_group(pid)
            os.waitpid(pid, 0)
            return "timeout", time.monotonic() - start
        rc = os.waitstatus_to_exitcode(status)
    else:
        with open(log, "w") as out:
            proc = subprocess.Popen(
                [sys.executable, "-m", "pytest", *args], cwd=work, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
            )
            try:
                rc = proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                _kill_group(proc.pid)
                proc.wait()
                return "timeout", time.monotonic() - start
    seconds = time.monotonic() - start
    if rc == 0:
        return "passed", seconds
    if rc == 1:
        return "failed", seconds
    return f"error:{rc}", seconds


def write_source(path: Path, text: str) -> None:
    """Write a module of the copy and drop its bytecode (a mutant may keep the size and the second)."""
    import importlib.util

    path.write_text(text)
    try:
        os.remove(importlib.util.cache_from_source(str(path)))
    except FileNotFoundError:
        pass


def _kill_group(pid: int) -> None:
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(pid, sig)
        except ProcessLookupError:
            return
        time.sleep(1.0)


# ---------------------------------------------------------------- main
def load_config(path: Path) -> dict:
    config = tomllib.loads(path.read_text())
    for module in config.get("module", []):
        for key in ("name", "file", "tests"):
            if key not in module:
                raise SystemExit(f"mutation_check: {path}: a [[module]] lacks '{key}'")
    return config


def digest(*texts: str) -> str:
    h = hashlib.sha256()
    for t in texts:
        h.update(t.encode())
        h.update(b"\0")
    return h.hexdigest()[:20]


def parse_args(argv: list[str] | None):
    parser = argparse.ArgumentParser(
        prog="mutation_check", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--config", type=Path, default=ROOT / "tools" / "mutation.toml")
    parser.add_argument("--module", action="append", default=[], help="only this module (repeatable)")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    parser.add_argument("--fresh", action="store_true", help="ignore earlier verdicts")
    parser.add_argument("--no-fork", action="store_true", help="a new interpreter per mutant (slower)")
    parser.add_argument("--named-only", action="store_true", help="only the [[named]] bugs (the issue's weaknesses)")
    parser.add_argument("--slow", action="store_true", help="also the modules marked slow = true")
    parser.add_argument("--max", type=int, default=0, help="at most this many mutants per module (0 = all)")
    parser.add_argument("--work", type=Path, default=Path(os.environ.get("DLO_MUTATION_DIR", "/tmp/dlo-mutation")))
    return parser.parse_args(argv)


def unknown_names(args, config: dict) -> str | None:
    """The error line when --module or a [[named]] bug names a module the configuration does not have."""
    unknown = set(args.module) - {m["name"] for m in config["module"]}
    if unknown:
        return f"mutation_check: unknown module(s) {', '.join(sorted(unknown))}"
    unknown_named = {n["module"] for n in config.get("named", [])} - {m["name"] for m in config["module"]}
    if unknown_named:
        return f"mutation_check: [[named]] for unknown module(s) {', '.join(sorted(unknown_named))}"
    return None


def list_mutants(modules: list[dict], plan: dict, equivalent: dict) -> None:
    for m in modules:
        for mutant in plan[m["name"]]:
            tag = "  (equivalent)" if (m["name"], mutant.key) in equivalent else ""
            print(f"{m['name']}: {mutant.describe()}{tag}\n    key = {mutant.key!r}")
    print(f"{sum(len(v) for v in plan.values())} mutants")


def prepare_work(root: Path, work: Path, fork: bool) -> None:
    """The tree copy ``work``, the environment of the test runs (Taichi's cache in ``root``), the fork server."""
    copy_tree(work)
    os.environ.setdefault("TI_OFFLINE_CACHE_FILE_PATH", str(root / "taichi-cache"))
    os.environ["PYTEST_DISABLE_PLUGIN_AUTOLOAD"] = "1"  # only pytest-timeout, loaded by name
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", str(150 + os.getpid() % 50))
    redirect_paths(work)
    if fork:
        preload()


def run_module(m: dict, mutants: list, work: Path, logs: Path, verdicts: dict, verdict_file: Path, fork: bool):
    """Every mutant of one module against its tests: [(mutant, verdict, seconds)], or None when the unmutated
    tests fail. A mutant killed before with the same source keeps its verdict; verdicts are saved as they come."""
    name, rel = m["name"], m["file"]
    target_file = work / rel
    original = (ROOT / rel).read_text()
    tests = list(m["tests"])
    missing = [t for t in tests if not (ROOT / t.split("::")[0]).exists()]
    if missing:
        print(f"{name}: test file(s) missing, skipped: {', '.join(missing)}", flush=True)
        tests = [t for t in tests if t not in missing]
    status, base = run_tests(work, tests, float(m.get("timeout", 1800)), logs / f"{name}.baseline.log", fork)
    if status != "passed":
        print(f"{name}: the unmutated tests do not pass ({status}); see {logs / (name + '.baseline.log')}", flush=True)
        return None
    limit = max(60.0, 4.0 * base + 30.0)
    print(f"{name}: {len(mutants)} mutants, baseline {base:.0f} s, limit {limit:.0f} s each", flush=True)
    outcome = []
    try:
        for i, mutant in enumerate(mutants):
            vkey = f"{name}|{mutant.key}"
            signature = digest(mutant.source)
            known = verdicts.get(vkey)
            if known and known["signature"] == signature and known["verdict"] != "survived":
                outcome.append((mutant, known["verdict"], 0.0))
                continue
            write_source(target_file, mutant.source)
            try:
                status, seconds = run_tests(work, tests, limit, logs / f"{name}.mutant.log", fork)
            finally:
                write_source(target_file, original)
            verdict = {"passed": "survived", "failed": "killed", "timeout": "killed (timeout)"}.get(status, f"killed ({status})")
            outcome.append((mutant, verdict, seconds))
            verdicts[vkey] = {"signature": signature, "verdict": verdict, "describe": mutant.describe()}
            verdict_file.write_text(json.dumps(verdicts, indent=1))
            print(f"  [{i + 1}/{len(mutants)}] {verdict:<16} {seconds:5.0f} s  {mutant.describe()}", flush=True)
    finally:
        write_source(target_file, original)
    return outcome


def report_scores(modules: list[dict], results: dict, equivalent: dict, target: float) -> tuple[bool, list]:
    """The score line of each module: (every module at the target, the surviving mutants: (name, mutant) or,
    when listed as equivalent, (name, mutant, reason))."""
    print("\n=== mutation score per module ===")
    ok = True
    survivors = []
    for m in modules:
        name = m["name"]
        outcome = results.get(name)
        if outcome is None:
            print(f"{name:<34} baseline failed")
            ok = False
            continue
        total = len(outcome)
        killed = sum(1 for _, v, _ in outcome if v.startswith("killed"))
        equiv = [mu for mu, v, _ in outcome if v == "survived" and (name, mu.key) in equivalent]
        alive = [mu for mu, v, _ in outcome if v == "survived" and (name, mu.key) not in equivalent]
        killable = total - len(equiv)
        score = killed / killable if killable else 1.0
        ok &= score >= target
        print(
            f"{name:<34} {killed:4d} / {total:4d} killed, {len(equiv):3d} equivalent, {len(alive):3d} surviving"
            f"  score {score:6.1%}{'' if score >= target else '  BELOW TARGET'}"
        )
        survivors += [(name, mu) for mu in alive]
        survivors += [(name, mu, equivalent[(name, mu.key)]) for mu in equiv]
    return ok, survivors


def report_survivors(results: dict, survivors: list) -> bool:
    """The surviving, named and equivalent mutants; False when a named bug survived."""
    ok = True
    alive = [s for s in survivors if len(s) == 2]
    if alive:
        print("\n=== surviving mutants (no test fails) ===")
        for name, mutant in alive:
            print(f"{name}: {mutant.describe()}\n    key = {mutant.key!r}")
    named_results = [(name, mu, v) for name in results if results[name] for mu, v, _ in results[name] if mu.operator == "named"]
    if named_results:
        print("\n=== named bugs (tools/mutation.toml [[named]]: the weaknesses of issue 14) ===")
        for name, mutant, verdict in named_results:
            print(f"{verdict:<16} {name}: {mutant.function}  ({mutant.path}:{mutant.line})")
            ok &= verdict.startswith("killed")
    equiv = [s for s in survivors if len(s) == 3]
    if equiv:
        print("\n=== equivalent mutants (listed in tools/mutation.toml) ===")
        for name, mutant, reason in equiv:
            print(f"{name}: {mutant.describe()}\n    why: {reason}")
    return ok


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    config = load_config(args.config)
    target = float(config.get("target", 0.9))
    modules = [
        m for m in config["module"] if m["name"] in args.module or (not args.module and (args.slow or not m.get("slow", False)))
    ]
    error = unknown_names(args, config)
    if error:
        print(error, file=sys.stderr)
        return 2
    equivalent = {(e["module"], e["key"]): e["reason"] for e in config.get("equivalent", [])}
    named = config.get("named", [])
    plan = {
        m["name"]: named_mutants(m["name"], m["file"], [n for n in named if n["module"] == m["name"]])
        + generate(m["name"], m["file"], m.get("functions"))
        for m in modules
    }
    for module, key in equivalent:
        if module in plan and key not in {mu.key for mu in plan[module]}:
            print(f"mutation_check: warning: [[equivalent]] of {module} matches no mutant (stale key?): {key}", file=sys.stderr)
    if args.list:
        list_mutants(modules, plan, equivalent)
        return 0

    work = args.work / "tree"
    logs = args.work / "logs"
    logs.mkdir(parents=True, exist_ok=True)
    verdict_file = args.work / "verdicts.json"
    verdicts = {} if args.fresh or not verdict_file.exists() else json.loads(verdict_file.read_text())
    fork = not args.no_fork
    prepare_work(args.work, work, fork)

    results = {}
    for m in modules:
        mutants = plan[m["name"]][: args.max or None]
        if args.named_only:
            mutants = [mu for mu in plan[m["name"]] if mu.operator == "named"]
        results[m["name"]] = run_module(m, mutants, work, logs, verdicts, verdict_file, fork)

    ok, survivors = report_scores(modules, results, equivalent, target)
    ok &= report_survivors(results, survivors)
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
