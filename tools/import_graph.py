"""Draw and check the package's import graph.

    .venv/bin/python tools/import_graph.py            # check the layers; print violations
    .venv/bin/python tools/import_graph.py --mermaid  # the layer diagram of docs/architecture.md

Reads every module under plush_opt/ with the standard library's ``ast``
(imports inside functions count too: a lazy import is still a dependency)
and checks that every arrow points down the layers of LAYERS.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "plush_opt"

# Layers, lowest first. A module may import its own layer and the ones
# below, never one above. Longest prefix wins.
LAYERS = [
    ("base", ("base",)),
    ("io", ("io",)),
    ("fem", ("fem",)),
    ("solve", ("solve",)),
    ("control", ("control", "fit")),
    ("api", ("problem",)),
    ("board", ("board",)),
    ("apps", ("apps", "__init__", "__main__")),
]
# Libraries only the edge may use: plots and windows, serial ports.
EDGE_ONLY = {"matplotlib": ("apps",), "serial": ("board",)}


def module_name(path: Path) -> str:
    rel = path.relative_to(PACKAGE).with_suffix("")
    parts = rel.parts[:-1] if rel.name == "__init__" and len(rel.parts) > 1 else rel.parts
    return ".".join(parts) or "__init__"


def layer_of(module: str) -> int:
    best, rank = -1, None
    for i, (_, prefixes) in enumerate(LAYERS):
        for p in prefixes:
            if (module == p or module.startswith(p + ".")) and len(p) > best:
                best, rank = len(p), i
    if rank is None:
        raise SystemExit(f"import_graph: module {module!r} is in no layer; add it to LAYERS")
    return rank


def _resolve(module: str, is_package: bool, node: ast.ImportFrom) -> list[str]:
    base = module.split(".") if module != "__init__" else []
    if node.level:
        keep = len(base) - node.level + (1 if is_package else 0)
        base = base[:keep]
        target = ".".join(base + ([node.module] if node.module else []))
        if node.module is None:
            return [".".join(base + [a.name]) for a in node.names]
        return [target]
    if node.module and node.module.split(".")[0] == "plush_opt":
        return [node.module[len("plush_opt."):] if node.module != "plush_opt" else "__init__"]
    return []


def graph() -> tuple[dict[str, set[str]], dict[str, set[str]]]:
    """(internal edges module -> modules, external top-level libraries per module)."""
    edges, libs = defaultdict(set), defaultdict(set)
    modules = {module_name(p): p for p in PACKAGE.rglob("*.py")}
    for name, path in modules.items():
        tree = ast.parse(path.read_text(), str(path))
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                if node.level == 0 and not (node.module or "").startswith("plush_opt"):
                    libs[name].add((node.module or "").split(".")[0])
                for target in _resolve(name, path.name == "__init__.py", node):
                    # "from .x import y" may name a submodule y
                    sub = [f"{target}.{a.name}" for a in node.names if f"{target}.{a.name}" in modules]
                    for t in sub or [target]:
                        if t in modules and t != name:
                            edges[name].add(t)
            elif isinstance(node, ast.Import):
                for a in node.names:
                    if a.name.startswith("plush_opt"):
                        t = a.name[len("plush_opt."):] or "__init__"
                        if t in modules and t != name:
                            edges[name].add(t)
                    else:
                        libs[name].add(a.name.split(".")[0])
        edges.setdefault(name, set())
    return edges, libs


def violations() -> list[str]:
    edges, libs = graph()
    out = []
    for a, targets in sorted(edges.items()):
        for b in sorted(targets):
            if layer_of(b) > layer_of(a):
                out.append(f"{a} ({LAYERS[layer_of(a)][0]}) imports {b} ({LAYERS[layer_of(b)][0]}): "
                           "an arrow pointing up the layers")
    for a, used in sorted(libs.items()):
        for lib, allowed in EDGE_ONLY.items():
            if lib in used and LAYERS[layer_of(a)][0] not in allowed:
                out.append(f"{a} imports {lib}, which only {', '.join(allowed)} may use")
    # no cycles between modules (a cycle inside one layer is still a tangle)
    state: dict[str, int] = {}

    def visit(n, stack):
        state[n] = 1
        for m in sorted(edges.get(n, ())):
            if state.get(m) == 1:
                out.append("import cycle: " + " -> ".join(stack[stack.index(m):] + [m]))
            elif m not in state:
                visit(m, stack + [m])
        state[n] = 2

    for n in sorted(edges):
        if n not in state:
            visit(n, [n])
    return out


def mermaid() -> str:
    """Layer-to-layer arrows (each arrow: some module of one imports one of the other)."""
    edges, _ = graph()
    names = [n for n, _ in LAYERS]
    pairs = set()
    for a, targets in edges.items():
        for b in targets:
            la, lb = layer_of(a), layer_of(b)
            if la != lb:
                pairs.add((names[la], names[lb]))
    lines = ["flowchart BT"]
    for i, (name, prefixes) in enumerate(LAYERS):
        lines.append(f"  {name}[\"{name}: {', '.join(prefixes)}\"]")
    for a, b in sorted(pairs, key=lambda p: (names.index(p[0]), names.index(p[1]))):
        lines.append(f"  {a} --> {b}")
    return "\n".join(lines)


if __name__ == "__main__":
    if "--mermaid" in sys.argv:
        print(mermaid())
        sys.exit(0)
    bad = violations()
    for line in bad:
        print(line)
    print(f"import graph: {len(bad)} violation(s)")
    sys.exit(1 if bad else 0)
