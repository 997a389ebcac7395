"""The import rules of the core's layers (README, "Layout"; issue 13).

An AST walk over every module of ``core/`` (the import package ``baarda`` without the dashboard):

- no function-level import, except the CLI's import of the dashboard (which needs Panel); none at
  all in ``core/solve/``;
- numba imported by one module only, ``baarda.solve.compiled`` (everything else takes the jit
  decorator from there);
- no import of a private name (``_x``) from another module;
- the models (``core/model/``) and the observation equations (``core/observations/``) import
  no statistics (``core/stats/``), nor does the solver: ``adjust``, ``iteration``, ``result`` and
  ``solve/`` (the solver knows no tests: the tests under a policy are
  :func:`baarda.stats.reliability.reliability_of`);
- no import cycle between the core's modules.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

CORE = Path(__file__).resolve().parent.parent / "core"
DASHBOARD = CORE.parent / "dashboard"


def module_name(path: Path) -> str:
    root, prefix = (DASHBOARD, ["baarda", "dashboard"]) if DASHBOARD in path.parents else (CORE, ["baarda"])
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join([*prefix, *parts])


MODULES = {module_name(p): p for p in [*sorted(CORE.rglob("*.py")), *sorted(DASHBOARD.rglob("*.py"))]}
#: the function-level imports allowed: (importing module, imported module's prefix)
LAZY_ALLOWED = {("baarda.solve.compiled", "numba"), ("baarda.commands", "baarda.dashboard"),
                # the command line parses first, then loads the computation (issue 30 item 5, issue 25)
                ("baarda.cli", "baarda.commands"), ("baarda.cli", "baarda.threads"),
                # the batch extra (Dask, pyarrow), imported by the commands that use it (issue 30)
                ("baarda.batch", "dask"), ("baarda.batch", "distributed"), ("baarda.batch", "pyarrow"),
                ("baarda.analysis", "baarda.dashboard.notebook")}


def is_package(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def imports(name: str):
    """(node, target modules, imported names, function-level?) of each import in module ``name``."""
    tree = ast.parse(MODULES[name].read_text(encoding="utf-8"))
    package = name if is_package(name) else name.rsplit(".", 1)[0]
    out = []

    def visit(node, nested):
        for child in ast.iter_child_nodes(node):
            inner = nested or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda))
            if isinstance(child, ast.Import):
                out.append((child, [a.name for a in child.names], [], inner))
            elif isinstance(child, ast.ImportFrom):
                if child.level:
                    base = package.split(".")
                    base = base[: len(base) - child.level + 1]
                    mod = ".".join(base + ([child.module] if child.module else []))
                else:
                    mod = child.module
                names = [a.name for a in child.names]
                targets = [mod] + [f"{mod}.{n}" for n in names if f"{mod}.{n}" in MODULES]
                out.append((child, targets, names, inner))
            visit(child, inner)

    visit(tree, False)
    return out


def where(name, node):
    return f"{MODULES[name].relative_to(CORE.parent)}:{node.lineno}"


def test_no_function_level_imports():
    bad = []
    for name in MODULES:
        for node, targets, _, nested in imports(name):
            if not nested:
                continue
            if any(name == m and targets[0].startswith(t) for m, t in LAZY_ALLOWED):
                continue                  # the optional numba import, the GUI behind the CLI and Analysis.view
            bad.append(f"{where(name, node)} imports {targets[0]}")
    assert not bad, "function-level imports:\n" + "\n".join(bad)


def test_no_private_names_across_modules():
    bad = []
    for name in MODULES:
        for node, targets, names, _ in imports(name):
            if not targets[0].startswith("baarda"):
                continue
            private = [n for n in names if n.startswith("_") and not n.startswith("__")]
            if private:
                bad.append(f"{where(name, node)} imports {', '.join(private)} from {targets[0]}")
    assert not bad, "private names imported across modules:\n" + "\n".join(bad)


@pytest.mark.parametrize("layer", ["baarda.model", "baarda.observations"])
def test_model_and_observations_import_no_statistics(layer):
    assert any(name.startswith(layer + ".") for name in MODULES), f"no modules in {layer}"
    bad = []
    for name in MODULES:
        if name != layer and not name.startswith(layer + "."):
            continue
        for node, targets, _, _ in imports(name):
            if any(t == "baarda.stats" or t.startswith("baarda.stats.") for t in targets):
                bad.append(f"{where(name, node)} imports {targets[0]}")
    assert not bad, "statistics imported by a lower layer:\n" + "\n".join(bad)


def _in(name: str, layers) -> bool:
    return any(name == layer or name.startswith(layer + ".") for layer in layers)


#: (importing layers, imported layers, exempt importers): imports that must never happen
NEVER = [
    (("baarda.model", "baarda.observations"), ("baarda.stats",), ()),
    # the observation equations are below the models: the models build problems from them, never
    # the other way round (the network -> Problem builder lives in model/, not observations/)
    (("baarda.observations",), ("baarda.model", "baarda.build"), ()),
    (("baarda.solve", "baarda.adjust", "baarda.iteration"), ("baarda.stats",), ()),
    # (the compiled-kernel decorator baarda.solve.compiled is a base utility, as numpy is)
    (("baarda.io",), ("baarda.solve.schur", "baarda.solve.linalg", "baarda.solve.heap", "baarda.stats",
                      "baarda.adjust"),
     # the result document, its text and its GeoJSON: statistics
     ("baarda.io.results", "baarda.io.summary_text", "baarda.io.analysis_text", "baarda.io.geojson")),
]


@pytest.mark.parametrize("rule", NEVER, ids=lambda r: f"{'+'.join(r[0])}-never-{'+'.join(r[1])}")
def test_never_edges(rule):
    importers, imported, exempt = rule
    assert any(_in(name, importers) for name in MODULES), f"no modules in {importers}"
    bad = []
    for name in MODULES:
        if not _in(name, importers) or name in exempt:
            continue
        for node, targets, _, _ in imports(name):
            if any(_in(t, imported) for t in targets):
                bad.append(f"{where(name, node)} imports {targets[0]}")
    assert not bad, "imports across a 'never' edge:\n" + "\n".join(bad)


def test_core_imports_no_dashboard_at_module_level():
    bad = [f"{where(name, node)} imports {targets[0]}" for name in MODULES if not name.startswith("baarda.dashboard")
           for node, targets, _, nested in imports(name) if not nested and _in(targets[0], ("baarda.dashboard",))]
    assert not bad, "\n".join(bad)


def test_the_rules_see_a_violation():
    """The walk finds what it looks for: a module-level edge the rules forbid, in a synthetic module."""
    tree = ast.parse("from baarda.stats import policy\ndef f():\n    import numba\n")
    nested = [isinstance(n, ast.Import) for n in ast.walk(tree.body[1])]
    assert any(nested) and isinstance(tree.body[0], ast.ImportFrom) and tree.body[0].module == "baarda.stats"
    assert _in("baarda.solve.schur", ("baarda.solve",)) and not _in("baarda.solver", ("baarda.solve",))


def test_no_function_level_import_in_solve():
    assert any(name.startswith("baarda.solve.") for name in MODULES)
    bad = [f"{where(name, node)} imports {targets[0]}" for name in MODULES
           if name == "baarda.solve" or name.startswith("baarda.solve.")
           for node, targets, _, nested in imports(name) if nested]
    assert not bad, "function-level imports in solve/:\n" + "\n".join(bad)


def test_numba_imported_in_one_place():
    users = sorted({name for name in MODULES for _, targets, _, _ in imports(name)
                    if targets[0] == "numba" or targets[0].startswith("numba.")})
    assert users in ([], ["baarda.solve.compiled"])
    # imported when the first kernel is compiled (issue 30, start-up), by that module only
    assert 'lazy("numba")' in MODULES["baarda.solve.compiled"].read_text(encoding="utf-8")


def _imports_stats(name):
    return [f"{where(name, node)} imports {targets[0]}" for node, targets, _, _ in imports(name)
            if any(t == "baarda.stats" or t.startswith("baarda.stats.") for t in targets)]


@pytest.mark.parametrize("layer", [
    "baarda.adjust", "baarda.iteration", "baarda.solve",
    "baarda.result",
])
def test_solver_imports_no_statistics(layer):
    names = [n for n in MODULES if n == layer or n.startswith(layer + ".")]
    assert names, f"no modules in {layer}"
    bad = [line for n in names for line in _imports_stats(n)]
    assert not bad, "statistics imported by the solver:\n" + "\n".join(bad)


def test_stats_import_check_sees_an_import(tmp_path, monkeypatch):
    """The check above finds a module-level import of the statistics (a planted module)."""
    (tmp_path / "core").mkdir()
    planted = tmp_path / "core" / "planted.py"
    planted.write_text("import numpy\n\nfrom .stats import policy\n", encoding="utf-8")
    monkeypatch.setitem(MODULES, "baarda.planted", planted)
    monkeypatch.setattr("tests.test_layers.CORE", tmp_path / "core")
    assert _imports_stats("baarda.planted") == ["core/planted.py:3 imports baarda.stats"]


def graph():
    """Module -> the core modules it imports. ``from pkg import sub`` depends on the submodule
    only, and a package being initialised is no dependency of its own modules."""
    edges = {name: set() for name in MODULES}
    for name in MODULES:
        for _, targets, names, nested in imports(name):
            if nested and any(name == m and targets[0].startswith(t) for m, t in LAZY_ALLOWED):
                continue                  # imported when called, never while the importer loads
            mod, subs = targets[0], targets[1:]
            if len(subs) < len(names) and not name.startswith(mod + "."):
                subs = [mod, *subs]
            edges[name].update(t for t in subs if t in MODULES and t != name)
    return edges


def find_cycle(edges):
    """One cycle of the directed graph as a list of nodes, or None (iterative depth-first search)."""
    state = {}
    for start in sorted(edges):
        if start in state:
            continue
        stack = [(start, iter(sorted(edges[start])))]
        path = [start]
        state[start] = "open"
        while stack:
            node, it = stack[-1]
            nxt = next(it, None)
            if nxt is None:
                state[node] = "done"
                stack.pop()
                path.pop()
            elif state.get(nxt) == "open":
                return path[path.index(nxt):] + [nxt]
            elif nxt not in state:
                state[nxt] = "open"
                stack.append((nxt, iter(sorted(edges[nxt]))))
                path.append(nxt)
    return None


def test_no_import_cycle():
    cycle = find_cycle(graph())
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_cycle_finder_sees_a_cycle():
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": set()}) is None


def test_no_module_of_the_core_over_800_lines():
    """Issue 24: a module of the core holds one concept; none grows past 800 lines."""
    long = {name: n for name, path in MODULES.items() if not name.startswith("baarda.dashboard")
            for n in [len(path.read_text(encoding="utf-8").splitlines())] if n > 800}
    assert not long, f"modules over 800 lines: {long}"


def test_adjust_is_a_short_loop():
    """Issue 24: ``adjust()`` is a loop over the iteration's steps (baarda.iteration), at most 80 lines."""
    tree = ast.parse(MODULES["baarda.adjust"].read_text(encoding="utf-8"))
    fn = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "adjust")
    assert fn.end_lineno - fn.lineno + 1 <= 80
