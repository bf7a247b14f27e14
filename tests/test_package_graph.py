"""The ROS 2 package graph of ros_ws/src is clean: every dlo_* import is declared, the graph is a DAG.

For each package, the ``dlo_*`` packages its modules import (any ``import``/``from`` statement,
also inside functions; read with ``ast``, nothing is imported) must be declared in its
``package.xml`` as ``<depend>`` or ``<exec_depend>`` (``<test_depend>`` also counts for its
``test/`` files), and the declared dependencies between the workspace's packages must form a DAG,
so that colcon and rosdep can order a real install. The checker is run on scratch trees too, to
show that it catches an undeclared import and a cycle.

The simulator is a plug-in behind the contract package ``dlo_interface``: no module outside ``dlo_sim`` imports
``dlo_sim`` (``test_nothing_outside_the_simulator_imports_it``), and the contract itself is pure Python.
"""

from __future__ import annotations

import ast
import pathlib
import re
import xml.etree.ElementTree as ET

ROOT = pathlib.Path(__file__).resolve().parents[1]
SRC = ROOT / "ros_ws" / "src"

RUN_TAGS = ("depend", "exec_depend", "build_export_depend")
ALL_TAGS = RUN_TAGS + ("build_depend", "test_depend", "buildtool_depend")


def manifest(package_dir: pathlib.Path) -> tuple[str, dict[str, set[str]]]:
    """(name, {tag: dependency names}) of a package.xml."""
    root = ET.parse(package_dir / "package.xml").getroot()
    deps = {tag: {e.text.strip() for e in root.findall(tag) if e.text} for tag in ALL_TAGS}
    return root.findtext("name").strip(), deps


def imported_packages(path: pathlib.Path, tree: ast.AST | None = None) -> set[str]:
    """Top-level names of the absolute imports in one Python file (``tree``: its parsed module, if parsed already)."""
    names = set()
    for node in ast.walk(tree or ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name.split(".")[0] for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def packages(src: pathlib.Path) -> dict[str, tuple[pathlib.Path, dict[str, set[str]]]]:
    found = {}
    for xml in sorted(src.glob("*/package.xml")):
        name, deps = manifest(xml.parent)
        found[name] = (xml.parent, deps)
    return found


def undeclared_imports(src: pathlib.Path) -> list[str]:
    """One line per import of a dlo_* package that the importing package does not declare."""
    pkgs = packages(src)
    problems = []
    for name, (directory, deps) in pkgs.items():
        run = set().union(*(deps[t] for t in RUN_TAGS))
        for path in sorted(directory.rglob("*.py")):
            rel = path.relative_to(directory)
            if rel.parts[0] in ("build", "install", "log") or "__pycache__" in rel.parts:
                continue
            allowed = run | deps["test_depend"] if rel.parts[0] == "test" else run
            for imported in sorted(imported_packages(path)):
                if not imported.startswith("dlo_") or imported == name:
                    continue
                if (path.parent / f"{imported}.py").exists():  # a helper module next to it (test/dlo_bag_testutil.py)
                    continue
                if imported not in pkgs:
                    problems.append(f"{name}/{rel}: imports {imported}, which is no package of {src}")
                elif imported not in allowed:
                    tag = "<test_depend> or <exec_depend>" if rel.parts[0] == "test" else "<exec_depend>"
                    problems.append(
                        f"{name}/{rel}: imports {imported}, not declared in {name}/package.xml (add {tag}{imported}</...>)"
                    )
    return problems


def dependency_cycle(src: pathlib.Path) -> list[str]:
    """A cycle of declared dependencies between the workspace's packages ([] if the graph is a DAG)."""
    pkgs = packages(src)
    graph = {name: sorted(set().union(*deps.values()) & set(pkgs)) for name, (_, deps) in pkgs.items()}
    state: dict[str, int] = {}  # 1 = on the current path, 2 = done
    path: list[str] = []

    def visit(node: str) -> list[str]:
        state[node] = 1
        path.append(node)
        for nxt in graph[node]:
            if state.get(nxt) == 1:
                return path[path.index(nxt) :] + [nxt]
            if nxt not in state:
                cycle = visit(nxt)
                if cycle:
                    return cycle
        path.pop()
        state[node] = 2
        return []

    for node in sorted(graph):
        if node not in state:
            cycle = visit(node)
            if cycle:
                return cycle
    return []


RESOLVERS = ("message_class", "import_message_class")  # resolve a "pkg/msg/Name" type at run time


def interface_packages(path: pathlib.Path) -> tuple[set[str], bool]:
    """(the ROS interface packages -- ``*_msgs``, ``*_interfaces`` -- one Python file imports, whether it calls a
    type resolver of ``RESOLVERS``)."""
    tree = ast.parse(path.read_text(), str(path))
    imported = {n for n in imported_packages(path, tree) if n.endswith(("_msgs", "_interfaces"))}
    resolves = any(
        isinstance(node, ast.Call) and getattr(node.func, "id", getattr(node.func, "attr", "")) in RESOLVERS
        for node in ast.walk(tree)
    )
    return imported, resolves


def registry_message_packages() -> set[str]:
    """The packages of every topic's and service's type in the topic registry."""
    from dlo_common.topics import SERVICES, TOPICS

    return {record.type.split("/")[0] for record in (*TOPICS, *SERVICES)}


def undeclared_message_packages(src: pathlib.Path, registry: set[str]) -> list[str]:
    """One line per message package a package's code uses without declaring it: imported by name, or -- for a
    module that resolves types from the topic registry at run time (a node subscribing to the registry's topics,
    the recorder, the bridge) -- any package of the registry's types."""
    problems = []
    for name, (directory, deps) in packages(src).items():
        run = set().union(*(deps[t] for t in RUN_TAGS))
        for path in sorted(directory.rglob("*.py")):
            rel = path.relative_to(directory)
            if rel.parts[0] in ("build", "install", "log", "test") or "__pycache__" in rel.parts or rel.name == "setup.py":
                continue
            imported, resolves = interface_packages(path)
            needed = imported | (registry if resolves else set())
            for pkg in sorted(needed - run - {name}):
                why = "imports it" if pkg in imported else "resolves the topic registry's types"
                problems.append(f"{name}/{rel}: {why}, {pkg} not declared in {name}/package.xml (add <exec_depend>{pkg}</...>)")
    return problems


def test_every_message_package_is_declared():
    """A real Jazzy install (rosdep, colcon) only has the message packages a package.xml names: every ``*_msgs``
    a module imports, and every package of the topic registry's types where a module resolves them at run time."""
    assert undeclared_message_packages(SRC, registry_message_packages()) == []


def test_message_package_checker_sees_both_kinds_of_use(tmp_path):
    """On scratch packages: an imported message package and a registry resolver, declared or not."""
    src = tmp_path / "src"
    _package(src, "dlo_a", ["std_msgs"], "from std_msgs.msg import String\nfrom sensor_msgs.msg import Image\n")
    _package(src, "dlo_b", ["dlo_common"], "from dlo_common.topics import message_class\nX = message_class('x')\n")
    _package(src, "dlo_c", ["std_msgs", "rosgraph_msgs"], "import dlo_common.topics as t\nX = t.message_class('x')\n")
    resolves = "dlo_b/dlo_b/__init__.py: resolves the topic registry's types"
    assert undeclared_message_packages(src, {"std_msgs", "rosgraph_msgs"}) == [
        "dlo_a/dlo_a/__init__.py: imports it, sensor_msgs not declared in dlo_a/package.xml (add <exec_depend>sensor_msgs</...>)",
        f"{resolves}, rosgraph_msgs not declared in dlo_b/package.xml (add <exec_depend>rosgraph_msgs</...>)",
        f"{resolves}, std_msgs not declared in dlo_b/package.xml (add <exec_depend>std_msgs</...>)",
    ]


def test_every_dlo_import_is_declared():
    assert undeclared_imports(SRC) == []


def test_declared_dependencies_form_a_dag():
    assert dependency_cycle(SRC) == [], " -> ".join(dependency_cycle(SRC))


ROOT_DIRS = ("tests", "tools", "benchmarks")  # besides ros_ws/src/*: where modules live that may not import the simulator
TOOLS = ("dlo_bag", "dlo_viz", "dlo_driver_kit")  # the tool packages, on top of the graph's own packages
# who may depend on a tool package (any tag): dlo_viz serves bags' schemas, the driver kit's tests analyse a bag;
# dlo_bringup starts the graph, the recorder and the Foxglove bridge with it
TOOL_USERS = {"dlo_bag": {"dlo_viz", "dlo_driver_kit", "dlo_bringup"}, "dlo_viz": {"dlo_bringup"}, "dlo_driver_kit": set()}


def test_node_helpers_live_in_the_base_package():
    """dlo_common depends on no other dlo_* package; the node helpers are its, not a tool package's."""
    pkgs = packages(SRC)
    assert "dlo_common" in pkgs
    base_deps = set().union(*pkgs["dlo_common"][1].values())
    assert not {d for d in base_deps if d.startswith("dlo_")}
    assert (SRC / "dlo_common" / "dlo_common" / "node_main.py").exists()
    assert not [t for t in TOOLS if (SRC / t / t / "node_main.py").exists()]


def test_the_tool_packages_sit_on_top_of_the_graph():
    """The expected DAG: dlo_bag (bag I/O, recorder, playback, analysis) and dlo_driver_kit (driver template
    and checker) need only msgs, common, the contract (interface) and perception to run, not the simulator (their
    tests: also dlo_policy, dlo_bag, and the sim node as a process); dlo_viz (live view) needs dlo_bag; no package of
    the graph itself depends on a tool package, and nothing but the launch package dlo_bringup depends on dlo_viz
    or dlo_driver_kit."""
    pkgs = packages(SRC)
    assert set(TOOLS) <= set(pkgs)
    dlo_deps = {name: {d for d in set().union(*deps.values()) if d in pkgs} for name, (_, deps) in pkgs.items()}
    for tool in TOOLS:
        users = {name for name, deps in dlo_deps.items() if tool in deps}
        assert users <= TOOL_USERS[tool], f"{sorted(users - TOOL_USERS[tool])} depend on {tool}"
    core = {"dlo_msgs", "dlo_common", "dlo_interface", "dlo_perception"}
    assert dlo_deps["dlo_bag"] == core | {"dlo_policy"}  # dlo_policy: <test_depend> only (a bag of a policy's run)
    assert "dlo_policy" not in set().union(*(pkgs["dlo_bag"][1][t] for t in RUN_TAGS))
    assert dlo_deps["dlo_driver_kit"] == core | {"dlo_bag", "dlo_sim"}  # <test_depend> only
    assert not {"dlo_bag", "dlo_sim"} & set().union(*(pkgs["dlo_driver_kit"][1][t] for t in RUN_TAGS))
    assert dlo_deps["dlo_viz"] == {"dlo_msgs", "dlo_common", "dlo_bag"}


def test_the_launch_package_sits_on_top_of_everything():
    """dlo_bringup starts the whole graph: it depends on every package whose nodes or functions it uses, and no
    package depends on it (a launch package is the top of the DAG)."""
    pkgs = packages(SRC)
    dlo_deps = {name: {d for d in set().union(*deps.values()) if d in pkgs} for name, (_, deps) in pkgs.items()}
    assert dlo_deps["dlo_bringup"] == set(pkgs) - {"dlo_bringup", "dlo_driver_kit"}
    assert not [name for name, deps in dlo_deps.items() if "dlo_bringup" in deps]


def simulator_imports(path: pathlib.Path) -> list[int]:
    """Lines of one Python file that import dlo_sim: import statements (also inside functions),
    ``importlib.import_module("dlo_sim...")`` / ``__import__`` with a literal name, and ``python -c CODE``
    argument lists whose CODE does."""
    lines = []
    code = re.compile(r"(^|[;\n]\s*)(import|from)\s+dlo_sim\b")
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "dlo_sim" for a in node.names):
            lines.append(node.lineno)
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and (node.module or "").split(".")[0] == "dlo_sim":
            lines.append(node.lineno)
        elif isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) in (
            "import_module",
            "__import__",
        ):
            first = node.args[0] if node.args else None
            if isinstance(first, ast.Constant) and str(first.value).split(".")[0] == "dlo_sim":
                lines.append(node.lineno)
        elif isinstance(node, (ast.List, ast.Tuple)):
            items = [e.value if isinstance(e, ast.Constant) else None for e in node.elts]
            for flag, text in zip(items, items[1:], strict=False):
                if flag == "-c" and isinstance(text, str) and code.search(text):
                    lines.append(node.lineno)
    return sorted(lines)


def modules_outside_the_simulator(root: pathlib.Path = ROOT) -> list[pathlib.Path]:
    """Every Python file of the product (ros_ws/src/*/ but dlo_sim, their tests included), tests/, tools/ and
    benchmarks/."""
    src = root / "ros_ws" / "src"
    files = [p for d in sorted(src.iterdir()) if d.is_dir() and d.name != "dlo_sim" for p in sorted(d.rglob("*.py"))]
    files += [p for name in ROOT_DIRS if (root / name).is_dir() for p in sorted((root / name).rglob("*.py"))]
    files += sorted(root.glob("*.py"))
    skip = {"build", "install", "log", "__pycache__"}
    return [p for p in files if not skip & set(p.relative_to(root).parts)]


def test_nothing_outside_the_simulator_imports_it():
    """The simulator is a plug-in: a driver, perception, the policy (its gym env gets the simulator as a backend,
    ``dlo_interface.simulator``), bag analysis, the launcher, the tools and the benchmarks depend on the contract
    ``dlo_interface``. The rule covers tests/ too: the graph tests start the simulator as a process (``ros2 run
    dlo_sim sim_node``, a package name, not an import) and read the contract for its rules; only the simulator's
    own tests (ros_ws/src/dlo_sim/test) import it. What loads every node by name, as ROS does, names no module in
    code: the generators (each ``*_node`` entry point of the setup.py files: tools/gen_node_configs.py,
    tools/gen_interfaces.py) and the launcher's one-process mode (each node's ``NodeSpec.plugin``, as ROS
    composition loads components)."""
    offenders = [f"{p.relative_to(ROOT)}:{line}" for p in modules_outside_the_simulator() for line in simulator_imports(p)]
    assert offenders == []


def test_the_simulator_import_check_sees_each_kind_of_import(tmp_path):
    """The check on scratch files: an import statement, one inside a function, import_module with a literal name
    and a ``python -c`` string are found; the package's name as a process to run, or the contract, are not."""
    cases = {
        "plain.py": ("from dlo_sim.episode import TaskSim\n", [1]),
        "late.py": ("def f():\n    import dlo_sim.kernels\n", [2]),
        "dynamic.py": ("import importlib\nimportlib.import_module('dlo_sim.rope')\n", [2]),
        "child.py": ("import sys\nARGS = [sys.executable, '-c', 'import os; import dlo_sim.kernels']\n", [2]),
        "process.py": ("CMD = ['ros2', 'run', 'dlo_sim', 'sim_node']\nfrom dlo_interface.task import RULES\n", []),
    }
    for name, (text, lines) in cases.items():
        (tmp_path / name).write_text(text)
        assert simulator_imports(tmp_path / name) == lines, name
    (tmp_path / "ros_ws" / "src" / "dlo_sim" / "dlo_sim").mkdir(parents=True)
    (tmp_path / "ros_ws" / "src" / "dlo_sim" / "dlo_sim" / "rope.py").write_text("import dlo_sim.kernels\n")
    (tmp_path / "ros_ws" / "src" / "dlo_bag" / "dlo_bag").mkdir(parents=True)
    (tmp_path / "ros_ws" / "src" / "dlo_bag" / "dlo_bag" / "video.py").write_text("import dlo_sim\n")
    (tmp_path / "tools").mkdir()
    (tmp_path / "tools" / "gen.py").write_text("from dlo_sim import RopeSim\n")
    found = [str(p.relative_to(tmp_path)) for p in modules_outside_the_simulator(tmp_path) if simulator_imports(p)]
    assert found == ["ros_ws/src/dlo_bag/dlo_bag/video.py", "tools/gen.py", "child.py", "dynamic.py", "late.py", "plain.py"]


def test_the_contract_is_pure_python():
    """dlo_interface depends on no other dlo_* package and its modules import only the standard library, numpy,
    themselves and (inside the functions that build messages) sensor_msgs: no Taichi, no rclpy, no simulator."""
    import sys

    pkgs = packages(SRC)
    assert not {d for d in set().union(*pkgs["dlo_interface"][1].values()) if d.startswith("dlo_")}
    allowed = set(sys.stdlib_module_names) | {"numpy", "dlo_interface", "sensor_msgs"}
    for path in sorted((SRC / "dlo_interface" / "dlo_interface").glob("*.py")):
        assert imported_packages(path) <= allowed, f"{path.name}: {sorted(imported_packages(path) - allowed)}"


def test_every_python_package_is_on_the_environment():
    """scripts/env.sh.in puts every ament_python package's sources and install prefix on the paths."""
    env = (ROOT / "scripts" / "env.sh.in").read_text()
    for name, (directory, _) in packages(SRC).items():
        loops = re.findall(r"for _p in ([\w ]+); do", env)
        assert loops and all(name in loop.split() for loop in loops), f"{name} missing in a loop of env.sh.in"
        if (directory / "setup.py").exists():
            assert f"$_dlo_root/ros_ws/src/{name}:" in env or f'$_dlo_root/ros_ws/src/{name}"' in env, name


def _package(src: pathlib.Path, name: str, depends: list[str], module_source: str = "") -> None:
    directory = src / name
    (directory / name).mkdir(parents=True)
    deps = "".join(f"  <exec_depend>{d}</exec_depend>\n" for d in depends)
    (directory / "package.xml").write_text(
        f'<?xml version="1.0"?>\n<package format="3">\n  <name>{name}</name>\n{deps}</package>\n'
    )
    (directory / name / "__init__.py").write_text(module_source)


def test_checker_finds_an_undeclared_import_and_a_cycle(tmp_path):
    """The old tree's faults, in a scratch copy: the tool package (here dlo_bag) imports dlo_sim without
    declaring it, and dlo_sim depends on it for its node helpers while it needs dlo_sim."""
    src = tmp_path / "src"
    _package(src, "dlo_common", [])
    _package(src, "dlo_sim", ["dlo_common"], "def main():\n    from dlo_common.node_main import run_node\n")
    _package(src, "dlo_bag", ["dlo_common"], "from dlo_sim.task import OUTCOME_NAMES\n")
    assert undeclared_imports(src) == [
        "dlo_bag/dlo_bag/__init__.py: imports dlo_sim, not declared in dlo_bag/package.xml (add <exec_depend>dlo_sim</...>)"
    ]
    assert dependency_cycle(src) == []

    (src / "dlo_bag" / "package.xml").write_text(
        (src / "dlo_bag" / "package.xml").read_text().replace("</package>", "  <exec_depend>dlo_sim</exec_depend>\n</package>")
    )
    assert undeclared_imports(src) == []
    (src / "dlo_sim" / "package.xml").write_text(
        (src / "dlo_sim" / "package.xml").read_text().replace("</package>", "  <exec_depend>dlo_bag</exec_depend>\n</package>")
    )
    assert dependency_cycle(src) in (["dlo_sim", "dlo_bag", "dlo_sim"], ["dlo_bag", "dlo_sim", "dlo_bag"])


def test_checker_on_a_copy_of_the_tree_with_an_undeclared_import(tmp_path):
    """Copy the real manifests and one real module, add an import the manifest lacks: reported."""
    src = tmp_path / "src"
    for name in packages(SRC):
        (src / name).mkdir(parents=True)
        (src / name / "package.xml").write_text((SRC / name / "package.xml").read_text())
    module = src / "dlo_perception" / "dlo_perception" / "tactile_node.py"
    module.parent.mkdir()
    module.write_text(
        (SRC / "dlo_perception" / "dlo_perception" / "tactile_node.py").read_text()
        + "\n\ndef _late():\n    from dlo_bag.reader import read_messages  # noqa\n"
    )
    problems = undeclared_imports(src)
    assert len(problems) == 1 and "imports dlo_bag, not declared in dlo_perception/package.xml" in problems[0]
