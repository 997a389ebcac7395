"""Issue 24, item 1: every public formula function of ``baarda.stats`` and ``baarda.observations``
has a numpydoc docstring — a one-line summary, a ``Parameters`` section naming each argument of
the signature (``name : type`` then an indented description with its units) and a ``Returns``
section unless the function returns None. The sections are parsed by a small numpydoc parser
(numpydoc itself is not a dependency); a function is found by reading the source, not by import."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MODULES = sorted(p for folder in ("stats", "observations") for p in (ROOT / "core" / folder).glob("*.py")
                 if p.name != "__init__.py")
HEADING = re.compile(r"^(\S[^\n]*)\n(-{3,})$", re.MULTILINE)
SECTIONS = {"Parameters", "Returns", "Yields", "Raises", "Warns", "Notes", "References", "Examples", "See Also",
            "Other Parameters", "Attributes", "Methods", "Warnings"}


def public_functions():
    """(module path, ast.FunctionDef) for every module-level function without a leading underscore."""
    for path in MODULES:
        tree = ast.parse(path.read_text(encoding="utf-8"))
        for node in tree.body:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) and not node.name.startswith("_"):
                yield path, node


def sections(doc: str) -> dict[str, list[str]]:
    """The numpydoc sections of a cleaned docstring: heading -> its lines; "" -> the text before.
    A heading is a known section name underlined by as many dashes; raises ValueError otherwise."""
    lines = doc.splitlines()
    out: dict[str, list[str]] = {"": []}
    current = ""
    i = 0
    while i < len(lines):
        line = lines[i]
        nxt = lines[i + 1] if i + 1 < len(lines) else ""
        if nxt.strip() and set(nxt.strip()) == {"-"} and line.strip() and not line.startswith(" "):
            name = line.strip()
            if name not in SECTIONS:
                raise ValueError(f"unknown section {name!r}")
            if len(nxt.strip()) != len(name):
                raise ValueError(f"section {name!r} underlined by {len(nxt.strip())} dashes")
            if name in out:
                raise ValueError(f"section {name!r} twice")
            current = name
            out[current] = []
            i += 2
            continue
        out[current].append(line)
        i += 1
    return out


def entries(lines: list[str]) -> list[tuple[str, str, str]]:
    """(name, type, description) of a Parameters/Returns section: an unindented ``name : type``
    (or, in Returns, just a type) followed by indented description lines; raises ValueError on
    an entry without a description or text outside an entry."""
    out: list[tuple[str, str, str]] = []
    for line in lines:
        if not line.strip():
            continue
        if not line.startswith(" "):
            name, sep, typ = line.partition(" : ")
            out.append((name.strip(), typ.strip() if sep else "", ""))
        elif out:
            name, typ, desc = out[-1]
            out[-1] = (name, typ, (desc + " " + line.strip()).strip())
        else:
            raise ValueError(f"indented text before any entry: {line.strip()!r}")
    for name, typ, desc in out:
        if not desc:
            raise ValueError(f"entry {name!r} has no indented description")
    return out


def signature_names(node: ast.FunctionDef) -> list[str]:
    a = node.args
    names = [x.arg for x in a.posonlyargs + a.args + a.kwonlyargs]
    if a.vararg:
        names.append("*" + a.vararg.arg)
    if a.kwarg:
        names.append("**" + a.kwarg.arg)
    return names


def returns_value(node: ast.FunctionDef) -> bool:
    """Whether the function returns (or yields) anything but None: a ``return`` with a value in
    its own body (not in a nested function or class) or a ``yield``."""
    todo = list(node.body)
    while todo:
        n = todo.pop()
        if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda)):
            continue
        if isinstance(n, ast.Return) and n.value is not None and not (
                isinstance(n.value, ast.Constant) and n.value.value is None):
            return True
        if isinstance(n, (ast.Yield, ast.YieldFrom)):
            return True
        todo.extend(ast.iter_child_nodes(n))
    return False


def check(node: ast.FunctionDef) -> list[str]:
    """What is wrong with the docstring of ``node`` ([] if nothing)."""
    doc = ast.get_docstring(node, clean=True)
    if not doc:
        return ["no docstring"]
    try:
        parts = sections(doc)
        params = entries(parts.get("Parameters", []))
        rets = entries(parts.get("Returns", []) or parts.get("Yields", []))
    except ValueError as e:
        return [str(e)]
    problems = []
    summary = [x for x in parts[""] if x.strip()]
    if not summary or parts[""][0].strip() != summary[0].strip():
        problems.append("no one-line summary on the first line")
    elif len(parts[""]) > 1 and parts[""][1].strip():
        problems.append("the summary is not one line followed by a blank line")
    wanted = signature_names(node)
    if wanted and "Parameters" not in parts:
        problems.append("no Parameters section")
    documented = []
    for name, _typ, _desc in params:
        documented += [n.strip() for n in name.split(",")]
    if documented != wanted:
        problems.append(f"Parameters name {documented}, the signature {wanted}")
    for name, typ, _desc in params:
        if not typ:
            problems.append(f"parameter {name!r} has no type (name : type)")
    for name, _typ, _desc in rets:
        if "," in name:
            problems.append(f"returned values {name!r} in one entry (numpydoc lists each on its own)")
    if returns_value(node) and not rets:
        problems.append("no Returns section")
    return problems


def _function(doc: str, body: str = "") -> ast.FunctionDef:
    """The ast of ``def f(x, y=1)`` with docstring ``doc`` (indented lines) and ``body``."""
    return ast.parse(f'def f(x, y=1):\n    """{doc}\n    """\n    {body or "pass"}\n').body[0]


def test_the_parser_reads_numpydoc_and_rejects_what_is_not():
    params = "\n    Parameters\n    ----------\n    x, y : float\n        Lengths, metres.\n"
    returns = "\n    Returns\n    -------\n    float\n        The sum, metres.\n"
    assert check(_function("One line.\n" + params + returns, "return x + y")) == []
    assert check(_function("One line.\n" + params, "return None")) == []
    assert check(_function("One line.\n" + params, "return x + y")) == ["no Returns section"]
    assert check(_function("One line.\n" + params.replace("x, y", "x"))) == [
        "Parameters name ['x'], the signature ['x', 'y']"]
    undescribed = params.replace("        Lengths, metres.\n", "")
    assert "no indented description" in check(_function("One line.\n" + undescribed))[0]
    assert "has no type" in check(_function("One line.\n" + params.replace("x, y : float", "x, y")))[0]
    assert "underlined by 4 dashes" in check(_function("One line.\n" + params.replace("----------", "----")))[0]
    assert "in one entry" in check(_function("One line.\n" + params + returns.replace("float", "a, b : float"),
                                             "return x, y"))[0]
    assert "summary" in check(_function("Two\n    lines.\n" + params))[0]


def test_the_parser_agrees_with_numpydoc():
    """Where numpydoc is installed (it is not a dependency), its docscrape reads the same
    Parameters and Returns from every docstring, without a warning."""
    docscrape = pytest.importorskip("numpydoc.docscrape", reason="numpydoc is not installed")
    import warnings

    for path, node in public_functions():
        doc = ast.get_docstring(node, clean=True)
        parts = sections(doc)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            nd = docscrape.NumpyDocString(doc)
        where = f"{path.relative_to(ROOT)}:{node.lineno}: {node.name}"
        assert [p.name for p in nd["Parameters"]] == [n for n, _, _ in entries(parts.get("Parameters", []))], where
        assert [(r.name, r.type) for r in nd["Returns"]] == [
            (n, t) if t else ("", n) for n, t, _ in entries(parts.get("Returns", []))], where
        assert nd["Summary"] and " ".join(nd["Summary"]) == parts[""][0].strip(), where


def test_there_are_public_functions_to_check():
    assert len(list(public_functions())) >= 90


@pytest.mark.parametrize("path,node", [pytest.param(p, n, id=f"{p.parent.name}/{p.stem}.{n.name}")
                                       for p, n in public_functions()])
def test_public_function_has_numpydoc_parameters_and_returns(path, node):
    problems = check(node)
    assert not problems, f"{path.relative_to(ROOT)}:{node.lineno}: {node.name}: " + "; ".join(problems)
