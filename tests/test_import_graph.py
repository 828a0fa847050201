"""No import cycles inside ``valve_env``, the generic identification core knows no valve, and the core
imports neither the RL add-on nor its extra (docs/architecture.md, "What each package may import").

**The graph** is read from the source with :mod:`ast`, nothing imported: every module of valve_env (a
file; a package is its ``__init__.py``) -> every valve_env module it imports, at module level and inside
functions, methods and ``if TYPE_CHECKING`` blocks alike: ``import a.b``, ``from a import b`` (an edge to
the module ``a.b`` when b is one, else to ``a``, where the name lives) and the relative forms
(``from . import x``, ``from ..y import z``). The parent packages that Python imports on the way are not
edges (every module would depend on valve_env/__init__.py otherwise). Imports by a string at run time
are not edges either: importlib.import_module over a table (valve_env.cli's SUBCOMMAND_MODULES,
valve_env.valveid's lazy attributes), Gymnasium entry points and the plug-in entry points.

**Two levels, two rules.** Between modules: no cycle at all. Between units (each sub-package of
valve_env and each top-level module is one node; the root valve_env/__init__.py, the registration, is its
own): no cycle except the known ones below.

**The known cycles are a ratchet.** :data:`KNOWN_UNIT_CYCLES` lists, explicitly, the strongly connected
components allowed among the identification packages (none today). The test fails on any cycle not in
that list, and also when a listed cycle has gone or changed, so the list stays true: whoever breaks a
cycle deletes its entry in the same commit.
"""


from __future__ import annotations

import ast
import sys
from collections.abc import Iterable, Mapping
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "valve_env"
IDENTIFICATION = ("valve_env.ident", "valve_env.valveid", "valve_env.loops", "valve_env.studies")

#: the unit-level cycles allowed in the identification packages (see the module docstring)
KNOWN_UNIT_CYCLES: frozenset[frozenset[str]] = frozenset()

#: what the core may never import: the RL add-on and what only its extra installs
FORBIDDEN = ("agents", "torch", "stable_baselines3", "sb3_contrib", "dask", "distributed", "tensorboard")


def module_files(root: Path, package: str) -> dict[str, Path]:
    """Dotted module name -> source file, for every module of ``package`` under ``root``."""
    out: dict[str, Path] = {}
    for f in sorted((root / package).rglob("*.py")):
        parts = list(f.relative_to(root).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = f
    return out


def imported_names(module: str, source: str, is_package: bool) -> list[str]:
    """Every dotted name that ``source`` imports, anywhere in it, relative forms resolved: ``import a.b``
    gives a.b; ``from a import b, c`` gives a.b and a.c (a module, or a name in the module a: the caller
    takes the longest prefix that is a module)."""
    here = module if is_package else module.rpartition(".")[0]
    names: list[str] = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            names += [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                parts = here.split(".")
                base = ".".join(parts[: len(parts) - (node.level - 1)] + ([node.module] if node.module else []))
            else:
                base = str(node.module)
            names += [base if alias.name == "*" else f"{base}.{alias.name}" for alias in node.names]
    return names


def build_graph(root: Path, package: str) -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(module -> the package's modules it imports, module -> the top-level names of everything it imports)."""
    files = module_files(root, package)

    def owner(name: str) -> str | None:  # the longest module prefix: a.b.C -> a.b
        while name and name not in files:
            name = name.rpartition(".")[0]
        return name or None

    edges: dict[str, set[str]] = {m: set() for m in files}
    tops: dict[str, set[str]] = {m: set() for m in files}
    for m, f in files.items():
        for name in imported_names(m, f.read_text(encoding="utf-8"), f.name == "__init__.py"):
            tops[m].add(name.split(".")[0])
            if name.split(".")[0] == package:
                target = owner(name)
                if target is not None and target != m:
                    edges[m].add(target)
    return edges, tops


def unit(module: str) -> str:
    """The unit of a module: valve_env itself, a sub-package (valve_env.tasks) or a top-level module."""
    return ".".join(module.split(".")[:2])


def unit_graph(edges: Mapping[str, Iterable[str]]) -> dict[str, set[str]]:
    out: dict[str, set[str]] = {unit(m): set() for m in edges}
    for m, targets in edges.items():
        out[unit(m)] |= {unit(t) for t in targets if unit(t) != unit(m)}
    return out


def cycles(graph: Mapping[str, Iterable[str]]) -> set[frozenset[str]]:
    """The strongly connected components of more than one node (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: set[frozenset[str]] = set()

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = set()
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.add(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.add(frozenset(comp))

    limit = sys.getrecursionlimit()
    sys.setrecursionlimit(max(limit, 10 * len(graph) + 100))
    try:
        for v in sorted(graph):
            if v not in index:
                visit(v)
    finally:
        sys.setrecursionlimit(limit)
    return found


@pytest.fixture(scope="module")
def graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    return build_graph(ROOT, PACKAGE)


def _show(found: Iterable[frozenset[str]]) -> str:
    return "; ".join(" <-> ".join(sorted(c)) for c in sorted(found, key=sorted))


def test_the_graph_sees_every_form_of_import(tmp_path: Path) -> None:
    """The reader on a package made for it: a function-level import, ``from . import x``, ``from .. import``,
    an absolute submodule import with an alias, a name from a package (an edge to the package) and a
    name from a module closes the cycles it should; a cycle through a function-level import is found."""
    pkg = tmp_path / "pkg"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "from pkg.a import A\n",
        "a.py": "A = 1\n\ndef f():\n    from . import b\n    return b\n",
        "b.py": "from .sub import c as _c\n",
        "sub/__init__.py": "NAME = 2\n",
        "sub/c.py": "import pkg.sub.d as d\nfrom .. import e\n",
        "sub/d.py": "from pkg.sub import NAME\n",
        "e.py": "class K:\n    def m(self):\n        import pkg.a\n        return pkg.a\n",
    }
    for rel, text in files.items():
        (pkg / rel).write_text(text)
    edges, tops = build_graph(tmp_path, "pkg")
    assert edges == {
        "pkg": {"pkg.a"}, "pkg.a": {"pkg.b"}, "pkg.b": {"pkg.sub.c"}, "pkg.sub": set(),
        "pkg.sub.c": {"pkg.sub.d", "pkg.e"}, "pkg.sub.d": {"pkg.sub"}, "pkg.e": {"pkg.a"},
    }
    assert tops["pkg.a"] == {"pkg"}
    # a -> b -> sub.c -> e -> a, only through imports inside functions
    assert cycles(edges) == {frozenset({"pkg.a", "pkg.b", "pkg.sub.c", "pkg.e"})}
    assert cycles(unit_graph(edges)) == {frozenset({"pkg.a", "pkg.b", "pkg.sub", "pkg.e"})}


def test_no_module_imports_itself_back(graph: tuple[dict[str, set[str]], dict[str, set[str]]]) -> None:
    edges, _ = graph
    assert len(edges) > 50 and sum(map(len, edges.values())) > 200  # the whole package was read
    found = cycles(edges)
    assert not found, f"import cycles between modules: {_show(found)}"


def test_package_cycles_are_only_the_known_identification_ones(
        graph: tuple[dict[str, set[str]], dict[str, set[str]]]) -> None:
    edges, _ = graph
    found = cycles(unit_graph(edges))
    new = found - KNOWN_UNIT_CYCLES
    assert not new, f"new import cycle(s) between valve_env's packages: {_show(new)}"
    gone = KNOWN_UNIT_CYCLES - found
    assert not gone, (f"known cycle(s) no longer there: {_show(gone)}; delete them from KNOWN_UNIT_CYCLES "
                      "(tests/test_import_graph.py) so the list stays true")


def test_the_known_cycles_lie_inside_the_identification_packages() -> None:
    for comp in KNOWN_UNIT_CYCLES:
        assert comp and all(u in IDENTIFICATION for u in comp), sorted(comp)


def test_the_core_imports_neither_the_rl_add_on_nor_its_extra(
        graph: tuple[dict[str, set[str]], dict[str, set[str]]]) -> None:
    _, tops = graph
    bad = {m: sorted(t & set(FORBIDDEN)) for m, t in tops.items() if t & set(FORBIDDEN)}
    assert not bad, f"the core imports the RL add-on or its extra: {bad}"


def test_the_identification_core_knows_no_valve(
        graph: tuple[dict[str, set[str]], dict[str, set[str]]]) -> None:
    """valve_env.ident (SDE models, Kalman filters, the estimator, uncertainty, bootstrap, tests) imports
    nothing of valve_env outside itself: the valve, the loops and the CLI sit on top of it."""
    edges, _ = graph
    core = {m: sorted(t for t in targets if not t.startswith("valve_env.ident"))
            for m, targets in edges.items() if m.startswith("valve_env.ident")}
    assert len(core) >= 6, sorted(core)
    bad = {m: t for m, t in core.items() if t}
    assert not bad, f"the identification core imports the valve or the loops: {bad}"


def test_the_commands_import_their_helpers_not_the_dispatcher(
        graph: tuple[dict[str, set[str]], dict[str, set[str]]]) -> None:
    """No module of valve_env imports the dispatcher valve_env.cli (it runs the command modules, which take their
    helpers from valve_env.cliutil), and cliutil imports nothing of valve_env: the commands import down."""
    edges, _ = graph
    assert {m for m, targets in edges.items() if "valve_env.cli" in targets} == set()
    assert {m for m, targets in edges.items() if "valve_env.cliutil" in targets} >= {
        "valve_env.cli", "valve_env.valveid.cli", "valve_env.loops.cli", "valve_env.evaluation.cli"}
    assert edges["valve_env.cliutil"] == set()
