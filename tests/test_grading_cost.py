"""Grading a fine outline stays cheap: the body's diameter (behind the
scene's point tolerance) is computed once, not once per pair of corners
(a crescent of 248 reentrant vertices took half a minute to grade)."""

import dataclasses

import numpy as np

from plush_opt.base import geometry
from plush_opt.fem import grading
from plush_opt.io import load_scene

from shipped import ROOT


def test_singular_points_of_a_fine_outline_ask_the_diameter_once(monkeypatch):
    scene = load_scene(ROOT / "tests" / "data" / "crescent.yaml")
    calls = []
    real = geometry.diameter
    monkeypatch.setattr("plush_opt.io.scene.diameter", lambda pts: calls.append(1) or real(pts))
    points = grading.singular_points(scene)
    assert len(points) > 200
    assert len(calls) <= 1


def test_singular_points_keep_one_copy_of_each_point():
    scene = load_scene(ROOT / "tests" / "data" / "crescent.yaml")
    points = grading.singular_points(scene)
    again = grading.singular_points(dataclasses.replace(scene))
    assert np.array_equal(points, again)
    d = np.linalg.norm(points[:, None] - points[None], axis=-1)
    np.fill_diagonal(d, np.inf)
    assert d.min() > scene.tolerance
