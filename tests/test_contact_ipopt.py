"""The IPOPT backends with obstacles: the symbolic barrier is the numeric
one (energy and forces, every pair kind), IPOPT and Newton find the same
equilibrium on a body held by an obstacle, and self-contact is refused in
one line."""

import json

import casadi as ca
import numpy as np
import pytest

from plush_opt.base.errors import SceneError
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import Model
from plush_opt.io.problem_file import scene_from_dict
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium

from test_contact import BLOCK
from test_contact_scenes import STRIP

#: the block of test_contact, without a floor, dropped into a V-shaped trough
VEE = {**BLOCK, "contact": {"distance": 1.0, "obstacles": [
    {"name": "vee", "outline": [[-5, -5], [15, -5], [15, 0.4], [5, -0.4], [-5, 0.4]]}]}}


def _model(doc, name):
    scene = scene_from_dict(json.loads(json.dumps(doc)), name)
    return Model(scene, build_mesh(scene))


def _symbolic(term, n_dofs):
    x = ca.MX.sym("x", n_dofs)
    e = term.expression(x, ca.MX.sym("c", 1))
    return ca.Function("e", [x], [e, ca.gradient(e, x)])


def test_the_symbolic_obstacle_barrier_is_the_numeric_one():
    doc = json.loads(json.dumps(STRIP))
    doc["contact"] = {"distance": 2.0, "obstacles": [{"name": "peg", "outline": [[40, -5], [44, -5], [42, -1.5]]},
                                                     {"name": "cap", "outline": [[60, 5], [70, 5], [65, 6]]}]}
    model = _model(doc, "strip.yaml")
    term = model.contact
    f = _symbolic(term, model.n_dofs)
    rng = np.random.default_rng(7)
    kinds = set()
    for _ in range(4):
        x = model.X + 0.3 * rng.standard_normal(model.n_dofs)
        pairs = term.pairs(x)
        kinds |= {tuple(p >= 0) for p in pairs.dofs[:, [0, 2]]}
        ev = term.evaluate(x, np.zeros(1), 1)
        e, g = f(x)
        assert float(e) == pytest.approx(ev.energy, rel=1e-12)
        assert np.abs(np.asarray(g).ravel() - ev.gradient).max() <= 1e-10 * np.abs(ev.gradient).max()
    # both kinds of pair were active: body node - obstacle edge, obstacle vertex - body segment
    assert kinds == {(True, False), (False, True)}


def test_a_node_carried_through_an_obstacle_makes_the_symbolic_barrier_nan():
    """The squared distances are unsigned: a node moved right through an
    obstacle edge, out of the barrier's reach on the inside, would sit at a
    finite energy without the winding-number guard, and IPOPT (no collision
    detection) would accept the step. Inside, energy and forces are NaN, and
    the model names the crossing."""
    doc = json.loads(json.dumps(STRIP))
    doc["contact"] = {"distance": 0.5, "obstacles": [{"name": "slab", "outline": [[30, -20], [50, -20],
                                                                                  [50, -10], [30, -10]]}]}
    model = _model(doc, "strip.yaml")
    f = _symbolic(model.contact, model.n_dofs)
    boundary = model.contact.boundary.nodes
    X = model.X.reshape(-1, 2)
    i = int(boundary[np.argmin(np.abs(X[boundary, 0] - 40) + np.abs(X[boundary, 1]))])
    x = model.X.copy().reshape(-1, 2)
    x[i] = [40.0, -15.0]                   # 5 from every edge: beyond d_hat, inside the slab
    x = x.ravel()
    assert not model.admissible(x) and "inside obstacle 'slab'" in model.violation(x)
    e, g = f(x)
    assert np.isnan(float(e)) and np.isnan(np.asarray(g)).any()
    x[2 * i + 1] = -25.0                    # the same node below the slab: outside, finite
    e, g = f(x)
    assert np.isfinite(float(e)) and np.isfinite(np.asarray(g)).all()


def test_an_obstacle_corner_carried_into_the_body_makes_the_symbolic_barrier_nan():
    """The other way through: a thin peg's tip inside the body between two
    boundary nodes, no node inside the peg."""
    doc = json.loads(json.dumps(STRIP))
    doc["contact"] = {"distance": 0.1, "obstacles": [{"name": "peg", "outline": [[40.3, -3], [40.7, -3],
                                                                                 [40.5, -0.5]]}]}
    model = _model(doc, "strip.yaml")
    f = _symbolic(model.contact, model.n_dofs)
    x = (model.X.reshape(-1, 2) - [0.0, 1.0]).ravel()        # the whole strip 1 lower: the tip 0.5 inside
    why = model.violation(x)
    assert why is not None and "crosses obstacle 'peg'" in why, why
    e, g = f(x)
    assert np.isnan(float(e)) and np.isnan(np.asarray(g)).any()
    e, g = f(model.X)
    assert np.isfinite(float(e)) and np.isfinite(np.asarray(g)).all()


@pytest.mark.parametrize("c", [0.0, 2.0])
def test_ipopt_and_newton_agree_on_a_body_held_by_an_obstacle(c):
    model = _model(VEE, "vee.yaml")
    newton = solve_equilibrium(model, np.array([c]))
    ipopt = solve_equilibrium(model, np.array([c]), options=EquilibriumOptions(backend="ipopt"))
    assert newton.converged and ipopt.converged, (newton.status, ipopt.status)
    assert len(model.contact.pairs(newton.x).weight) > 0          # it rests on the trough
    assert np.abs(newton.x - ipopt.x).max() <= 1e-8


def test_ipopt_refuses_self_contact_in_one_line():
    doc = json.loads(json.dumps(STRIP))
    doc["contact"] = {"self": True, "distance": 0.5}
    model = _model(doc, "strip.yaml")
    with pytest.raises(SceneError, match=r"^strip.yaml: contact.self: the IPOPT backends .* not self-contact"):
        solve_equilibrium(model, np.array([4.0]), options=EquilibriumOptions(backend="ipopt"))
