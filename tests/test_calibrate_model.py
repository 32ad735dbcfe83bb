"""Calibration's foundations: assembly offsets in the model, the exact mixed
derivatives d2E/dx dp, marker sensitivities against fresh solves, and the
measurement file's loader."""

from __future__ import annotations

import functools
import textwrap

import numpy as np
import pytest
import yaml

from plush_opt.base.errors import SceneError
from plush_opt.fit.parameters import Values, mixed_columns, parse_fit, scene_with, to_theta
from plush_opt.fit.predict import Predictor
from plush_opt.io import load_scene
from plush_opt.io.measurement import load_measurements
from plush_opt.io.problem_file import scene_from_dict
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from shipped import ROOT

TENTACLE = ROOT / "problems" / "calib" / "tentacle.yaml"
COARSE = 16.0                     # mesh for the derivative checks: a few hundred dofs
ALL_KINDS = "youngs_modulus,poisson_ratio,tendon_stiffness,assembly_offset,winch_offset"


@functools.lru_cache(maxsize=None)
def tentacle(max_area=COARSE):
    scene = load_scene(TENTACLE)
    return scene, build_mesh(scene, max_area)


def offset_scene(offsets):
    scene, mesh = tentacle()
    values = Values.of_scene(scene)
    values = Values(values.youngs_modulus, values.poisson_ratio, values.tendon_stiffness,
                    np.asarray(offsets, float), values.winch_offset)
    return scene_with(scene, values), mesh


# -- assembly_offset in the scene and the model ------------------------------

def test_assembly_offset_defaults_to_zero_and_adds_to_the_assembly_length():
    scene, mesh = tentacle()
    assert all(t.assembly_offset == 0.0 for t in scene.tendons)
    base = build_model(scene, mesh)
    geometric = [np.linalg.norm(np.diff(t.path, axis=0), axis=1).sum() for t in scene.tendons]
    np.testing.assert_allclose(base.assembly_length, geometric, rtol=1e-12)
    shifted = build_model(*offset_scene([-0.5, 0.25, 1.0]))
    np.testing.assert_allclose(shifted.assembly_length - base.assembly_length, [-0.5, 0.25, 1.0],
                               atol=1e-12)


def test_assembly_offset_acts_like_minus_a_contraction_of_that_tendon():
    """G = l - (a + d) + c: a common offset d of a winch's tendons is that
    winch contracted by -d, exactly."""
    scene, mesh = tentacle()
    base = build_model(scene, mesh)
    shifted = build_model(*offset_scene([0.7, 0.0, 0.0]))     # 'top' is lift's only tendon
    x = base.X + 0.01 * np.sin(np.arange(base.n_dofs))
    a = shifted.evaluate(x, [3.0, 1.0])
    b = base.evaluate(x, [3.0 - 0.7, 1.0])
    assert a.energy == pytest.approx(b.energy, rel=1e-13)
    np.testing.assert_allclose(a.gradient, b.gradient, rtol=1e-10, atol=1e-12)


def test_assembly_offset_is_read_validated_and_written_to_the_result():
    doc = yaml.safe_load(TENTACLE.read_text())
    doc["tendons"]["list"][1]["assembly_offset"] = -0.4
    scene = scene_from_dict(doc, "t.yaml")
    assert [t.assembly_offset for t in scene.tendons] == [0.0, -0.4, 0.0]
    for bad, message in (("x", r"t\.yaml: tendons\.list\[1\]\.assembly_offset: expected a number"),
                         (-1000.0, r"t\.yaml: tendons\.list\[1\]\.assembly_offset: -1000\.0 leaves the "
                                   "tendon no length")):
        doc["tendons"]["list"][1]["assembly_offset"] = bad
        with pytest.raises(SceneError, match=message):
            scene_from_dict(doc, "t.yaml")


@pytest.mark.slow
def test_a_result_with_offsets_passes_the_spec_checker(tmp_path):
    from plush_opt.problem import from_scene
    from plush_opt.solve.result_file import result_dict
    from plush_opt.base.files import write_json_atomic
    from spec_checker import check_result
    scene, _ = offset_scene([-0.3, 0.2, 0.1])
    p = from_scene(scene, max_area=COARSE)
    eq = p.equilibrium({"lift": 4.0})
    doc = result_dict(p.model, p.targets, eq, method="forward", converged=eq.converged,
                      status=eq.status, total_s=0.0, solve_s=0.0, iterations=eq.iterations)
    assert [t["assembly_offset"] for t in doc["model"]["tendons"]["list"]] == [-0.3, 0.2, 0.1]
    write_json_atomic(tmp_path / "r.json", doc)
    check_result(tmp_path / "r.json")


# -- exact mixed derivatives ---------------------------------------------------

def test_offset_mixed_derivative_is_minus_the_contraction_one():
    model = build_model(*offset_scene([-0.5, 0.3, -0.2]))
    x = model.X + 0.05 * np.cos(np.arange(model.n_dofs))
    c = np.array([2.0, 3.0])
    per_tendon = model.parameter_mixed(x, c)["assembly_offset"]
    per_winch = np.stack([per_tendon[:, model.tendon_winch == w].sum(axis=1)
                          for w in range(model.n_winches)], axis=1)
    np.testing.assert_allclose(per_winch, -model.mixed(x, c), rtol=1e-12, atol=1e-14)


@pytest.mark.parametrize("kind", ALL_KINDS.split(","))
def test_mixed_columns_match_finite_differences_of_the_gradient(kind):
    scene, mesh = offset_scene([-0.5, 0.3, -0.2])
    params = parse_fit(scene, kind)
    base = Values.of_scene(scene)
    model = build_model(scene, mesh)
    x = model.X + 0.05 * np.cos(np.arange(model.n_dofs))
    c = np.array([2.0, 3.0])
    cols = mixed_columns(model, base, params, x, c)
    from plush_opt.fit.parameters import values_from_theta
    theta = np.array([to_theta(p, base.get(p)) for p in params])
    for j, p in enumerate(params):
        h = 1e-6 * max(1.0, abs(theta[j]))

        def grad(sign):
            t = theta.copy()
            t[j] += sign * h
            v = values_from_theta(base, params, t)
            return build_model(scene_with(scene, v), mesh).evaluate(x, c + v.winch_offset, 1).gradient

        fd = (grad(1) - grad(-1)) / (2 * h)
        assert np.linalg.norm(cols[:, j] - fd) <= 1e-6 * np.linalg.norm(fd), p.name


@pytest.mark.slow
def test_marker_sensitivities_match_finite_differences_of_fresh_solves(tmp_path):
    """dy/dtheta from H dx/dtheta = -d2E/dx dtheta against central
    differences of equilibria solved afresh, for every parameter kind."""
    scene, mesh = tentacle()
    meas_path = tmp_path / "m.yaml"
    meas_path.write_text(yaml.safe_dump({
        "format": "plush-opt-measurements/1", "problem": str(TENTACLE),
        "markers": [[40, 6], [100, 0], [70, -6]],
        "poses": [{"contractions": {"lift": 5.0, "curl": 1.0}, "positions": [[0, 0] for _ in range(3)]},
                  {"contractions": {"lift": 0.5, "curl": 6.0}, "positions": [[0, 0] for _ in range(3)]}]}))
    meas = load_measurements(meas_path)
    params = parse_fit(meas.scene, ALL_KINDS)
    base = Values.of_scene(meas.scene)
    base = Values(base.youngs_modulus, base.poisson_ratio, base.tendon_stiffness,
                  np.array([-0.4, 0.3, -0.2]), np.array([0.2, -0.1]))
    theta = np.array([to_theta(p, base.get(p)) for p in params])
    J = Predictor(meas, mesh, params, base)(theta).jacobian
    for j, p in enumerate(params):
        h = 1e-5
        e = np.zeros_like(theta)
        e[j] = h
        y_plus = Predictor(meas, mesh, params, base)(theta + e, jacobian=False).y
        y_minus = Predictor(meas, mesh, params, base)(theta - e, jacobian=False).y
        fd = ((y_plus - y_minus) / (2 * h)).reshape(J.shape[0], -1)
        assert np.linalg.norm(J[:, :, j] - fd) <= 1e-5 * np.linalg.norm(fd), p.name


# -- the measurement file --------------------------------------------------------

GOOD = textwrap.dedent(f"""\
    format: plush-opt-measurements/1
    problem: {TENTACLE}
    markers: [[50, 0], [100, 6]]
    poses:
      - contractions: {{lift: 2.0, curl: 0.0}}
        positions: [[50.1, 0.3], null]
      - contractions: {{lift: 0.0, curl: 4.0}}
        positions: [[49.8, -2.0], [95.0, -10.0]]
    sigma: 0.5
    """)


def test_a_measurement_file_loads(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(GOOD)
    m = load_measurements(path)
    assert m.n_poses == 2 and m.n_markers == 2 and m.sigma == 0.5
    np.testing.assert_array_equal(m.contractions, [[2.0, 0.0], [0.0, 4.0]])
    assert m.seen.tolist() == [[True, False], [True, True]]
    assert m.scene.name == "tentacle"


def test_a_relative_problem_path_is_relative_to_the_measurement_file(tmp_path):
    (tmp_path / "scene.yaml").write_text(TENTACLE.read_text())
    (tmp_path / "sub").mkdir()
    path = tmp_path / "sub" / "m.yaml"
    path.write_text(GOOD.replace(str(TENTACLE), "../scene.yaml").replace("sigma: 0.5\n", ""))
    m = load_measurements(path)
    assert m.problem_path == (tmp_path / "scene.yaml").resolve() and m.sigma == 1.0


@pytest.mark.parametrize("old, new, message", [
    ("plush-opt-measurements/1", "plush-opt/1", r"format: expected exactly 'plush-opt-measurements/1'"),
    ("sigma: 0.5", "sigma: 0", r"sigma: must be > 0, got 0"),
    ("sigma: 0.5", "sigmas: 0.5", r"sigmas: unknown key \(did you mean 'sigma'\?\)"),
    ("[[50, 0], [100, 6]]", "[[50, 0], [100, 60]]", r"markers\[1\]: point \(100\.0, 60\.0\) lies outside the body"),
    ("{lift: 2.0, curl: 0.0}", "{lift: 2.0}", r"poses\[0\]\.contractions\.curl: missing: every pose gives"),
    ("{lift: 2.0, curl: 0.0}", "{lift: 2.0, curl: 0.0, grip: 1}",
     r"poses\[0\]\.contractions\.grip: unknown key"),
    ("{lift: 0.0, curl: 4.0}", "{lift: 0.0, curl: 40.0}",
     r"poses\[1\]\.contractions\.curl: 40 is outside the winch's bounds"),
    ("[[50.1, 0.3], null]", "[[50.1, 0.3]]", r"poses\[0\]\.positions: expected 2 entries"),
    ("[[49.8, -2.0], [95.0, -10.0]]", "[[49.8, -2.0], [95.0, x]]",
     r"poses\[1\]\.positions\[1\]\[1\]: expected a number, got string 'x'"),
    ("positions: [[50.1, 0.3], null]", "where: 1", r"poses\[0\]\.where: unknown key"),
])
def test_bad_measurement_files_get_one_line_naming_key_and_index(tmp_path, old, new, message):
    path = tmp_path / "m.yaml"
    assert old in GOOD
    path.write_text(GOOD.replace(old, new, 1))
    with pytest.raises(SceneError, match="^m\\.yaml: " + message):
        load_measurements(path)


def test_missing_problem_and_all_unseen_are_errors(tmp_path):
    path = tmp_path / "m.yaml"
    path.write_text(GOOD.replace(str(TENTACLE), "nowhere.yaml"))
    with pytest.raises(SceneError, match=r"^m\.yaml: problem: no problem file 'nowhere\.yaml'"):
        load_measurements(path)
    path.write_text(GOOD.replace("[[50.1, 0.3], null]", "[null, null]")
                    .replace("[[49.8, -2.0], [95.0, -10.0]]", "[null, null]"))
    with pytest.raises(SceneError, match=r"^m\.yaml: poses: no marker is seen"):
        load_measurements(path)
    path.write_text(GOOD + "extra: &a 1\n")
    with pytest.raises(SceneError, match=r"^m\.yaml: line \d+: anchor &a"):
        load_measurements(path)


# -- the fitted file: a textual edit ------------------------------------------------

def test_edit_replaces_values_in_place_and_adds_missing_keys_at_the_mapping_indent():
    from plush_opt.fit.edit import edit_problem_text
    text = textwrap.dedent("""\
        a:
          k: 1.0   # keep me
          list:
            - {name: x, path: [[0, 0], [1, 1]]}  # flow
            - name: y
              path:
                - [0, 0]
                - [1, 1]
            - name: z
        b: 1
        """)
    new = edit_problem_text(text, {("a", "k"): 2.5e-7, ("a", "list", 0, "d"): 2.0,
                                   ("a", "list", 1, "d"): -3.0, ("a", "list", 2, "d"): 4.0})
    assert new == textwrap.dedent("""\
        a:
          k: 2.5e-07   # keep me
          list:
            - {name: x, path: [[0, 0], [1, 1]], d: 2.0}  # flow
            - name: y
              path:
                - [0, 0]
                - [1, 1]
              d: -3.0
            - name: z
              d: 4.0
        b: 1
        """)
    assert yaml.safe_load(new)["a"]["k"] == 2.5e-7     # a float in YAML 1.1 too


def test_fitted_lame_parameters_are_written_as_mu_and_lambda():
    from plush_opt.fit.edit import fitted_changes
    scene, _ = tentacle()
    params = parse_fit(scene, "youngs_modulus")
    doc = yaml.safe_load(TENTACLE.read_text())
    v = Values.of_scene(scene)
    del doc["material"]["youngs_modulus"], doc["material"]["poisson_ratio"]
    doc["material"].update(mu=v.mu, **{"lambda": v.lam})
    changes = fitted_changes(doc, v, v.assembly_offset, params)
    assert changes == {("material", "mu"): v.mu, ("material", "lambda"): v.lam}
