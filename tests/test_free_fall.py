"""A body that falls onto the floor (plush_opt/solve/free_fall.py), the
translation invariance the fall relies on, and the contact term's kept
pairs and its one even-odd test."""

from __future__ import annotations

import json
import logging

import numpy as np
import pytest

from plush_opt.fem import contact_geometry as geo
from plush_opt.fem.mesh import area_for_nodes, build_mesh
from plush_opt.fem.model import Model
from plush_opt.io import plausibility
from plush_opt.io.problem_file import load_scene, scene_from_dict
from plush_opt.solve import newton
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium

from shipped import ROOT
from test_contact import BLOCK

NO_EIG = EquilibriumOptions(eigenvalue=False)


def _block(lift: float, **contact):
    """The test block, its underside ``lift`` above d_hat (nothing touches at rest)."""
    doc = json.loads(json.dumps(BLOCK))
    doc["mesh"]["outline"] = [[x, y + 0.5 + lift] for x, y in doc["mesh"]["outline"]]
    doc["contact"].update(contact)
    doc["contact"] = {k: v for k, v in doc["contact"].items() if v is not None}
    doc["tendons"]["list"][0]["path"] = [[1, 5.0 + lift], [9, 5.0 + lift]]
    scene = scene_from_dict(doc, "block.yaml")
    return Model(scene, build_mesh(scene))


def _without_fall(monkeypatch):
    monkeypatch.setattr(newton, "free_fall", lambda model, c, x, ev: (x, ev))


@pytest.mark.parametrize("lift", [0.0, 3.0])
def test_a_body_above_the_floor_falls_onto_it_and_is_certified_where_newton_alone_puts_it(lift, monkeypatch):
    model = _block(lift)
    ev = model.evaluate(model.X, np.zeros(1))
    assert ev.unbalanced is not None                  # it hangs: nothing holds it yet
    eq = solve_equilibrium(model, np.zeros(1), options=NO_EIG)
    assert eq.converged, eq.status
    assert "escaped" not in eq.status
    weight = -model.f_gravity.reshape(-1, 2).sum(axis=0)[1]
    force = model.contact.evaluate(eq.x, np.zeros(1), 1).gradient.reshape(-1, 2).sum(axis=0)
    assert -force[1] == pytest.approx(weight, rel=1e-6)
    _without_fall(monkeypatch)
    alone = solve_equilibrium(model, np.zeros(1), options=NO_EIG)
    assert alone.converged, alone.status
    assert eq.iterations <= alone.iterations
    # the same certified pose (the horizontal place is free: compare shapes)
    d, d0 = eq.x.reshape(-1, 2), alone.x.reshape(-1, 2)
    assert np.abs((d - d.mean(axis=0)) - (d0 - d0.mean(axis=0))).max() <= 1e-7
    assert d[:, 1].min() == pytest.approx(d0[:, 1].min(), abs=1e-7)


def test_a_fall_never_passes_through_the_floor_and_keeps_every_gap_positive():
    model = _block(40.0)
    eq = solve_equilibrium(model, np.zeros(1), options=NO_EIG)
    assert eq.converged, eq.status
    gaps = model.contact.ground_gaps(eq.x)
    assert 0 < gaps.min() < model.contact.distance


def test_the_evaluation_at_the_falls_end_reuses_the_rest_and_matches_a_fresh_one():
    model = _block(3.0)
    c = np.zeros(1)
    ev = model.evaluate(model.X, c)
    assert ev.parts is not None                       # kept only for a body that falls
    x = model.X + np.tile([0.0, -3.2], model.n_nodes)  # 0.3 into the barrier's reach: it carries load
    moved, fresh = model.evaluate_moved(x, c, ev), model.evaluate(x, c)
    assert moved.admissible and fresh.admissible
    assert moved.energy == pytest.approx(fresh.energy, rel=1e-12)
    scale = np.abs(fresh.gradient).max()
    assert np.abs(moved.gradient - fresh.gradient).max() <= 1e-12 * scale
    assert abs(moved.hessian - fresh.hessian).max() <= 1e-12 * abs(fresh.hessian).max()
    assert (moved.unbalanced is None) == (fresh.unbalanced is None)
    # the reused parts are the translation-invariant terms' own
    for term, part in zip(model.terms, ev.parts):
        if term.translation_invariant:
            assert part.energy == pytest.approx(term.evaluate(x, c, 0).energy, rel=1e-12)


def test_a_body_held_by_the_floor_does_not_fall():
    model = _block(-0.5)                              # BLOCK as it is: within d_hat at rest
    assert model.evaluate(model.X, np.zeros(1)).unbalanced is None


def test_a_body_with_nothing_below_it_still_says_it_falls():
    # only an obstacle beside the body: nothing ahead of the fall, Newton's
    # own steps and the honest status as before
    model = _block(0.0, ground=None, obstacles=[{"name": "wall", "outline": [[20, 0], [30, 0], [30, 10], [20, 10]]}])
    eq = solve_equilibrium(model, np.zeros(1), options=EquilibriumOptions(eigenvalue=False, max_iterations=20))
    assert not eq.converged
    assert "falls" in eq.status


@pytest.mark.parametrize("name", ["hexapod_stand.yaml", "gripper_object.yaml"])
def test_terms_marked_translation_invariant_are(name):
    scene = load_scene(ROOT / "problems" / name)
    model = Model(scene, build_mesh(scene))
    rng = np.random.default_rng(0)
    x = model.X + 0.01 * rng.standard_normal(model.n_dofs)
    c = 0.5 * (scene.lower + scene.upper)
    shift = np.tile([3.0, -2.0], model.n_nodes)
    for term in model.terms:
        if term.translation_invariant:
            e0, e1 = term.evaluate(x, c, 1), term.evaluate(x + shift, c, 0)
            assert e1.energy == pytest.approx(e0.energy, rel=1e-12, abs=1e-12 * abs(e0.energy) + 1e-15)
            net = e0.gradient.reshape(-1, 2).sum(axis=0)
            assert np.abs(net).max() <= 1e-9 * max(np.abs(e0.gradient).max(), 1e-300)


def test_the_contact_term_keeps_the_last_poses_pairs():
    scene = load_scene(ROOT / "problems" / "gripper_object.yaml")
    term = Model(scene, build_mesh(scene)).contact
    x = np.asarray(build_mesh(scene).X, float).reshape(-1)
    first = term.pairs(x)
    assert term.pairs(x.copy()) is first              # same pose: kept
    assert not first.dofs.flags.writeable
    moved = x + 1e-3
    assert term.pairs(moved) is not first


def test_points_inside_the_segments_of_a_ring_with_a_hole():
    outer = np.array([[0, 0], [10, 0], [10, 10], [0, 10]], float)
    hole = np.array([[4, 4], [4, 6], [6, 6], [6, 4]], float)
    a = np.r_[outer, hole]
    b = np.r_[np.roll(outer, -1, axis=0), np.roll(hole, -1, axis=0)]
    pts = np.array([[1, 1], [5, 5], [11, 5], [3, 5]], float)
    assert geo.points_inside(pts, a, b).tolist() == [True, False, False, True]
    assert geo.points_in_polygon(pts, outer).tolist() == [True, True, False, True]


def test_a_node_count_search_announces_only_the_mesh_it_keeps(monkeypatch, caplog):
    scene = scene_from_dict(json.loads(json.dumps(BLOCK)), "block.yaml")
    # a threshold the search's first, finer trial crosses and its answer does not
    monkeypatch.setattr(plausibility, "LARGE_MESH_NODES", 700)
    with caplog.at_level(logging.WARNING, logger="plush_opt"):
        _, mesh = area_for_nodes(scene, 500)
    assert abs(mesh.n_nodes - 500) <= 0.05 * 500
    assert not [r for r in caplog.records if "gives about" in r.getMessage()]
