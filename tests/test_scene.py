"""Problem-file loader: valid files load, every kind of bad file raises
SceneError naming the file, the key and the list index."""

import copy
import math
import re

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import plush_opt.base.geometry
from plush_opt.base.errors import SceneError
from plush_opt.io import load_scene, scene_from_dict
from plush_opt.io.yaml_reader import MAX_FILE_BYTES
from plush_opt.fem.mesh import build_mesh
from plush_opt.io.scene import Scene


def valid():
    """A small valid problem as plain data (a fresh copy each call)."""
    return {
        "format": "plush-opt/1",
        "name": "finger",
        "description": "a finger with a hole",
        "mesh": {
            "outline": [[0, 0], [80, 0], [80, 20], [0, 20]],
            "holes": [[[30, 8], [40, 8], [40, 12], [30, 12]]],
            "max_area": 20.0,
            "min_angle": 25.0,
        },
        "material": {"model": "neo_hookean", "youngs_modulus": 0.02, "poisson_ratio": 0.3,
                     "thickness": 30.0, "density": 2.0e-11},
        "gravity": [0.0, -9810.0],
        "pins": {"stiffness": 1000.0, "at": [[0, 10]], "box": [0, 0, 1, 20]},
        "winches": [
            {"name": "grip", "bounds": [0.0, 25.0]},
            {"name": "left", "bounds": [2.0, 5.0], "frozen": True},
        ],
        "tendons": {
            "stiffness": 50.0,
            "smoothing": 0.05,
            "list": [
                {"name": "lower", "winch": "grip", "path": [[80, 2], [40, 3], [2, 2]]},
                {"name": "upper", "winch": "left", "path": [[80, 18], [40, 17], [2, 18]]},
            ],
        },
        "targets": [{"at": [80, 10], "to": [60, 40]}, {"at": [35, 8], "to": [0, 0], "weight": 2}],
        "points": [[50, 10], [50, 0]],
    }


def explicit():
    """A valid problem with an explicit two-triangle mesh."""
    d = valid()
    d["mesh"] = {"nodes": [[0, 0], [10, 0], [10, 10], [0, 10]],
                 "triangles": [[0, 1, 2], [0, 2, 3]]}
    del d["points"]
    d["pins"] = {"stiffness": 1.0, "at": [[0, 0]]}
    d["tendons"]["list"] = [{"name": "a", "winch": "grip", "path": [[10, 0], [0, 10]]},
                            {"name": "b", "winch": "left", "path": [[10, 10], [0, 0]]}]
    d["targets"] = [{"at": [5, 5], "to": [6, 6]}]
    return d


def load(d):
    return scene_from_dict(d, "t.yaml")


def raises(d, pattern):
    """The loader refuses ``d`` with a message starting with the file name
    and matching ``pattern``."""
    with pytest.raises(SceneError, match=pattern) as info:
        load(d)
    assert str(info.value).startswith("t.yaml: ")
    return str(info.value)


def write(tmp_path, text, name="p.yaml"):
    path = tmp_path / name
    path.write_text(text)
    return path


# -- valid input -------------------------------------------------------------

def test_valid_problem_loads_with_derived_values():
    s = load(valid())
    assert isinstance(s, Scene) and s.name == "finger" and s.source == "t.yaml"
    E, nu = 0.02, 0.3
    assert s.material.mu == pytest.approx(E / (2 * (1 + nu)), rel=1e-15)
    assert s.material.lam == pytest.approx(E * nu / ((1 + nu) * (1 - 2 * nu)), rel=1e-15)
    assert s.material.thickness == 30.0 and s.material.density == 2.0e-11
    assert s.winch_names == ("grip", "left")
    # contraction defaults to 0, or to the nearer bound when 0 is outside
    np.testing.assert_array_equal(s.contraction, [0.0, 2.0])
    np.testing.assert_array_equal(s.frozen, [False, True])
    assert [t.weight for t in s.targets] == [1.0, 2.0]
    assert s.outline.shape == (4, 2) and len(s.holes) == 1 and s.nodes is None
    assert s.pin_box.tolist() == [0, 0, 1, 20]
    assert not s.outline.flags.writeable and s.outline.flags.c_contiguous
    assert s.diameter == pytest.approx(math.hypot(80, 20))


def test_contraction_default_negative_range():
    d = valid()
    d["winches"][1]["bounds"] = [-5.0, -1.0]
    assert load(d).contraction.tolist() == [0.0, -1.0]


def test_lame_form_and_optional_nulls():
    d = valid()
    d["material"] = {"model": "neo_hookean", "mu": 1.0, "lambda": 2.0, "thickness": 1.0,
                     "density": None}
    d["gravity"] = None
    d["description"] = None
    s = load(d)
    assert (s.material.mu, s.material.lam, s.material.density) == (1.0, 2.0, None)
    assert s.gravity is None and s.description == ""


def test_load_scene_reads_file_and_names_it(tmp_path):
    path = write(tmp_path, yaml.safe_dump(valid()), "gripper.yaml")
    s = load_scene(path)
    assert s == load(valid()).replace(source="gripper.yaml")
    assert load_scene(str(path)).source == "gripper.yaml"


def test_exponent_floats_are_numbers(tmp_path):
    text = yaml.safe_dump(valid()).replace("2.0e-11", "2e-11")
    assert "2e-11" in text
    assert load_scene(write(tmp_path, text)).material.density == 2e-11


def test_explicit_mesh_accepts_either_orientation():
    d = explicit()
    d["mesh"]["triangles"] = [[0, 2, 1], [0, 2, 3]]     # first one clockwise
    s = load(d)
    assert s.triangles.tolist() == [[0, 2, 1], [0, 2, 3]]   # kept as given ...
    mesh = build_mesh(s)                                     # ... ordered CCW by the mesher
    assert mesh.triangles.tolist() == [[0, 1, 2], [0, 2, 3]]


def test_empty_optional_lists_are_allowed():
    d = valid()
    d["targets"], d["points"], d["mesh"]["holes"] = [], [], []
    s = load(d)
    assert s.targets == () and s.points.shape == (0, 2) and s.holes == ()
    d = valid()
    d["pins"]["at"] = []                                     # the box still pins
    assert load(d).pin_points.shape == (0, 2)


# -- files and YAML ------------------------------------------------------------

def _bad_files():
    from pathlib import Path
    return sorted((Path(__file__).parent / "bad").glob("*.yaml"))


@pytest.mark.parametrize("path", _bad_files(), ids=lambda p: p.stem)
def test_bad_files(path):
    first = path.read_text().splitlines()[0]
    assert first.startswith("# expect: ")
    with pytest.raises(SceneError, match=first[len("# expect: "):]) as info:
        load_scene(path)
    assert str(info.value).startswith(path.name + ": ")


def test_bad_dir_fixture_has_files(bad_dir):
    assert len(list(bad_dir.glob("*.yaml"))) >= 15


def test_billion_laughs_refused_quickly(bad_dir, reader_stages):
    # refused while composing, at the first anchor: the tree is never walked
    # nor built (walking the expanded aliases would take hours)
    reader_stages.forbidden = {"walk", "construct"}
    with pytest.raises(SceneError, match="anchors and aliases are not allowed"):
        load_scene(bad_dir / "billion_laughs.yaml")
    assert reader_stages[0] == "parse" and set(reader_stages) == {"parse", "node"}
    assert reader_stages.count("node") <= 3      # the mapping, its first key, the anchored list


def test_alias_refused(tmp_path):
    with pytest.raises(SceneError, match=r"line 2: alias \*x"):
        load_scene(write(tmp_path, "a: 1\nb: *x\n"))


def test_huge_file_refused_before_parsing(tmp_path, reader_stages):
    path = tmp_path / "huge.yaml"
    path.write_bytes(b"# padding\n" * 500_000)            # 5 MB
    reader_stages.forbidden = {"parse"}                    # refused before parsing
    with pytest.raises(SceneError, match=r"^huge\.yaml: file larger than 1048576 bytes"):
        load_scene(path)
    assert reader_stages == []
    reader_stages.forbidden = set()
    path.write_bytes(b"#" * MAX_FILE_BYTES)                 # exactly the limit is read
    with pytest.raises(SceneError, match="the file is empty"):
        load_scene(path)
    assert reader_stages == ["parse"]                       # parsed: all comment, no node


@pytest.mark.parametrize("text, pattern", [
    ("name: a\nname: b\n", r"line 2: name: duplicate key \(first on line 1\)"),
    ("mesh:\n  outline: 1\n  outline: 2\n", r"line 3: mesh\.outline: duplicate key"),
    ("winches:\n- {name: a, name: b}\n", r"line 2: winches\[0\]\.name: duplicate key"),
    ("1: a\n1.0: b\n", r"line 2: duplicate key 1\.0"),
])
def test_duplicate_keys(tmp_path, text, pattern):
    with pytest.raises(SceneError, match=pattern):
        load_scene(write(tmp_path, text))


@pytest.mark.parametrize("text, pattern", [
    ("", r"^p\.yaml: the file is empty"),
    ("# only a comment\n", r"the file is empty"),
    ("- 1\n- 2\n", r"the document must be a mapping of keys, got a list of 2"),
    ("just text\n", r"the document must be a mapping of keys, got string"),
    ("a: 1\n---\nb: 2\n", r"line 2: invalid YAML"),
    ("a: [1, 2\nb: 3\n", r"line \d: invalid YAML"),
    ("a:\tb\n  - c: d\n", r"line \d: invalid YAML"),
    ("? [1, 2]\n: x\n", r"line 1: a mapping key must be a plain value"),
    ("a: !!binary aGk=\n", r"a: unknown key"),
])
def test_malformed_yaml(tmp_path, text, pattern):
    with pytest.raises(SceneError, match=pattern):
        load_scene(write(tmp_path, text))


@pytest.mark.parametrize("depth", [400, 5000])
def test_deep_nesting_is_one_clear_error(tmp_path, depth):
    """Deep nesting is refused with one line naming the file and the
    nesting, whichever layer notices first (the YAML parser's own depth
    limit or the loader's recursion guard); the wording of the parser's
    message is not the loader's to promise."""
    text = "a: " + "[" * depth + "]" * depth + "\n"
    with pytest.raises(SceneError) as info:
        load_scene(write(tmp_path, text))
    msg = str(info.value)
    assert msg.startswith("p.yaml: ") and "\n" not in msg
    assert re.search(r"nest(ed|ing)", msg), msg
    # raised `from None`: the CLI prints this line, never a chained traceback
    assert info.value.__cause__ is None and info.value.__suppress_context__


def test_missing_file_directory_and_binary(tmp_path):
    with pytest.raises(SceneError, match=r"^nope\.yaml: no such file"):
        load_scene(tmp_path / "nope.yaml")
    with pytest.raises(SceneError, match=r"is a directory"):
        load_scene(tmp_path)
    path = tmp_path / "bin.yaml"
    path.write_bytes(b"name: \xff\xfe\n")
    with pytest.raises(SceneError, match=r"^bin\.yaml: not UTF-8 text"):
        load_scene(path)


# -- validation: one case per rule ---------------------------------------------

def _set(path, value):
    """Mutation that sets d[path...] = value (path: tuple of keys/indices)."""
    def apply(d):
        target = d
        for k in path[:-1]:
            target = target[k]
        target[path[-1]] = value
    return apply


def _del(*path):
    def apply(d):
        target = d
        for k in path[:-1]:
            target = target[k]
        del target[path[-1]]
    return apply


T0 = ("tendons", "list", 0)

CASES = [
    # top level
    ("format-wrong", _set(("format",), "plush-opt/2"), r"^t\.yaml: format: expected exactly 'plush-opt/1'"),
    ("format-number", _set(("format",), 1), r"format: expected a string, got number 1"),
    ("format-missing", _del("format"), r"format: missing required key"),
    ("name-pattern", _set(("name",), "my gripper"), r"name: 'my gripper' must match"),
    ("name-number", _set(("name",), 12), r"name: expected a string, got number 12"),
    ("name-empty", _set(("name",), ""), r"name: '' must match"),
    ("description-list", _set(("description",), ["a"]), r"description: expected a string"),
    ("unknown-top", _set(("tendon",), {}), r"tendon: unknown key \(did you mean 'tendons'\?\); "
                                          r"allowed keys: format, name"),
    ("unknown-nonstring-key", _set((1,), 2), r"t\.yaml: 1: unknown key"),
    ("required-null", _set(("material",), None), r"material: required key has no value"),
    # mesh
    ("mesh-both", _set(("mesh", "nodes"), [[0, 0], [1, 0], [0, 1]]), r"mesh\.nodes: give either"),
    ("mesh-none", _set(("mesh",), {"max_area": 1.0}), r"mesh: give mesh\.outline, or mesh\.nodes"),
    ("mesh-unknown", _set(("mesh", "outlines"), []), r"mesh\.outlines: unknown key \(did you mean 'outline'"),
    ("mesh-not-mapping", _set(("mesh",), [1]), r"mesh: expected a mapping, got a list of 1"),
    ("outline-two-points", _set(("mesh", "outline"), [[0, 0], [1, 0]]), r"mesh\.outline: expected at least 3"),
    ("outline-empty", _set(("mesh", "outline"), []), r"mesh\.outline: empty list"),
    ("outline-bad-point", _set(("mesh", "outline", 2), [80, 20, 0]), r"mesh\.outline\[2\]: expected a point \[x, y\]"),
    ("outline-string", _set(("mesh", "outline", 2, 1), "20"), r"mesh\.outline\[2\]\[1\]: expected a number, got string '20'"),
    ("outline-bool", _set(("mesh", "outline", 2, 1), True), r"mesh\.outline\[2\]\[1\]: expected a number, got boolean true"),
    ("outline-inf", _set(("mesh", "outline", 2, 1), math.inf), r"mesh\.outline\[2\]\[1\]: expected a finite number, got inf"),
    ("outline-crossing", _set(("mesh", "outline"), [[0, 0], [80, 20], [80, 0], [0, 20]]), r"mesh\.outline: not a simple polygon"),
    ("outline-touching", _set(("mesh", "outline"), [[0, 0], [80, 0], [80, 20], [40, 0], [0, 20]]),
     r"mesh\.outline: not a simple polygon"),
    ("outline-repeat", _set(("mesh", "outline"), [[0, 0], [80, 0], [80, 0], [80, 20], [0, 20]]),
     r"mesh\.outline\[2\]: point \(80\.0, 0\.0\) repeats the previous point"),
    ("outline-closed", _set(("mesh", "outline"), [[0, 0], [80, 0], [80, 20], [0, 20], [0, 0]]),
     r"mesh\.outline\[4\]: repeats the first point"),
    ("outline-backtrack", _set(("mesh", "outline"), [[0, 0], [80, 0], [40, 0], [80, 20], [0, 20]]),
     r"mesh\.outline\[1\]: the polygon turns back on itself"),
    ("hole-outside", _set(("mesh", "holes", 0), [[100, 1], [110, 1], [110, 5]]), r"mesh\.holes\[0\]: lies outside the outline"),
    ("hole-crossing", _set(("mesh", "holes", 0), [[-5, 8], [40, 8], [40, 12]]), r"mesh\.holes\[0\]: crosses or touches the outline"),
    ("hole-touching", _set(("mesh", "holes", 0), [[0, 8], [40, 8], [40, 12]]), r"mesh\.holes\[0\]: crosses or touches the outline"),
    ("hole-overlap", _set(("mesh", "holes"), [[[30, 8], [40, 8], [40, 12], [30, 12]], [[35, 9], [45, 9], [45, 11]]]),
     r"mesh\.holes\[1\]: crosses or touches mesh\.holes\[0\]"),
    ("hole-nested", _set(("mesh", "holes"), [[[30, 8], [40, 8], [40, 12], [30, 12]], [[31, 9], [33, 9], [33, 11]]]),
     r"mesh\.holes\[1\]: lies inside mesh\.holes\[0\]"),
    ("hole-self-crossing", _set(("mesh", "holes", 0), [[30, 8], [40, 12], [40, 8], [30, 12]]),
     r"mesh\.holes\[0\]: not a simple polygon"),
    ("hole-short", _set(("mesh", "holes", 0), [[30, 8], [40, 8]]), r"mesh\.holes\[0\]: expected at least 3"),
    ("holes-not-list", _set(("mesh", "holes"), 3), r"mesh\.holes: expected a list of polygons, got number 3"),
    ("max-area-zero", _set(("mesh", "max_area"), 0), r"mesh\.max_area: must be > 0, got 0\.0"),
    ("max-area-string", _set(("mesh", "max_area"), "big"), r"mesh\.max_area: expected a number"),
    ("min-angle-negative", _set(("mesh", "min_angle"), -1), r"mesh\.min_angle: must be >= 0"),
    ("min-angle-too-big", _set(("mesh", "min_angle"), 40), r"mesh\.min_angle: must be <= 34 degrees"),
    # material
    ("material-unknown", _set(("material", "E"), 1.0), r"material\.E: unknown key"),
    ("material-model", _set(("material", "model"), "linear"), r"material\.model: unknown model 'linear'"),
    ("material-model-missing", _del("material", "model"), r"material\.model: missing required key"),
    ("E-zero", _set(("material", "youngs_modulus"), 0), r"material\.youngs_modulus: must be > 0"),
    ("E-negative", _set(("material", "youngs_modulus"), -1.0), r"material\.youngs_modulus: must be > 0, got -1\.0"),
    ("E-bool", _set(("material", "youngs_modulus"), False), r"material\.youngs_modulus: expected a number, got boolean false"),
    ("E-nan", _set(("material", "youngs_modulus"), math.nan), r"material\.youngs_modulus: expected a finite number, got nan"),
    ("E-string", _set(("material", "youngs_modulus"), "0.02"), r"material\.youngs_modulus: expected a number, got string '0\.02'"),
    ("nu-half", _set(("material", "poisson_ratio"), 0.5), r"material\.poisson_ratio: must be < 0\.5"),
    ("nu-negative", _set(("material", "poisson_ratio"), -0.1), r"material\.poisson_ratio: must be >= 0"),
    ("nu-missing", _del("material", "poisson_ratio"), r"material\.poisson_ratio: required with material\.youngs_modulus"),
    ("E-and-mu", _set(("material", "mu"), 1.0), r"material\.mu: give either youngs_modulus and poisson_ratio, or mu and lambda"),
    ("no-elasticity", lambda d: [d["material"].pop(k) for k in ("youngs_modulus", "poisson_ratio")],
     r"material: give youngs_modulus and poisson_ratio, or mu and lambda"),
    ("thickness-zero", _set(("material", "thickness"), 0.0), r"material\.thickness: must be > 0"),
    ("thickness-missing", _del("material", "thickness"), r"material\.thickness: missing required key"),
    ("density-negative", _set(("material", "density"), -2.0), r"material\.density: must be > 0"),
    ("density-needed", _del("material", "density"), r"material\.density: required when gravity is given"),
    ("gravity-scalar", _set(("gravity",), 9.81), r"gravity: expected a point \[x, y\], got number 9\.81"),
    ("gravity-string", _set(("gravity", 1), "down"), r"gravity\[1\]: expected a number"),
    # pins
    ("pins-none", _set(("pins",), {"stiffness": 1.0}), r"pins: no pins: give pins\.at or pins\.box"),
    ("pins-empty", _set(("pins",), {"stiffness": 1.0, "at": []}), r"pins\.at: empty list"),
    ("pins-stiffness", _set(("pins", "stiffness"), 0), r"pins\.stiffness: must be > 0"),
    ("pins-stiffness-missing", _del("pins", "stiffness"), r"pins\.stiffness: missing required key"),
    ("pin-outside", _set(("pins", "at", 0), [-1, 10]), r"pins\.at\[0\]: point \(-1\.0, 10\.0\) lies outside the body"),
    ("pin-in-hole", _set(("pins", "at"), [[0, 10], [35, 10]]), r"pins\.at\[1\]: point \(35\.0, 10\.0\) lies outside the body"),
    ("box-unordered-x", _set(("pins", "box"), [1, 0, 0, 20]), r"pins\.box: xmin 1\.0 > xmax 0\.0"),
    ("box-unordered-y", _set(("pins", "box"), [0, 20, 1, 0]), r"pins\.box: ymin 20\.0 > ymax 0\.0"),
    ("box-short", _set(("pins", "box"), [0, 0, 1]), r"pins\.box: expected \[xmin, ymin, xmax, ymax\]"),
    ("box-nan", _set(("pins", "box", 2), math.nan), r"pins\.box\[2\]: expected a finite number"),
    ("pins-unknown", _set(("pins", "nodes"), [1]), r"pins\.nodes: unknown key; allowed keys: stiffness, at, box"),
    # winches
    ("winches-empty", _set(("winches",), []), r"winches: empty list"),
    ("winches-mapping", _set(("winches",), {"name": "grip"}), r"winches: expected a list of winches, got a mapping"),
    ("winch-duplicate", _set(("winches", 1, "name"), "grip"), r"winches\[1\]\.name: duplicate name 'grip' \(also winches\[0\]\)"),
    ("winch-name-missing", _del("winches", 1, "name"), r"winches\[1\]\.name: missing required key"),
    ("winch-name-number", _set(("winches", 1, "name"), 3), r"winches\[1\]\.name: expected a string"),
    ("winch-bounds-equal", _set(("winches", 1, "bounds"), [2.0, 2.0]), r"winches\[1\]\.bounds: lower 2\.0 must be < upper 2\.0"),
    ("winch-bounds-reversed", _set(("winches", 0, "bounds"), [25, 0]), r"winches\[0\]\.bounds: lower 25\.0 must be < upper 0\.0"),
    ("winch-bounds-short", _set(("winches", 0, "bounds"), [25]), r"winches\[0\]\.bounds: expected \[lower, upper\]"),
    ("winch-bounds-string", _set(("winches", 0, "bounds", 1), "max"), r"winches\[0\]\.bounds\[1\]: expected a number"),
    ("winch-contraction-out", _set(("winches", 1, "contraction"), 6.0), r"winches\[1\]\.contraction: 6\.0 is outside bounds \[2\.0, 5\.0\]"),
    ("winch-frozen-number", _set(("winches", 1, "frozen"), 1), r"winches\[1\]\.frozen: expected true or false, got number 1"),
    ("winch-unknown", _set(("winches", 1, "speed"), 1), r"winches\[1\]\.speed: unknown key"),
    ("winch-not-mapping", _set(("winches", 1), "grip"), r"winches\[1\]: expected a mapping, got string 'grip'"),
    ("winch-unused", lambda d: d["winches"].append({"name": "spare", "bounds": [0, 1]}),
     r"winches\[2\]: winch 'spare' has no tendons"),
    # tendons
    ("tendons-empty", _set(("tendons", "list"), []), r"tendons\.list: empty list"),
    ("tendons-stiffness", _set(("tendons", "stiffness"), -50), r"tendons\.stiffness: must be > 0"),
    ("tendons-smoothing", _set(("tendons", "smoothing"), 0), r"tendons\.smoothing: must be > 0"),
    ("tendons-smoothing-missing", _del("tendons", "smoothing"), r"tendons\.smoothing: missing required key"),
    ("tendons-unknown", _set(("tendons", "damping"), 1), r"tendons\.damping: unknown key"),
    ("tendon-unknown", _set(T0 + ("via",), []), r"tendons\.list\[0\]\.via: unknown key"),
    ("tendon-duplicate", _set(("tendons", "list", 1, "name"), "lower"), r"tendons\.list\[1\]\.name: duplicate name 'lower' \(also tendons\.list\[0\]\)"),
    ("tendon-winch", _set(T0 + ("winch",), "grab"), r"tendons\.list\[0\]\.winch: no winch named 'grab' \(winches: 'grip', 'left'\)"),
    ("tendon-path-short", _set(T0 + ("path",), [[80, 2]]), r"tendons\.list\[0\]\.path: expected at least 2 entries, got 1"),
    ("tendon-path-empty", _set(T0 + ("path",), []), r"tendons\.list\[0\]\.path: empty list"),
    ("tendon-repeat", _set(T0 + ("path",), [[80, 2], [40, 3], [40, 3]]),
     r"tendons\.list\[0\]\.path\[2\]: point \(40\.0, 3\.0\) repeats the previous via point"),
    ("via-outside", _set(T0 + ("path", 1), [81.0, 3.0]), r"^t\.yaml: tendons\.list\[0\]\.path\[1\]: point \(81\.0, 3\.0\) lies outside the body$"),
    ("via-in-hole", _set(("tendons", "list", 1, "path", 1), [35, 10]), r"tendons\.list\[1\]\.path\[1\]: point \(35\.0, 10\.0\) lies outside the body"),
    ("via-point-type", _set(T0 + ("path", 1), {"x": 1}), r"tendons\.list\[0\]\.path\[1\]: expected a point \[x, y\], got a mapping"),
    # targets and points
    ("target-outside", _set(("targets", 1, "at"), [90, 10]), r"targets\[1\]\.at: point \(90\.0, 10\.0\) lies outside the body"),
    ("target-weight", _set(("targets", 1, "weight"), 0), r"targets\[1\]\.weight: must be > 0"),
    ("target-to-missing", _del("targets", 0, "to"), r"targets\[0\]\.to: missing required key"),
    ("target-unknown", _set(("targets", 0, "tol"), 1), r"targets\[0\]\.tol: unknown key"),
    ("targets-mapping", _set(("targets",), {"at": [1, 1]}), r"targets: expected a list of targets"),
    ("point-outside", _set(("points", 1), [50, -0.5]), r"points\[1\]: point \(50\.0, -0\.5\) lies outside the body"),
    ("points-scalar", _set(("points",), 5), r"points: expected a list of points"),
]


@pytest.mark.parametrize("mutate, pattern", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_invalid(mutate, pattern):
    d = valid()
    mutate(d)
    raises(d, pattern)


EXPLICIT_CASES = [
    ("tri-out-of-range", _set(("mesh", "triangles", 1, 2), 4), r"mesh\.triangles\[1\]\[2\]: node index 4 out of range 0\.\.3"),
    ("tri-negative", _set(("mesh", "triangles", 1, 0), -1), r"mesh\.triangles\[1\]\[0\]: node index -1 out of range"),
    ("tri-float", _set(("mesh", "triangles", 1, 0), 0.0), r"mesh\.triangles\[1\]\[0\]: expected an integer, got number 0\.0"),
    ("tri-bool", _set(("mesh", "triangles", 1, 0), False), r"mesh\.triangles\[1\]\[0\]: expected an integer, got boolean"),
    ("tri-two", _set(("mesh", "triangles", 1), [0, 2]), r"mesh\.triangles\[1\]: expected three node indices"),
    ("tri-repeated-index", _set(("mesh", "triangles", 1), [0, 2, 2]), r"mesh\.triangles\[1\]: degenerate triangle \[0, 2, 2\]"),
    ("tri-zero-area", lambda d: (d["mesh"]["nodes"].append([5, 5]), d["mesh"]["triangles"].append([0, 4, 2])),
     r"mesh\.triangles\[2\]: degenerate triangle \[0, 4, 2\] \(zero area\)"),
    ("tri-duplicate", _set(("mesh", "triangles"), [[0, 1, 2], [0, 2, 3], [2, 1, 0]]),
     r"mesh\.triangles\[2\]: duplicate of mesh\.triangles\[0\]"),
    ("tri-empty", _set(("mesh", "triangles"), []), r"mesh\.triangles: empty list"),
    ("node-unused", lambda d: d["mesh"]["nodes"].append([20, 20]), r"mesh\.nodes\[4\]: node is not used by any triangle"),
    ("node-coincident", lambda d: (d["mesh"]["nodes"].append([10, 10]), d["mesh"]["triangles"].append([1, 4, 3])),
     r"mesh\.nodes\[4\]: coincides with mesh\.nodes\[2\]"),
    ("nodes-without-triangles", _del("mesh", "triangles"), r"mesh\.triangles: required with mesh\.nodes"),
    ("holes-with-nodes", _set(("mesh", "holes"), [[[1, 1], [2, 1], [2, 2]]]), r"mesh\.holes: only allowed with mesh\.outline"),
    ("max-area-with-nodes", _set(("mesh", "max_area"), 1.0), r"mesh\.max_area: only allowed with mesh\.outline"),
    ("via-not-node", _set(("tendons", "list", 1, "path", 1), [5, 5]),
     r"tendons\.list\[1\]\.path\[1\]: point \(5\.0, 5\.0\) is not a node of the explicit mesh"),
    ("pin-not-node", _set(("pins", "at", 0), [0, 1]), r"pins\.at\[0\]: point \(0\.0, 1\.0\) is not a node"),
    ("target-outside-explicit", _set(("targets", 0, "at"), [11, 5]), r"targets\[0\]\.at: point \(11\.0, 5\.0\) lies outside the body"),
]


@pytest.mark.parametrize("mutate, pattern", [c[1:] for c in EXPLICIT_CASES],
                         ids=[c[0] for c in EXPLICIT_CASES])
def test_invalid_explicit_mesh(mutate, pattern):
    d = explicit()
    load(d)                      # the base case is valid
    mutate(d)
    raises(d, pattern)


def test_points_on_the_boundary_are_inside():
    d = valid()
    d["pins"]["at"] = [[0, 10], [0, 0]]                  # on an edge, on a corner
    d["tendons"]["list"][0]["path"] = [[80, 2], [30, 10], [2, 2]]   # on the hole's edge
    d["targets"][0]["at"] = [40, 12]                     # a hole corner
    load(d)


def test_point_within_tolerance_outside_is_on_the_boundary():
    d = valid()
    diam = math.hypot(80, 20)
    d["points"] = [[50, -0.1e-9 * diam]]
    load(d)
    d["points"] = [[50, -10e-9 * diam]]
    raises(d, r"points\[0\]: point .* lies outside the body")


def test_error_is_value_error_subclass():
    d = valid()
    d["format"] = "x"
    with pytest.raises(ValueError):
        load(d)


def test_non_mapping_document():
    with pytest.raises(SceneError, match=r"^t\.yaml: the document must be a mapping"):
        scene_from_dict([1, 2], "t.yaml")


class _PairCount:
    """Pairs handed to the pairwise primitives of plush_opt.base.geometry:
    edge pairs the crossing sweep enumerates (with ``np.repeat``) and tests,
    and point x segment pairs of the point-in-body tests."""

    def __init__(self, monkeypatch):
        self.pairs = 0
        geometry = plush_opt.base.geometry
        sizes = {"segments_touch": lambda args, out: len(args[0]),
                 "_ring_contains": lambda args, out: len(args[0]) * len(args[1]),
                 "distance_to_segments": lambda args, out: len(args[0]) * len(args[1])}
        for name, size in sizes.items():
            monkeypatch.setattr(geometry, name, self._counted(getattr(geometry, name), size))
        monkeypatch.setattr(geometry, "np", _Numpy(repeat=self._counted(np.repeat, lambda args, out: out.size)))

    def _counted(self, f, size):
        def counted(*args, **kwargs):
            out = f(*args, **kwargs)
            self.pairs += size(args, out)
            return out
        return counted


class _Numpy:
    """numpy, with some functions replaced."""

    def __init__(self, **replaced):
        self.__dict__.update(replaced)

    def __getattr__(self, name):
        return getattr(np, name)


@pytest.mark.slow
def test_large_outline_loads_in_reasonable_time(tmp_path, monkeypatch, reader_stages):
    n = 20000
    th = np.linspace(0, 2 * np.pi, n, endpoint=False)
    d = valid()
    d["mesh"] = {"outline": np.c_[100 * np.cos(th), 100 * np.sin(th)].round(6).tolist()}
    d["pins"] = {"stiffness": 1.0, "at": [[0, 0]]}
    d["targets"] = [{"at": [10, 10], "to": [0, 0]}]
    d["points"] = [[99.9, 0]]
    for t in d["tendons"]["list"]:
        t["path"] = [[0, 1], [50, 5]] if t["name"] == "lower" else [[0, -1], [50, -5]]
    path = write(tmp_path, yaml.safe_dump(d, default_flow_style=True), "big.yaml")
    work = _PairCount(monkeypatch)
    s = load_scene(path)
    assert s.outline.shape == (20000, 2)
    # no quadratic work: every stage is linear (or n log n) in the vertices
    # (all pairs of them would be 2e8)
    nodes = reader_stages.count("node")
    assert nodes <= 3 * n + 1000, nodes                   # a list and two numbers per vertex
    assert 0 < work.pairs <= 25 * n, work.pairs


# -- property tests ------------------------------------------------------------

@st.composite
def problems(draw):
    """Random valid problems: star-shaped outlines (so segments from the
    centre to a vertex are inside), pins, tendons and targets inside."""
    n = draw(st.integers(3, 12))
    cx, cy = draw(st.floats(-100, 100)), draw(st.floats(-100, 100))
    scale = draw(st.floats(0.5, 200))
    gaps = np.array(draw(st.lists(st.floats(0.6, 1.0), min_size=n, max_size=n)))  # each < pi
    angles = 2 * np.pi * np.cumsum(gaps) / gaps.sum()
    radii = scale * np.array(draw(st.lists(st.floats(0.5, 1.0), min_size=n, max_size=n)))
    outline = np.c_[cx + radii * np.cos(angles), cy + radii * np.sin(angles)]
    if draw(st.booleans()):
        outline = outline[::-1]

    def inside():
        k = draw(st.integers(0, n - 1))
        s = draw(st.floats(0.05, 0.95))
        return [float(cx + s * (outline[k, 0] - cx)), float(cy + s * (outline[k, 1] - cy))]

    def path():
        pts = [inside()]
        for _ in range(draw(st.integers(1, 4))):
            p = inside()
            if math.dist(p, pts[-1]) > 1e-3 * scale:
                pts.append(p)
        if len(pts) < 2:
            pts.append(outline[0].tolist())
        return pts

    n_winches = draw(st.integers(1, 3))
    winches = []
    for i in range(n_winches):
        lo = draw(st.floats(-10, 10))
        hi = lo + draw(st.floats(0.1, 20))
        w = {"name": f"w{i}", "bounds": [lo, hi]}
        if draw(st.booleans()):
            w["contraction"] = draw(st.floats(lo, hi))
        winches.append(w)
    tendons = [{"name": f"t{i}", "winch": f"w{i % n_winches}", "path": path()}
               for i in range(n_winches + draw(st.integers(0, 2)))]
    area = 0.5 * abs(np.dot(outline[:, 0], np.roll(outline[:, 1], -1))
                     - np.dot(np.roll(outline[:, 0], -1), outline[:, 1]))
    d = {
        "format": "plush-opt/1",
        "name": "random",
        "mesh": {"outline": outline.tolist(),
                 "max_area": float(area / draw(st.integers(5, 60))),
                 "min_angle": draw(st.floats(0, 30))},
        "material": {"model": "neo_hookean", "youngs_modulus": draw(st.floats(1e-3, 1e3)),
                     "poisson_ratio": draw(st.floats(0, 0.49)), "thickness": 1.0},
        "pins": {"stiffness": 1.0, "at": [inside() for _ in range(draw(st.integers(1, 3)))]},
        "winches": winches,
        "tendons": {"stiffness": 1.0, "smoothing": 0.01, "list": tendons},
        "targets": [{"at": inside(), "to": [0.0, 0.0]} for _ in range(draw(st.integers(0, 3)))],
        "points": [outline[0].tolist()] + [inside() for _ in range(draw(st.integers(0, 3)))],
    }
    return d


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problems())
def test_random_valid_problems_load_and_mesh(d):
    s = load(d)
    mesh = build_mesh(s)
    assert np.all(mesh.areas > 0)
    tol = 1e-9 * s.diameter
    for tendon, nodes in zip(s.tendons, mesh.tendon_nodes):
        assert np.max(np.abs(mesh.X[nodes] - tendon.path)) <= tol
    np.testing.assert_allclose(np.einsum("kj,kjd->kd", mesh.target_beta,
                                         mesh.X[mesh.triangles[mesh.target_triangles]]),
                               np.array([t.at for t in s.targets]).reshape(-1, 2),
                               atol=1e-9 * s.diameter)


JUNK = st.one_of(
    st.none(), st.booleans(), st.integers(-10**30, 10**30),
    st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=8),
    st.lists(st.floats(-1e3, 1e3), max_size=4),
    st.lists(st.lists(st.floats(-1e3, 1e3), min_size=2, max_size=2), max_size=4),
    st.dictionaries(st.text(max_size=5), st.integers(), max_size=2),
)


def _paths(node, prefix=()):
    """Every key path into a plain-data document."""
    yield prefix
    if isinstance(node, dict):
        for k, v in node.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _paths(v, prefix + (i,))


@pytest.mark.slow
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problems(), st.data())
def test_random_mutations_load_or_raise_scene_error(d, data):
    d = copy.deepcopy(d)
    for _ in range(data.draw(st.integers(1, 3))):
        paths = [p for p in _paths(d) if p]
        path = data.draw(st.sampled_from(paths))
        parent = d
        for k in path[:-1]:
            parent = parent[k]
        action = data.draw(st.sampled_from(["replace", "delete", "add_key", "scale"]))
        if action == "replace":
            parent[path[-1]] = data.draw(JUNK)
        elif action == "delete":
            del parent[path[-1]]
        elif action == "add_key" and isinstance(parent, dict):
            parent[data.draw(st.text(min_size=1, max_size=6))] = data.draw(JUNK)
        elif action == "scale" and isinstance(parent[path[-1]], (int, float)) \
                and not isinstance(parent[path[-1]], bool):
            parent[path[-1]] *= data.draw(st.sampled_from([-1.0, 0.0, 1e-6, 3.0]))
        if not isinstance(d, dict):
            break
    try:
        s = load(d)
    except SceneError as exc:
        assert str(exc).startswith("t.yaml: ")
        return
    try:
        build_mesh(s)
    except SceneError as exc:
        assert str(exc).startswith("t.yaml: ")


@settings(max_examples=40, deadline=None)
@given(st.text(max_size=200))
def test_random_text_loads_or_raises_scene_error(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("fuzz") / "f.yaml"
    path.write_text(text, encoding="utf-8")
    with pytest.raises(SceneError, match=r"^f\.yaml: "):
        load_scene(path)


def test_message_names_key_and_index_like_the_docs():
    d = valid()
    d["tendons"]["list"][1]["path"][1] = [81.0, 3.0]
    msg = raises(d, re.escape("tendons.list[1].path[1]"))
    assert msg == "t.yaml: tendons.list[1].path[1]: point (81.0, 3.0) lies outside the body"


def test_docs_example_loads_and_meshes():
    from pathlib import Path
    text = (Path(__file__).parent.parent / "docs" / "problem-format.md").read_text()
    example = text.split("```yaml\n", 1)[1].split("```", 1)[0]
    s = scene_from_dict(yaml.load(example, Loader=yaml.SafeLoader), "example.yaml")
    assert s.name == "finger" and s.contraction.tolist() == [0.0, 4.0]
    assert build_mesh(s).n_nodes > 50


@pytest.mark.parametrize("name", ["billion_laughs.yaml", "duplicate_key.yaml", "merge_key.yaml",
                                  "syntax_error.yaml", "via_outside.yaml"])
def test_pure_python_yaml_path_gives_the_same_errors(bad_dir, monkeypatch, name):
    from plush_opt.io import yaml_reader
    path = bad_dir / name
    with pytest.raises(SceneError) as fast:
        load_scene(path)
    monkeypatch.setattr(yaml_reader, "_CParser", None)       # as without libyaml
    with pytest.raises(SceneError) as slow:
        load_scene(path)
    expect = path.read_text().splitlines()[0][len("# expect: "):]
    assert re.search(expect, str(slow.value)), str(slow.value)
    if name != "syntax_error.yaml":                            # parsers word these differently
        assert str(slow.value) == str(fast.value)


def test_numpy_input_is_accepted():
    d = valid()
    d["mesh"]["outline"] = np.array(d["mesh"]["outline"], dtype=float)
    d["tendons"]["list"][0]["path"] = np.array(d["tendons"]["list"][0]["path"])
    d["material"]["thickness"] = np.float64(30.0)
    d["winches"][1]["frozen"] = np.bool_(True)
    assert load(d) == load(valid())
