"""Dependencies point one way: the pipeline's packages import each other without cycles, and the
generic layers (the QD loop, the simulators, the repair) know nothing of the layers above them.

Read from the source (every ``import`` statement, also those inside functions, which are
dependencies too), so a new import that breaks the layering fails here with its file and line.
"""

from __future__ import annotations

import ast
from collections import defaultdict
from collections.abc import Mapping
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "nca_qd"

# The layers that run an experiment: what the generic layers below must never reach into.
# (``calibration`` re-derives the constants they use from runs: a layer above them all.)
EXPERIMENT_LAYERS = {"pipeline", "experiment", "evaluation", "run_dir", "run_pictures", "calibration"}

# unit -> units it must never import (a unit is a top-level module or subpackage of nca_qd)
FORBIDDEN = {
    "interfaces": {"*"},
    "errors": {"*"},
    "qd": {"domains", "scoring", "sim", "repair", "agent"} | EXPERIMENT_LAYERS,
    "sim": {"domains", "scoring", "qd", "repair", "agent"} | EXPERIMENT_LAYERS,
    "repair": {"domains", "scoring", "qd", "sim", "agent"} | EXPERIMENT_LAYERS,
    "scoring": {"domains", "qd", "agent"} | EXPERIMENT_LAYERS,
    "domains": {"agent", "qd"} | EXPERIMENT_LAYERS,
    "layouts": {"domains", "scoring", "qd", "sim", "repair", "agent"} | EXPERIMENT_LAYERS,
    "nca": {"domains", "scoring", "qd", "sim", "repair", "agent"},
    "measures": {"domains", "scoring", "qd", "sim", "repair", "agent"},
}


def _unit(module: str) -> str | None:
    parts = module.split(".")
    if parts[0] != "nca_qd" or len(parts) < 2:
        return None
    return parts[1]


def import_graph() -> dict[str, dict[str, list[str]]]:
    """unit -> imported unit -> ["file:line", ...] over every import in the package."""
    graph: dict[str, dict[str, list[str]]] = defaultdict(lambda: defaultdict(list))
    for path in sorted(PACKAGE.rglob("*.py")):
        rel = path.relative_to(PACKAGE.parent)
        here = _unit(".".join(rel.with_suffix("").parts))
        for node in ast.walk(ast.parse(path.read_text(), str(rel))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            else:
                continue
            for name in names:
                there = _unit(name)
                if here and there and there != here:
                    graph[here][there].append(f"{rel}:{node.lineno}")
    return graph


def outside_imports(package: Path = PACKAGE) -> list[str]:
    """Every import of ``benchmarks`` or ``experiments`` in the package, as "file:line imports x"."""
    found = []
    for path in sorted(package.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names = [a.name for a in node.names] if isinstance(node, ast.Import) else []
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            found += [
                f"{path.relative_to(package.parent)}:{node.lineno} imports {n}"
                for n in names
                if n.split(".")[0] in ("benchmarks", "experiments")
            ]
    return found


def test_the_product_imports_nothing_from_the_benchmarks_or_the_commands():
    """``benchmarks/`` times and reports, ``experiments/`` are entry points: the package needs
    neither (a constant it uses is re-derived by ``nca_qd.calibration``, not by a benchmark)."""
    found = outside_imports()
    assert not found, "; ".join(found)


def test_the_outside_import_check_sees_a_lazy_import(tmp_path):
    pkg = tmp_path / "nca_qd"
    (pkg / "sim").mkdir(parents=True)
    (pkg / "sim" / "fit.py").write_text("def f():\n    from benchmarks.bench_screen import spearman\n")
    (pkg / "ok.py").write_text("import numpy\nfrom nca_qd.sim import fit\n")
    assert outside_imports(pkg) == ["nca_qd/sim/fit.py:2 imports benchmarks.bench_screen"]


def test_the_package_graph_has_no_cycle():
    graph = import_graph()
    found = cycles(graph)
    assert not found, "; ".join(
        "import cycle " + " -> ".join(c) + f" (e.g. {graph[c[-2]][c[-1]][0]})" for c in found
    )


def module_graph(package: Path = PACKAGE) -> dict[str, dict[str, str]]:
    """module -> imported module -> "file:line", over every import of the package's modules
    (``from nca_qd.sim import screen_base`` counts as importing that module)."""

    def name_of(path: Path) -> str:
        parts = list(path.relative_to(package.parent).with_suffix("").parts)
        return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)

    modules = {name_of(p): p for p in package.rglob("*.py")}
    graph: dict[str, dict[str, str]] = defaultdict(dict)
    for here, path in modules.items():
        rel = path.relative_to(package.parent)
        for node in ast.walk(ast.parse(path.read_text(), str(rel))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [f"{node.module}.{a.name}" for a in node.names]
                names = [n if n in modules else node.module for n in names]
            else:
                continue
            for there in names:
                if there in modules and there != here:
                    graph[here].setdefault(there, f"{rel}:{node.lineno}")
    return graph


def cycles(graph: Mapping[str, Mapping[str, object]]) -> list[list[str]]:
    """Every cycle a depth-first walk of ``graph`` (node -> the nodes it imports) runs into."""
    state: dict[str, int] = {}
    found: list[list[str]] = []

    def visit(module: str, stack: list[str]) -> None:
        state[module] = 1
        for nxt in graph.get(module, {}):
            if state.get(nxt) == 1:
                found.append(stack[stack.index(nxt) :] + [module, nxt] if nxt in stack else [module, nxt])
            elif nxt not in state:
                visit(nxt, stack + [module])
        state[module] = 2

    for module in list(graph):
        if module not in state:
            visit(module, [])
    return found


def test_no_module_imports_a_module_that_imports_it_back():
    """Within a package too: two modules that import each other (even lazily, inside a
    function) share internals that belong in a third."""
    graph = module_graph()
    found = cycles(graph)
    assert not found, "; ".join(" -> ".join(c) + f" (e.g. {graph[c[-2]][c[-1]]})" for c in found)


def test_the_module_check_sees_a_lazy_import_loop(tmp_path):
    pkg = tmp_path / "nca_qd"
    (pkg / "sim").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "sim" / "__init__.py").write_text("")
    (pkg / "sim" / "a.py").write_text("from nca_qd.sim.b import f\n")
    (pkg / "sim" / "b.py").write_text("def f():\n    from nca_qd.sim import a\n")
    graph = module_graph(pkg)
    assert graph["nca_qd.sim.b"] == {"nca_qd.sim.a": "nca_qd/sim/b.py:2"}
    assert cycles(graph) == [["nca_qd.sim.a", "nca_qd.sim.b", "nca_qd.sim.a"]]


@pytest.mark.parametrize("unit", sorted(FORBIDDEN))
def test_a_generic_layer_does_not_import_the_layers_above_it(unit):
    graph = import_graph()
    banned = FORBIDDEN[unit]
    bad = {
        there: where
        for there, where in graph.get(unit, {}).items()
        if there in banned or ("*" in banned and there != unit)
    }
    assert not bad, f"nca_qd.{unit} imports " + "; ".join(
        f"nca_qd.{t} ({', '.join(w[:3])})" for t, w in sorted(bad.items())
    )


def test_no_module_outside_a_layout_family_branches_on_its_name():
    """A layout family's facts live in its module under nca_qd/layouts/; elsewhere nothing
    compares a domain name with a family's (``== "manufacturing"``, ``startswith("warehouse")``)."""
    from nca_qd.layouts import LAYOUTS

    families = {kind.family for kind in LAYOUTS.values()} | set(LAYOUTS)
    found = []
    for path in sorted(PACKAGE.rglob("*.py")):
        if path.parent.name == "layouts":
            continue
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.Compare) and any(
                isinstance(c, ast.Constant) and c.value in families for c in node.comparators
            ):
                found.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
            if (
                isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute)
                and node.func.attr == "startswith"
                and node.args
                and isinstance(node.args[0], ast.Constant)
                and node.args[0].value in families
            ):
                found.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
    assert not found, "branches on a layout family's name: " + ", ".join(found)


def test_the_checker_sees_an_import_it_must_refuse(tmp_path, monkeypatch):
    """The graph is read from the source: a planted lazy import shows up with its line."""
    pkg = tmp_path / "nca_qd"
    (pkg / "qd").mkdir(parents=True)
    (pkg / "__init__.py").write_text("")
    (pkg / "qd" / "__init__.py").write_text("def f():\n    from nca_qd.scoring import mapf\n")
    monkeypatch.setattr(__import__(__name__), "PACKAGE", pkg)
    assert import_graph()["qd"]["scoring"] == ["nca_qd/qd/__init__.py:2"]


# Rooms of a size one can read (issue 56): no module over MAX_MODULE_LINES lines, no function
# over MAX_FUNCTION_LINES. A function listed in OVERSIZED_FUNCTIONS (none today) may shrink but
# not grow, and leaves the list once it fits.
MAX_MODULE_LINES = 600
MAX_FUNCTION_LINES = 120
OVERSIZED_FUNCTIONS: dict[str, int] = {}


def sizes(root: Path = PACKAGE) -> tuple[dict[str, int], dict[str, int]]:
    """Lines per module and per function (``"path:name"``, nested functions counted in their
    parent and on their own)."""
    modules, functions = {}, {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root).as_posix()
        text = path.read_text()
        modules[rel] = text.count("\n")
        for node in ast.walk(ast.parse(text, rel)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                key = f"{rel}:{node.name}"
                functions[key] = max(functions.get(key, 0), node.end_lineno - node.lineno + 1)
    return modules, functions


def test_modules_and_functions_stay_small():
    modules, functions = sizes()
    big = {m: n for m, n in modules.items() if n > MAX_MODULE_LINES}
    assert not big, f"modules over {MAX_MODULE_LINES} lines: {big}"
    long = {f: n for f, n in functions.items() if n > MAX_FUNCTION_LINES}
    grown = {f: n for f, n in long.items() if n > OVERSIZED_FUNCTIONS.get(f, MAX_FUNCTION_LINES)}
    assert not grown, f"functions over {MAX_FUNCTION_LINES} lines (or grown past their listed size): {grown}"
    fitted = sorted(set(OVERSIZED_FUNCTIONS) - set(long))
    assert not fitted, f"these now fit: take them off OVERSIZED_FUNCTIONS: {fitted}"


def test_the_size_check_sees_a_long_function(tmp_path):
    (tmp_path / "m.py").write_text("def f():\n" + "    x = 1\n" * 130 + "\n" * 700)
    modules, functions = sizes(tmp_path)
    assert modules["m.py"] > MAX_MODULE_LINES and functions["m.py:f"] == 131
