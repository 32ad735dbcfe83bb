"""The shape of the package: one-way imports down the layers of
docs/architecture.md, and pieces small enough to read."""

from __future__ import annotations

import ast
import importlib.util

from shipped import ROOT

spec = importlib.util.spec_from_file_location("import_graph", ROOT / "tools" / "import_graph.py")
import_graph = importlib.util.module_from_spec(spec)
spec.loader.exec_module(import_graph)

MAX_MODULE_LINES = 600
MAX_CLASS_LINES = 300
MAX_FUNCTION_LINES = 80
# Larger pieces, each with the reason it stays whole.
EXCEPTIONS = {
    # Triangle's switches, forced points and holes, then the checks of what
    # it returned, in the order they happen
    "plush_opt/fem/mesh.py:build_mesh",
    # the report's sections, one after the other, as they appear in report.md
    "plush_opt/apps/compare/report.py:report_text",
}


def test_imports_point_down_the_layers_only():
    assert import_graph.violations() == []


def _pieces():
    for path in sorted((ROOT / "plush_opt").rglob("*.py")):
        rel = path.relative_to(ROOT).as_posix()
        text = path.read_text()
        yield rel, "module", text.count("\n"), MAX_MODULE_LINES
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, ast.ClassDef):
                yield f"{rel}:{node.name}", "class", node.end_lineno - node.lineno + 1, MAX_CLASS_LINES
            elif isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                yield f"{rel}:{node.name}", "function", node.end_lineno - node.lineno + 1, MAX_FUNCTION_LINES


def test_modules_classes_and_functions_stay_small():
    big = [f"{name} ({kind}, {n} lines > {limit})" for name, kind, n, limit in _pieces()
           if n > limit and name not in EXCEPTIONS]
    assert big == [], "\n".join(big)


def test_every_exception_is_still_needed():
    # an exception for a piece that was split or removed would hide the next one
    over = {name for name, _, n, limit in _pieces() if n > limit}
    assert sorted(EXCEPTIONS - over) == []


def test_the_map_in_docs_architecture_is_the_code():
    # the diagram, the folders' contents, their promises (each folder's own
    # docstring) and who imports whom, as tools/import_graph.py draws them today
    assert import_graph.doc_is_current(), (
        "docs/architecture.md's map differs from the code: run tools/import_graph.py --write-doc")
