"""Messages that name the right key and stay short (issue 34, item 9)."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from plush_opt.base.errors import SceneError
from plush_opt.io import load_scene
from plush_opt.io.checker import Checker
from plush_opt.io.mesh_input import mesh_section

ROOT = Path(__file__).resolve().parents[1]
BASE = yaml.safe_load((ROOT / "problems" / "cantilever.yaml").read_text())


def _section_error(mesh) -> str:
    with pytest.raises(SceneError) as exc:
        mesh_section(Checker("p.yaml"), mesh)
    return str(exc.value)


@pytest.mark.parametrize("at", [0.0, 1e6, 1e11, -1e11])
def test_a_valid_rectangle_far_from_the_origin_is_not_flat(at):
    rect = [[at, at], [at + 200, at], [at + 200, at + 10], [at, at + 10]]
    geo = mesh_section(Checker("p.yaml"), {"outline": rect})
    assert geo["outline"].shape == (4, 2)


@pytest.mark.parametrize("at", [0.0, 1e11])
def test_a_flat_ring_is_still_refused(at):
    flat = [[at, at], [at + 100, at], [at + 200, at + 1e-9], [at + 100, at + 2e-9]]
    if at:   # at 1e11 a point 1e-9 off the line is the line itself: a zigzag on it
        flat = [[at, at], [at + 100, at], [at + 200, at], [at + 100, at]]
    msg = _section_error({"outline": flat})
    assert msg.startswith("p.yaml: mesh.outline"), msg


def test_a_nodes_list_one_short_gives_the_real_count():
    nodes = [[0, 0], [1, 0], [1, 1], [0, 1]]
    msg = _section_error({"nodes": nodes[:-1], "triangles": [[0, 1, 2], [0, 2, 3]]})
    assert msg == ("p.yaml: mesh.triangles[1][2]: node index 3 out of range 0..2 "
                   "(mesh.nodes has 3 nodes)"), msg


def test_a_negative_node_index_still_names_the_triangle():
    msg = _section_error({"nodes": [[0, 0], [1, 0], [1, 1]], "triangles": [[0, 1, -1]]})
    assert msg.startswith("p.yaml: mesh.triangles[0][2]: node index -1"), msg


LONG = "n" * 4000


@pytest.mark.parametrize("edit", [
    lambda d: d.__setitem__("name", LONG + "/"),
    lambda d: d["tendons"]["list"][0].__setitem__("winch", LONG),
    lambda d: d["winches"][0].__setitem__("name", LONG),
    lambda d: d["material"].__setitem__("model", LONG),
    lambda d: d.__setitem__("format", LONG),
])
def test_a_long_value_is_echoed_capped(tmp_path, edit):
    doc = copy.deepcopy(BASE)
    edit(doc)
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(SceneError) as exc:
        load_scene(path)
    msg = str(exc.value)
    assert len(msg) < 400, (len(msg), msg[:200])
    assert "4000 characters" in msg or "4001 characters" in msg, msg
