"""The code's shape, checked: no import cycle, dependencies pointing one way, node names in one place.

Every import counts, including those inside functions (a lazy import is still a dependency);
only `if TYPE_CHECKING:` blocks are left out. Run `python -m pytest test/test_architecture.py -q`.
"""

import ast
import re
from pathlib import Path

import pytest
from conftest import REPO

from advperc_ros.core.rules.registry import RULES

PACKAGE = REPO / "advperc_ros"


def _module(path: Path) -> str:
    parts = path.relative_to(REPO).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _imports(path: Path) -> set[str]:
    """advperc_ros modules `path` imports (a `from X import y` counts X.y when that is a module)."""
    tree = ast.parse(path.read_text())
    skipped = {id(node) for guard in ast.walk(tree) if isinstance(guard, ast.If)
               and "TYPE_CHECKING" in ast.unparse(guard.test) for node in ast.walk(guard)}
    found = set()
    for node in ast.walk(tree):
        if id(node) in skipped:
            continue
        if isinstance(node, ast.Import):
            found |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found |= {f"{node.module}.{alias.name}" for alias in node.names}
    return {name for name in found if name.startswith("advperc_ros")}


@pytest.fixture(scope="module")
def graph() -> dict[str, set[str]]:
    modules = {_module(path): path for path in PACKAGE.rglob("*.py")}
    return {name: {i for i in _imports(path) if i in modules and i != name} for name, path in modules.items()}


def test_no_import_cycle(graph):
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(module: str) -> None:
        state[module] = 1
        stack.append(module)
        for target in sorted(graph[module]):
            if state.get(target) == 1:
                cycle = stack[stack.index(target):] + [target]
                raise AssertionError("import cycle: " + " -> ".join(cycle))
            if target not in state:
                visit(target)
        stack.pop()
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module)


def _layer(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


@pytest.mark.parametrize("layer, may_import", [
    ("core", {"core", "exceptions"}),
    ("importers", {"core", "importers", "exceptions"}),
    ("ros", {"core", "ros", "exceptions"}),
])
def test_lower_layers_import_only_below_them(graph, layer, may_import):
    for module, targets in graph.items():
        if _layer(module) == layer:
            above = sorted(t for t in targets if _layer(t) not in may_import and t != "advperc_ros")
            assert not above, f"{module} imports {above}"


def test_the_exceptions_module_imports_nothing_of_the_package(graph):
    """Every layer may raise the package's exceptions because that module is a leaf."""
    assert not graph["advperc_ros.exceptions"]


def test_every_exception_the_package_defines_derives_from_one_base():
    from advperc_ros import exceptions

    for path in PACKAGE.rglob("*.py"):
        defined = re.findall(r"^class (\w+)\((?:\w+, )*\w*(?:Error|Exception)\w*\)", path.read_text(), flags=re.M)
        assert path.name == "exceptions.py" or not defined, f"{path} defines {defined}: put them in exceptions.py"
    for name in dir(exceptions):
        kind = getattr(exceptions, name)
        if isinstance(kind, type) and issubclass(kind, BaseException):
            assert issubclass(kind, exceptions.AdvpercError), name


def _exception_names() -> set[str]:
    from advperc_ros import exceptions

    return {name for name, kind in vars(exceptions).items() if isinstance(kind, type) and issubclass(kind, BaseException)}


def _taken_elsewhere(path: Path, exceptions: set[str]) -> list[str]:
    """The package's exceptions `path` takes through a module that is not their home: `from X import
    ParamsError`, or `X.ParamsError` where X is a module of the package it imported."""
    tree = ast.parse(path.read_text())
    modules = {}  # the names bound to a module of the package other than exceptions
    wrong = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("advperc_ros"):
            for alias in node.names:
                if node.module != "advperc_ros.exceptions" and alias.name in exceptions:
                    wrong.append(f"line {node.lineno}: from {node.module} import {alias.name}")
                elif alias.name not in exceptions:
                    modules[alias.asname or alias.name] = f"{node.module}.{alias.name}"
        elif isinstance(node, ast.Import):
            modules.update({alias.asname: alias.name for alias in node.names if alias.asname})
    for node in ast.walk(tree):
        if (isinstance(node, ast.Attribute) and node.attr in exceptions and isinstance(node.value, ast.Name)
                and modules.get(node.value.id, "advperc_ros.exceptions") != "advperc_ros.exceptions"):
            wrong.append(f"line {node.lineno}: {node.value.id}.{node.attr}")
    return wrong


def test_every_exception_is_imported_from_its_home():
    """One name, one place: an exception is taken from advperc_ros.exceptions, never through a module that
    imports it for its own use, so no module keeps an import alive for others' sake (a module's imports
    stay its own business) and reading an import says where the type is defined."""
    exceptions = _exception_names()
    found = {str(path.relative_to(REPO)): wrong for folder in ("advperc_ros", "test", "launch", "benchmarks", "examples")
             for path in sorted((REPO / folder).rglob("*.py")) if (wrong := _taken_elsewhere(path, exceptions))}
    assert not found, f"import these from advperc_ros.exceptions: {found}"


ENTRY_POINTS = {"advperc_ros.cli", "advperc_ros.orchestrator_node", "advperc_ros.launch_plan"}
APPLICATION = ("advperc_ros.application", "advperc_ros.results", "advperc_ros.replay", "advperc_ros.campaign")


def _within(module: str, packages) -> bool:
    return any(module == p or module.startswith(f"{p}.") for p in packages)


def test_nothing_imports_an_entry_point(graph):
    """The CLI and the orchestrator node are the top: nothing imports them."""
    for module, targets in graph.items():
        assert not targets & ENTRY_POINTS, f"{module} imports {sorted(targets & ENTRY_POINTS)}"


@pytest.mark.parametrize("layer, may_not_import", [
    # core <- ros <- graph nodes <- backends <- application <- entry points (cli, orchestrator node)
    ("advperc_ros.nodes", ("advperc_ros.backends", *APPLICATION)),
    ("advperc_ros.backends", APPLICATION),
    ("advperc_ros.params", ("advperc_ros.backends", "advperc_ros.nodes", *APPLICATION)),
])
def test_no_arrow_runs_back_up(graph, layer, may_not_import):
    for module, targets in graph.items():
        if _within(module, (layer,)):
            up = sorted(t for t in targets if _within(t, may_not_import))
            assert not up, f"{module} imports {up}"


RULE_MODULES = tuple(target.partition(":")[0] for target in RULES.values())


@pytest.mark.parametrize("interface, implementations", [
    ("advperc_ros.core.search.method", ("advperc_ros.core.search.paper", "advperc_ros.core.search.guided",
                                        "advperc_ros.core.search.registry")),
    ("advperc_ros.core.search.registry", ("advperc_ros.core.search.paper", "advperc_ros.core.search.guided")),
    ("advperc_ros.core.planners.base", ("advperc_ros.core.planners.idm", "advperc_ros.core.planners.obp",
                                        "advperc_ros.core.planners.registry")),
    ("advperc_ros.core.planners.registry", ("advperc_ros.core.planners.idm", "advperc_ros.core.planners.obp")),
    ("advperc_ros.core.rules.base", (*RULE_MODULES, "advperc_ros.core.rules.registry")),
    ("advperc_ros.core.rules.registry", RULE_MODULES),
    ("advperc_ros.backends.base", ("advperc_ros.backends.embedded", "advperc_ros.backends.graph",
                                   "advperc_ros.backends.resumed", "advperc_ros.backends.registry")),
    ("advperc_ros.backends.registry", ("advperc_ros.backends.embedded", "advperc_ros.backends.graph")),
])
def test_interfaces_and_registries_import_no_implementation(graph, interface, implementations):
    """A plug-in's interface imports none of them, and its registry imports them only when one is
    chosen, so a new one is a module and a registry line and nothing imports back into the registry."""
    wrong = sorted(t for t in graph[interface] if _within(t, implementations))
    assert not wrong, f"{interface} imports {wrong}"


def test_node_executables_are_listed_once(repo):
    """setup.py's console scripts are the orchestrator (advperc_ros.orchestrator_node, an entry point
    like the CLI) and the graph nodes of nodes.graph_nodes, each its module in advperc_ros/nodes/."""
    from advperc_ros.nodes.graph_nodes import SPECS

    listed = re.search(r"^NODES = \(([^)]*)\)", (repo / "setup.py").read_text(), flags=re.M).group(1)
    assert tuple(re.findall(r'"(\w+)"', listed)) == ("orchestrator", *(spec.name for spec in SPECS))
    assert (PACKAGE / "orchestrator_node.py").is_file()
    assert all((PACKAGE / "nodes" / f"{spec.name}.py").is_file() for spec in SPECS)


def test_docs_architecture_names_every_module():
    """docs/architecture.md's Architecture block stays true to the code: every package (as `name/`) and module
    (by name) of advperc_ros is in it, so a new module cannot land undocumented."""
    block = (REPO / "docs" / "architecture.md").read_text().split("\n## Architecture\n")[1].split("\n## ")[0]
    missing = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if "data" in path.relative_to(PACKAGE).parts:
            continue
        if path.name == "__init__.py":
            if path.parent != PACKAGE and f"{path.parent.name}/" not in block:
                missing.append(f"{path.parent.name}/")
        elif not re.search(rf"\b{re.escape(path.stem)}\b", block):
            missing.append(str(path.relative_to(REPO)))
    assert not missing, f"docs/architecture.md does not name: {missing}"


MAX_MODULE_LINES = 500
PACKAGES = ("params", "results", "core/perception_errors", "core/perception_errors/kinds", "core/pem", "core/rules")


def test_the_layout_every_concern_in_its_package_and_no_module_too_long():
    """Where knowledge lives: the params, the output, the error kinds (one module each), the PEM and the rulebook
    are packages of their own, no module outgrows MAX_MODULE_LINES, and the tests mirror the package's folders."""
    assert all((PACKAGE / package / "__init__.py").is_file() for package in PACKAGES)
    too_long = {str(path.relative_to(REPO)): lines for path in PACKAGE.rglob("*.py")
                if (lines := len(path.read_text().splitlines())) > MAX_MODULE_LINES}
    assert not too_long, too_long
    from advperc_ros.core.perception_errors.registry import KINDS

    kinds = {path.stem for path in (PACKAGE / "core" / "perception_errors" / "kinds").glob("*.py")} - {"__init__"}
    assert kinds == {kind.name for kind in KINDS}, "one module per error kind, each registered"
    from advperc_ros.core.rules.registry import RULES

    assert all((PACKAGE / "core" / "rules" / f"{name}.py").is_file() for name in RULES), "one module per rule"
    folders = {path.parent.relative_to(REPO / "test") for path in (REPO / "test").rglob("test_*.py")}
    assert {Path("core"), Path("ros"), Path("backends"), Path("nodes"), Path("campaign"), Path("fuzz"), Path("cli")} <= folders
