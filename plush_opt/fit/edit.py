"""Write the fitted problem file: the input's text with only the fitted
scalars changed, so comments, layout and every other key stay as written.

The YAML is composed (not loaded) to find each value's exact span in the
text; a value is replaced in place, a missing key (an ``assembly_offset``
the input did not give) is added after the last key of its mapping, at
that mapping's indentation (or inside the braces of a flow mapping).
"""

from __future__ import annotations

import yaml

from ..base.errors import SceneError

#: significant digits written: far below any standard error, and still readable
DIGITS = 10


def format_number(value: float) -> str:
    """A float YAML 1.1 and 1.2 both read as a float (exponent with a dot)."""
    s = f"{float(value):.{DIGITS}g}"
    if "e" in s and "." not in s.split("e")[0]:
        mantissa, exp = s.split("e")
        s = f"{mantissa}.0e{exp}"
    elif "e" not in s and "." not in s and s not in ("inf", "-inf", "nan"):
        s += ".0"
    return s


def _child(node, key):
    if isinstance(node, yaml.MappingNode):
        for k, v in node.value:
            if isinstance(k, yaml.ScalarNode) and k.value == key:
                return v
        return None
    if isinstance(node, yaml.SequenceNode) and isinstance(key, int) and key < len(node.value):
        return node.value[key]
    return None


def _edit(text: str, root, path: tuple, value: str) -> tuple[int, int, str]:
    """(start, end, replacement) of one change in ``text``."""
    node = root
    for key in path[:-1]:
        node = _child(node, key)
        if node is None:
            raise SceneError(f"cannot write the fitted file: {'.'.join(map(str, path))} not found")
    target = _child(node, path[-1])
    if target is not None:
        if not isinstance(target, yaml.ScalarNode):
            raise SceneError(f"cannot write the fitted file: {'.'.join(map(str, path))} is not a number")
        return target.start_mark.index, target.end_mark.index, value
    if not isinstance(node, yaml.MappingNode) or not node.value:
        raise SceneError(f"cannot write the fitted file: no mapping for {'.'.join(map(str, path))}")
    entry = f"{path[-1]}: {value}"
    if node.flow_style:
        close = text.rfind("}", 0, node.end_mark.index)
        return close, close, f", {entry}"
    column = node.value[0][0].start_mark.column
    end = node.value[-1][1].end_mark
    line_start = text.rfind("\n", 0, end.index) + 1
    if not text[line_start:end.index].strip():   # a block value ends where the next line's token starts
        return line_start, line_start, " " * column + entry + "\n"
    eol = text.find("\n", end.index)
    eol = len(text) if eol < 0 else eol
    return eol, eol, "\n" + " " * column + entry


def edit_problem_text(text: str, changes: dict[tuple, float]) -> str:
    """``text`` with each key path (e.g. ``("tendons", "list", 2,
    "assembly_offset")``) set to its number."""
    root = yaml.compose(text, Loader=yaml.SafeLoader)
    edits = sorted((_edit(text, root, path, format_number(v)) for path, v in changes.items()),
                   key=lambda e: e[0], reverse=True)
    for start, end, new in edits:
        text = text[:start] + new + text[end:]
    return text


def fitted_changes(scene_data: dict, values, offsets, params) -> dict[tuple, float]:
    """The key paths the fit changes, with their new values.

    ``scene_data`` is the input document (to see whether the material is
    given as E and nu or as mu and lambda); ``offsets`` the assembly
    offsets to write (winch zero offsets folded in)."""
    kinds = {p.kind for p in params}
    out: dict[tuple, float] = {}
    material = scene_data["material"]
    if kinds & {"youngs_modulus", "poisson_ratio"}:
        if material.get("youngs_modulus") is not None:
            out[("material", "youngs_modulus")] = values.youngs_modulus
            out[("material", "poisson_ratio")] = values.poisson_ratio
        else:
            out[("material", "mu")] = values.mu
            out[("material", "lambda")] = values.lam
        if "poisson_ratio" not in kinds:        # E alone: nu (or mu/lambda's ratio) as it was
            out.pop(("material", "poisson_ratio"), None)
    if "tendon_stiffness" in kinds:
        out[("tendons", "stiffness")] = values.tendon_stiffness
    touched = {p.index for p in params if p.kind == "assembly_offset"}
    winches = {p.index for p in params if p.kind == "winch_offset"}
    for t in range(len(scene_data["tendons"]["list"])):
        if t in touched or _winch_of(scene_data, t) in winches:
            out[("tendons", "list", t, "assembly_offset")] = float(offsets[t])
    return out


def _winch_of(scene_data: dict, t: int) -> int:
    name = scene_data["tendons"]["list"][t]["winch"]
    return [w["name"] for w in scene_data["winches"]].index(name)
