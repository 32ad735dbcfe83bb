"""Loader fuzzing on text: mutations of the shipped and hard problem files.

tests/test_scene.py fuzzes the validator with mutated Python dicts and
random short texts. Here the mutations act on the YAML text of real
problem files, the way a user damages one: a deleted line, a number
replaced by NaN, infinity, a huge or negative value, a value of another
type, truncated text, random bytes, a duplicated or re-indented line.

* Invalid results must raise the package's own SceneError, whose message
  starts with the file name; never another exception.
* Whatever loads must also mesh and build a model (or raise SceneError),
  and its rest pose must have a finite energy.
* Value-preserving rewrites (numbers in another notation, sections in
  another order, comments and blank lines) must load to an equal scene, and
  a physical constant changed to another positive value must load to the
  same scene with just that value changed.

Example counts are bounded so the module runs in seconds.
"""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from hardlib import HARD, SHIPPED
from plush_opt.base.errors import SceneError
from plush_opt.base.geometry import ring_area
from plush_opt.io import load_scene
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model

pytestmark = pytest.mark.slow  # many mutated files loaded, meshed and modelled

OUTLINE_SOURCES = ("gripper", "hexapod", "hexapod_leg", "near_inversion", "stiff_tendons",
                   "slack_taut", "contradictory_targets", "unreachable_target")
EXPLICIT_SOURCES = ("inverted_explicit", "sliver_explicit", "underpinned_hinge")


def _text(name: str) -> str:
    path = SHIPPED / f"{name}.yaml"
    return (path if path.exists() else HARD / f"{name}.yaml").read_text()


TEXTS = {name: _text(name) for name in OUTLINE_SOURCES + EXPLICIT_SOURCES}
# a number token: not part of a word, a name like hexapod_leg or plush-opt/1
NUMBER = re.compile(r"(?<![\w./-])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?(?![\w./-])")
REPLACEMENTS = (
    ".nan", "nan", ".inf", "-.inf", "1e400", "-1e400", "1e308", "-1", "-0.0", "0", "0.0",
    "1e-320", "123456789012345678901234567890", "0x1F", "1_000", "'12'", "abc", "[1, 2]",
    "{a: 1}", "null", "~", "true", "no", "2001-12-14", "!!binary aGk=", "*x", "&y 3", "[]",
)
SETTINGS = settings(max_examples=300, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@st.composite
def damaged(draw):
    """(source name, damaged bytes) after 1 to 3 mutations."""
    name = draw(st.sampled_from(sorted(TEXTS)))
    text = TEXTS[name]
    data = text.encode()
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["number", "number_float", "delete_line", "duplicate_line",
                                     "indent_line", "truncate", "bytes", "swap_lines"]))
        text = data.decode("utf-8", errors="replace")
        lines = text.splitlines(keepends=True)
        if kind in ("number", "number_float"):
            tokens = list(NUMBER.finditer(text))
            if not tokens:
                continue
            m = draw(st.sampled_from(tokens))
            if kind == "number":
                new = draw(st.sampled_from(REPLACEMENTS))
            else:
                new = repr(draw(st.floats(allow_nan=True, allow_infinity=True, width=64)))
            text = text[:m.start()] + new + text[m.end():]
            data = text.encode()
        elif kind == "delete_line" and lines:
            del lines[draw(st.integers(0, len(lines) - 1))]
            data = "".join(lines).encode()
        elif kind == "duplicate_line" and lines:
            i = draw(st.integers(0, len(lines) - 1))
            lines.insert(i, lines[i])
            data = "".join(lines).encode()
        elif kind == "indent_line" and lines:
            i = draw(st.integers(0, len(lines) - 1))
            lines[i] = draw(st.sampled_from(["", " ", "  ", "\t", "      "])) + lines[i].lstrip(" ")
            data = "".join(lines).encode()
        elif kind == "swap_lines" and len(lines) > 1:
            i = draw(st.integers(0, len(lines) - 2))
            lines[i], lines[i + 1] = lines[i + 1], lines[i]
            data = "".join(lines).encode()
        elif kind == "truncate":
            data = data[: draw(st.integers(0, len(data)))]
        elif kind == "bytes":
            at = draw(st.integers(0, len(data)))
            data = data[:at] + draw(st.binary(min_size=1, max_size=12)) + data[at:]
    return name, data


def _triangle_estimate(scene) -> float:
    if scene.outline is None or scene.max_area is None:
        return 0.0
    return abs(ring_area(scene.outline)) / scene.max_area


def _load_mesh_model(path):
    """load_scene, then build_mesh and build_model when the mesh is small;
    every error on the way must be a SceneError naming the file."""
    try:
        scene = load_scene(path)
    except SceneError as exc:
        assert str(exc).startswith(f"{path.name}: "), str(exc)
        event("refused by the loader")
        return None
    if _triangle_estimate(scene) > 20_000 or (scene.min_angle or 0) > 30:
        event("loaded; too large to mesh here")
        return scene                   # valid, but too slow to mesh in a fuzz loop
    try:
        mesh = build_mesh(scene)
        model = build_model(scene, mesh)
    except SceneError as exc:
        assert str(exc).startswith(f"{path.name}: "), str(exc)
        event("refused by the mesher or the model")
        return scene
    event("loaded, meshed and modelled")
    assert np.all(mesh.areas > 0)
    ev = model.evaluate(model.X, scene.contraction, order=1)
    assert ev.admissible and math.isfinite(ev.energy) and np.all(np.isfinite(ev.gradient))
    return scene


@SETTINGS
@given(damaged())
def test_damaged_problem_files_load_or_raise_scene_error(tmp_path_factory, case):
    name, data = case
    path = tmp_path_factory.mktemp("fuzz") / f"{name}.yaml"
    path.write_bytes(data)
    _load_mesh_model(path)             # anything but SceneError fails the test


# -- value-preserving rewrites ---------------------------------------------------

def _renotate(token: str, style: int) -> str:
    v = float(token)
    if style == 0:
        return repr(v)                                  # 10 -> 10.0
    if style == 1:
        return f"{v:.17e}"                              # 10 -> 1.00000000000000000e+01
    if style == 2:
        return f"+{token}" if not token.startswith(("-", "+")) else token
    return token


def _sections(text: str) -> tuple[str, list[str]]:
    """Leading comments, then the top-level blocks (each with the comment
    lines just above it)."""
    lines = text.splitlines(keepends=True)
    head = []
    while lines and (lines[0].startswith("#") or not lines[0].strip()):
        head.append(lines.pop(0))
    blocks, pending = [], []
    for line in lines:
        if line.strip() and not line[0].isspace() and not line.startswith("#"):
            blocks.append(pending + [line])
            pending = []
        elif not line.strip() or line.startswith("#"):
            pending.append(line)
        else:
            blocks[-1].extend(pending + [line])
            pending = []
    if pending:
        blocks[-1].extend(pending)
    return "".join(head), ["".join(b) for b in blocks]


def _data_spans(text: str):
    """(start, end) of the text that is YAML data: not comments and not the
    free-text description block."""
    spans, pos, in_description = [], 0, False
    for line in text.splitlines(keepends=True):
        start, pos = pos, pos + len(line)
        if in_description and (line[:1].isspace() or not line.strip()):
            continue
        in_description = line.startswith("description:")
        if in_description or line.lstrip().startswith("#"):
            continue
        cut = line.find(" #")
        spans.append((start, start + (cut if cut >= 0 else len(line))))
    return spans


@st.composite
def rewritten(draw):
    name = draw(st.sampled_from(OUTLINE_SOURCES))
    text = TEXTS[name]
    styles = draw(st.lists(st.integers(0, 3), min_size=1, max_size=200))
    pieces, last, i = [], 0, 0
    for a, b in _data_spans(text):
        for m in NUMBER.finditer(text, a, b):
            pieces.append(text[last:m.start()])
            pieces.append(_renotate(m.group(), styles[i % len(styles)]))
            last, i = m.end(), i + 1
    text = "".join(pieces) + text[last:]
    head, blocks = _sections(text)
    order = draw(st.permutations(range(len(blocks))))
    blocks = [blocks[i] for i in order]
    blocks = [b if b.endswith("\n") else b + "\n" for b in blocks]
    if draw(st.booleans()):
        blocks = [b + "\n# a comment between sections\n\n" for b in blocks]
    return name, head + "".join(blocks)


@settings(max_examples=30, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(rewritten())
def test_value_preserving_rewrites_load_to_the_same_scene(tmp_path_factory, case):
    name, text = case
    path = tmp_path_factory.mktemp("same") / f"{name}.yaml"
    path.write_text(text)
    original = tmp_path_factory.mktemp("orig") / f"{name}.yaml"
    original.write_text(TEXTS[name])
    assert load_scene(path) == load_scene(original)


POSITIVE = ("youngs_modulus", "thickness", "smoothing")


@settings(max_examples=30, deadline=None, derandomize=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(OUTLINE_SOURCES), st.sampled_from(POSITIVE),
       st.floats(1e-3, 1e3, allow_nan=False, allow_infinity=False))
def test_changed_positive_constant_loads_meshes_and_models(tmp_path_factory, name, key, factor):
    text = TEXTS[name]
    m = re.search(rf"^(\s*{key}:\s*)(\S+)", text, flags=re.M)
    value = float(m.group(2)) * factor
    path = tmp_path_factory.mktemp("valid") / f"{name}.yaml"
    path.write_text(text[:m.start(2)] + repr(value) + text[m.end(2):])
    scene = load_scene(path)
    base = load_scene(SHIPPED / f"{name}.yaml" if (SHIPPED / f"{name}.yaml").exists()
                      else HARD / f"{name}.yaml")
    if key == "smoothing":
        assert scene == base.replace(tendon_smoothing=value)
    elif key == "thickness":
        assert scene.material.thickness == value
        assert scene.replace(material=base.material) == base
    else:
        assert scene.material.mu == pytest.approx(base.material.mu * factor, rel=1e-12)
        assert scene.replace(material=base.material) == base
    assert _load_mesh_model(path) is not None
