"""Friction at via points: parsing, the segment energies' derivatives, the
capstan law, mu = 0 equals the one-spring model, hysteresis, and the state
checker at every returned state."""

import copy

import numpy as np
import pytest

from plush_opt.base.errors import SceneError
from plush_opt.fem.friction import FrictionModel
from plush_opt.solve.friction_path import (SLIP_WINCH, FrictionOptions, check_state, follow,
                                     start_state)
from plush_opt.io import scene_from_dict
from plush_opt.problem import from_scene

EPS = np.finfo(float).eps


def arc(friction=0.2, stiff=True):
    """A stiff pinned block with one tendon through five interior via points
    on a half circle of radius 50: six chords, each turning by pi/6 at an
    interior point (total wrap 5 pi / 6 at rest)."""
    angles = np.linspace(np.pi, 0, 7)
    path = [[float(round(50 * np.cos(a), 6)), float(round(10 + 50 * np.sin(a), 6))] for a in angles]
    return {
        "format": "plush-opt/1", "name": "arc",
        "mesh": {"outline": [[-60, 0], [60, 0], [60, 70], [-60, 70]], "max_area": 60.0},
        "material": {"model": "neo_hookean", "youngs_modulus": 1000.0 if stiff else 1.0,
                     "poisson_ratio": 0.3, "thickness": 10.0},
        "pins": {"stiffness": 1.0e6 if stiff else 1.0e3, "at": [[-60, 0], [60, 0]], "box": [-60, 0, 60, 0]},
        "winches": [{"name": "w", "bounds": [-5.0, 5.0]}],
        "tendons": {"stiffness": 50.0, "smoothing": 0.01, "friction": friction,
                    "list": [{"name": "arc", "winch": "w", "path": path}]},
    }


def loop_area(c, y):
    """Signed area enclosed by the closed polygon (c_i, y_i) (shoelace)."""
    return 0.5 * float(np.sum(c * np.roll(y, -1) - np.roll(c, -1) * y))


def problem(doc):
    return from_scene(scene_from_dict(doc, "arc.yaml"))


# -- parsing -----------------------------------------------------------------

def test_friction_parses_with_default_and_override():
    doc = arc(0.2)
    assert scene_from_dict(doc).tendons[0].friction == 0.2
    doc["tendons"]["list"][0]["friction"] = 0.5
    assert scene_from_dict(doc).tendons[0].friction == 0.5
    del doc["tendons"]["friction"], doc["tendons"]["list"][0]["friction"]
    assert scene_from_dict(doc).tendons[0].friction == 0.0


@pytest.mark.parametrize("bad", [-0.1, float("nan"), True, "0.3", None.__class__])
def test_bad_friction_names_file_key_and_index(bad):
    doc = arc(0.2)
    doc["tendons"]["list"][0]["friction"] = bad if bad is not None.__class__ else [0.3]
    with pytest.raises(SceneError, match=r"arc\.yaml: tendons\.list\[0\]\.friction"):
        scene_from_dict(doc, "arc.yaml")
    doc = arc(0.2)
    doc["tendons"]["friction"] = bad if bad is not None.__class__ else [0.3]
    with pytest.raises(SceneError, match=r"arc\.yaml: tendons\.friction"):
        scene_from_dict(doc, "arc.yaml")


# -- derivatives ---------------------------------------------------------------

def test_segment_energy_derivatives_against_central_differences():
    p = problem(arc(0.2, stiff=False))
    fm = FrictionModel(p.model)
    rng = np.random.default_rng(3)
    c = np.array([1.0])
    r = fm.start_rest_lengths() * (1 + 0.01 * rng.standard_normal(fm.n_segments))
    x = p.model.X + 0.2 * rng.standard_normal(p.model.n_dofs)
    ev = fm.evaluate(x, c, r, 2)
    v, w = rng.standard_normal(p.model.n_dofs), rng.standard_normal(fm.n_segments)
    h = 1e-6
    checks = {
        "gradient": ((fm.evaluate(x + h * v, c, r, 0).energy - fm.evaluate(x - h * v, c, r, 0).energy)
                     / (2 * h), ev.gradient @ v),
        "hessian": ((fm.evaluate(x + h * v, c, r, 1).gradient - fm.evaluate(x - h * v, c, r, 1).gradient)
                    / (2 * h), ev.hessian @ v),
        "mixed": ((fm.evaluate(x, c, r + h * w, 1).gradient - fm.evaluate(x, c, r - h * w, 1).gradient)
                  / (2 * h), fm.mixed_r(x, r, c) @ w),
        "de_dr": ((fm.segments(x, r + h * w, c)["energy"] - fm.segments(x, r - h * w, c)["energy"])
                  / (2 * h), fm.segments(x, r, c)["de_dr"] * w),
        "tension_x": ((fm.segments(x + h * v, r, c)["tension"] - fm.segments(x - h * v, r, c)["tension"])
                      / (2 * h), fm.to_x(fm.segments(x, r, c)["dtension_dx"], fm.seg_p) @ v),
        "tension_r": ((fm.segments(x, r + h * w, c)["tension"] - fm.segments(x, r - h * w, c)["tension"])
                      / (2 * h), fm.segments(x, r, c)["dtension_dr"] * w),
        "wrap": ((fm.wraps(x + h * v)[0] - fm.wraps(x - h * v)[0]) / (2 * h),
                 fm.to_x(fm.wraps(x)[1], fm.wrap_p) @ v),
    }
    for name, (fd, exact) in checks.items():
        err = np.max(np.abs(np.asarray(fd) - exact))
        threshold = 1e3 * np.sqrt(EPS) * max(1.0, np.max(np.abs(exact)))
        assert err <= threshold, f"{name}: error {err:.3g} > threshold {threshold:.3g}"


def test_the_segments_are_a_term_whose_history_is_the_rest_lengths():
    import casadi as ca
    from plush_opt.fem.segments import SegmentTerm
    p = problem(arc(0.2, stiff=False))
    fm = FrictionModel(p.model)
    term = fm.segment_term
    assert isinstance(term, SegmentTerm) and fm.terms == fm.base.terms + (term,)
    assert [t.name for t in fm.terms] == ["elastic", "pins", "segments"]     # the arc's one tendon is segmented
    rng = np.random.default_rng(4)
    c = np.array([1.0])
    r = fm.start_rest_lengths() * (1 + 0.01 * rng.standard_normal(fm.n_segments))
    x = p.model.X + 0.2 * rng.standard_normal(p.model.n_dofs)
    # the history: the start state's rest lengths until a commit; held copies leave it alone
    assert np.array_equal(term.state, fm.start_rest_lengths())
    held = term.held(r)
    assert np.array_equal(held.state, r) and np.array_equal(term.state, fm.start_rest_lengths())
    mine = copy.copy(term)
    mine.commit(x, c, r)
    assert np.array_equal(mine.state, r)
    mine.commit(x, c)                                       # no rest lengths: kept
    assert np.array_equal(mine.state, r)
    mine.reset()
    assert np.array_equal(mine.state, fm.start_rest_lengths())
    # the model's evaluation is its terms', the segment term's at the held rest lengths
    ev, part = fm.evaluate(x, c, r, 1), held.evaluate(x, c, 1)
    assert part.energy == pytest.approx(float(fm.segments(x, r, c)["energy"].sum()), rel=1e-15)
    assert np.array_equal(fm.fixed(r).evaluate(x, c, 1).gradient, ev.gradient)
    # d2E/dx dc with the rest lengths held, against central differences in c
    h = 1e-6
    fd = (fm.evaluate(x, c + h, r, 1).gradient - fm.evaluate(x, c - h, r, 1).gradient) / (2 * h)
    exact = fm.mixed(x, c, r)
    assert exact.shape == (p.model.n_dofs, 1)
    assert np.max(np.abs(fd - exact[:, 0])) <= 1e3 * np.sqrt(EPS) * max(1.0, np.abs(exact).max())
    # the CasADi expression at the held rest lengths is the same energy
    xs, cs = ca.MX.sym("x", p.model.n_dofs), ca.MX.sym("c", 1)
    E = ca.Function("E", [xs, cs], [held.expression(xs, cs)])
    assert float(E(x, c)) == pytest.approx(part.energy, rel=1e-12)
    # a rest length <= 0 is no state: not admissible, no energy
    bad = r.copy()
    bad[0] = 0.0
    assert not term.held(bad).admissible(x)
    assert not fm.fixed(bad).evaluate(x, c, 2).admissible


def test_equal_shares_are_the_one_spring_model():
    p = problem(arc(0.2))
    fm = FrictionModel(p.model)
    c = np.zeros(1)
    r = fm.start_rest_lengths()
    assert fm.evaluate(p.model.X, c, r, 0).energy == pytest.approx(p.model.energy(p.model.X, c), rel=1e-12)
    g = fm.evaluate(p.model.X, c, r, 1).gradient
    assert np.allclose(g, p.model.evaluate(p.model.X, c, 1).gradient, atol=1e-12 * np.abs(g).max())


# -- the path-following solver --------------------------------------------------

def test_capstan_law_on_a_stiff_arc():
    mu = 0.2
    p = problem(arc(mu))
    fm = FrictionModel(p.model)
    states = follow(fm, start_state(fm), np.linspace(0, 1.0, 6)[1:, None])
    assert all(s.converged for s in states), [s.status for s in states]
    for s in states:
        assert not check_state(fm, s)
        assert np.all(s.mode == SLIP_WINCH)
        ratio = s.tension[fm.seg_last[0]] / s.tension[fm.seg_first[0]]
        assert ratio == pytest.approx(np.exp(mu * s.wrap.sum()), rel=1e-2)
        # the stiff body hardly moves: the rest geometry's wrap gives the ratio
        assert ratio == pytest.approx(np.exp(mu * 5 * np.pi / 6), rel=1e-2)


def test_zero_friction_equal_tensions_and_the_ordinary_equilibrium():
    p = problem(arc(0.0, stiff=False))
    fm = FrictionModel(p.model, include_frictionless=True)
    options = FrictionOptions(tol=1e-11)
    states = follow(fm, start_state(fm, options), np.linspace(0, 2.0, 4)[1:, None], options)
    for s in states:
        assert s.converged, s.status
        assert np.ptp(s.tension) <= 1e-9 * s.tension.max()
        eq = p.equilibrium({"w": float(s.contraction[0])})
        assert np.max(np.abs(s.x - eq.x)) <= 1e-6


def test_a_load_unload_cycle_encloses_a_loop_only_with_friction():
    areas = {}
    for mu in (0.0, 0.3):
        p = problem(arc(mu, stiff=False))
        fm = FrictionModel(p.model, include_frictionless=True)
        up = np.linspace(0, 3, 7)
        path = np.r_[up[1:], up[::-1][1:]][:, None]
        start = start_state(fm)
        states = [start] + follow(fm, start, path)
        assert all(s.converged for s in states), [s.status for s in states]
        for s in states:
            assert not check_state(fm, s)
        node = int(p.model.tendon_paths[0][3])          # the top of the arc
        y = np.array([s.nodes[node, 1] for s in states])
        c = np.array([s.contraction[0] for s in states])
        areas[mu] = abs(loop_area(c, y))
    assert areas[0.0] <= 1e-9 * areas[0.3]
    assert areas[0.3] > 0


def test_a_step_that_does_not_move_the_winches_keeps_the_state():
    p = problem(arc(0.2))
    fm = FrictionModel(p.model)
    moved, still = follow(fm, start_state(fm), [[1.0], [1.0]])
    assert moved.converged and still is moved
    # the rest state before the first solve is not an equilibrium: it is solved
    at_rest = start_state(fm)
    assert at_rest.status == "converged" and not check_state(fm, at_rest)


def test_check_state_reports_a_violated_bound():
    p = problem(arc(0.2))
    fm = FrictionModel(p.model)
    s = follow(fm, start_state(fm), [[1.0]])[-1]
    bad = copy.copy(s)
    r = s.rest.copy()
    r[fm.seg_last[0]] -= 0.5          # a winch-end segment far too tight ...
    r[fm.seg_first[0]] += 0.5         # ... with the sum kept
    object.__setattr__(bad, "rest", r)
    problems = check_state(fm, bad)
    assert problems and any("exp(mu theta)" in m for m in problems)


@pytest.mark.slow
def test_sweep_command_writes_csv_and_plot(tmp_path):
    import subprocess
    import sys

    import yaml
    doc = arc(0.3, stiff=False)
    doc["points"] = [[0, 60]]
    src = tmp_path / "arc.yaml"
    src.write_text(yaml.safe_dump(doc))
    out, png = tmp_path / "s.csv", tmp_path / "s.png"
    run = subprocess.run([sys.executable, "-m", "plush_opt", "sweep", str(src), "--winch", "w",
                          "--to", "2", "--back", "0", "--steps", "4", "--out", str(out),
                          "--plot", str(png)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    rows = out.read_text().splitlines()
    assert rows[0] == "step,c_w,x_0,y_0,T_arc_winch,T_arc_stopper"
    assert len(rows) == 1 + 9 and png.stat().st_size > 0
    bad = subprocess.run([sys.executable, "-m", "plush_opt", "sweep", str(src), "--winch", "nope",
                          "--to", "2", "--out", str(out)], capture_output=True, text=True)
    assert bad.returncode == 2 and "no winch named 'nope'" in bad.stderr


# -- forward solves and result files -----------------------------------------

def _forward_doc(p, eq):
    from plush_opt.solve.result_file import result_dict
    return result_dict(p.model, p.targets, eq, method="forward", converged=eq.converged,
                       status=eq.status, total_s=0.0, solve_s=0.0, iterations=eq.iterations)


def test_forward_solve_with_friction_follows_the_path_from_the_start_state():
    from spec_checker import check_result
    from plush_opt.solve.friction_solve import FrictionEquilibrium
    p = problem(arc(0.3, stiff=False))
    eq = p.equilibrium({"w": 3.0}, steps=4)
    assert isinstance(eq, FrictionEquilibrium) and eq.converged, eq.status
    assert np.allclose(eq.path[:, 0], [0.75, 1.5, 2.25, 3.0]) and eq.steps_done == 4
    assert eq.min_eigenvalue is not None and eq.min_eigenvalue > 0
    fm = p.plant.friction_model
    assert not check_state(fm, eq.friction)
    by_hand = follow(fm, start_state(fm), eq.path)[-1]
    assert np.max(np.abs(by_hand.x - eq.x)) <= 1e-6
    # friction changes the answer: not the frictionless equilibrium
    plain = problem(arc(0.0, stiff=False)).equilibrium({"w": 3.0})
    assert np.max(np.abs(plain.x - eq.x)) > 1e-3
    doc = _forward_doc(p, eq)
    assert doc["friction_path"]["steps"] == 4 and doc["friction_path"]["steps_done"] == 4
    entry = doc["model"]["tendons"]["list"][0]
    assert entry["segment_rest_lengths"] == pytest.approx(eq.friction.rest.tolist())
    assert entry["segment_tensions"] == pytest.approx(eq.friction.tension.tolist())
    assert doc["tendon_tension"]["arc"] == pytest.approx(eq.friction.tension[-1])
    check_result(doc)          # rebuilds E from the segments' rest lengths


def test_a_frictionless_result_records_proportional_segments_and_equal_tensions():
    from spec_checker import check_result
    p = problem(arc(0.0, stiff=False))
    eq = p.equilibrium({"w": 2.0})
    assert type(eq).__name__ == "Equilibrium"
    doc = _forward_doc(p, eq)
    assert "friction_path" not in doc
    entry = doc["model"]["tendons"]["list"][0]
    r, T = np.array(entry["segment_rest_lengths"]), np.array(entry["segment_tensions"])
    nodes = eq.x.reshape(-1, 2)[p.model.tendon_paths[0]]
    lengths = np.linalg.norm(np.diff(nodes, axis=0), axis=1)
    assert r.sum() == pytest.approx(p.model.assembly_length[0] - 2.0, rel=1e-12)
    assert np.allclose(r / lengths, r[0] / lengths[0], rtol=1e-12)
    assert np.all(T == T[0]) and T[0] == pytest.approx(doc["tendon_tension"]["arc"])
    check_result(doc)


def test_forward_solve_that_cannot_start_reports_it(monkeypatch):
    import plush_opt.solve.friction_solve as fs
    p = problem(arc(0.3, stiff=False))
    bad = fs.start_state(p.plant.friction_model)
    monkeypatch.setattr(fs, "start_state", lambda fm, options=None: copy.copy(bad).__class__(
        **{**bad.__dict__, "converged": False, "status": "no equilibrium"}))
    eq = p.equilibrium({"w": 1.0}, steps=2)
    assert not eq.converged and "stopped after 0 of 2" in eq.status and "no equilibrium" in eq.status


# -- sensitivities and control with history ----------------------------------

def _settled(fm, path):
    """States along ``path`` from the start state (all converged)."""
    states = follow(fm, start_state(fm), np.asarray(path, float)[:, None])
    assert all(s.converged for s in states), [s.status for s in states]
    return states


@pytest.mark.parametrize("path, direction", [([1.0, 2.0], 1.0), ([1.0, 2.0, 1.5, 1.0], -1.0)])
def test_path_sensitivity_against_a_small_step_in_the_same_modes(path, direction):
    from plush_opt.solve.friction_path import step
    from plush_opt.solve.friction_solve import path_sensitivity
    fm = problem(arc(0.3, stiff=False)).plant.friction_model
    s = _settled(fm, path)[-1]
    S = path_sensitivity(fm, s, s.equilibrium.factor)[:, 0]
    errors = []
    for eps in (1e-3, 1e-4):
        nxt = step(fm, s, s.contraction + direction * eps, FrictionOptions(tol=1e-12, check_tol=1e-10))
        assert nxt.converged and np.array_equal(nxt.mode, s.mode)      # the modes hold
        errors.append(np.abs((nxt.x - s.x) / (direction * eps) - S).max() / np.abs(S).max())
    assert errors[1] <= 1e-4 and errors[1] < 0.2 * errors[0]          # first order: O(eps)


def arc_with_target(friction=0.3):
    doc = arc(friction, stiff=False)
    doc["targets"] = [{"at": [0.0, 60.0], "to": [0.0, 57.0]}]
    return doc


@pytest.mark.slow
def test_control_iterates_are_the_states_of_the_robot_driven_in_that_order():
    from plush_opt.control import ControlOptions
    from plush_opt.solve.friction_solve import FrictionEquilibrium, drive
    p = problem(arc_with_target())
    res = p.control("reparam", options=ControlOptions(max_iterations=6))
    assert isinstance(res.equilibrium, FrictionEquilibrium)
    assert len(res.history) >= 3
    # drive a fresh robot through the accepted contractions, in order
    fm = p.plant.friction_model
    eq = drive(fm, start_state(fm), res.history[0].contraction)
    assert np.max(np.abs(eq.x - res.history[0].x)) <= 1e-6
    for it in res.history[1:]:
        eq = drive(fm, eq.friction, it.contraction)
        assert eq.converged and np.max(np.abs(eq.x - it.x)) <= 1e-6
        assert not check_state(fm, eq.friction)
    assert np.max(np.abs(res.equilibrium.x - eq.x)) <= 1e-6
    assert res.history[-1].objective < res.history[0].objective
    assert np.allclose(res.equilibrium.path, [it.contraction for it in res.history])
    from spec_checker import check_result
    from plush_opt.solve.result_file import control_result_dict
    doc = check_result(control_result_dict(res))
    assert doc["friction_path"]["steps"] == len(res.history)
    assert doc["friction_path"]["from"].startswith("the control run's starting state")


def test_control_starts_from_the_robots_state():
    from plush_opt.control import ControlOptions
    from plush_opt.solve.friction_solve import drive
    p = problem(arc_with_target())
    fm = p.plant.friction_model
    # the same contraction reached two ways: straight there, or past it and back
    there = drive(fm, start_state(fm), [1.0]).friction
    back = drive(fm, drive(fm, start_state(fm), [3.0]).friction, [1.0]).friction
    assert np.max(np.abs(there.x - back.x)) > 1e-3          # friction: history matters
    for state in (there, back):
        res = p.control("clip", {"w": 1.0}, options=ControlOptions(max_iterations=0), start=state)
        assert np.max(np.abs(res.history[0].x - state.x)) <= 1e-8


def test_bilevel_refuses_a_friction_scene_with_the_reason():
    p = problem(arc_with_target())
    with pytest.raises(SceneError, match="tendons.friction: the bilevel method .* depends on the path"):
        p.control("bilevel")


def test_a_run_carries_the_friction_state_from_step_to_step(tmp_path):
    import yaml
    from plush_opt.apps.planner import ControlPlanner
    from plush_opt.solve.friction_solve import drive
    path = tmp_path / "arc.yaml"
    path.write_text(yaml.safe_dump(arc_with_target()))
    straight, round_trip = ControlPlanner(path), ControlPlanner(path)
    assert straight.forward({"w": 1.0})["converged"]
    for c in (3.0, 1.0):
        assert round_trip.forward({"w": c})["converged"]
    assert np.max(np.abs(straight.x - round_trip.x)) > 1e-3      # same command, other history
    fm = round_trip.problem.plant.friction_model
    by_hand = drive(fm, drive(fm, drive(fm, start_state(fm), [0.0]).friction, [3.0]).friction, [1.0])
    assert np.max(np.abs(by_hand.x - round_trip.x)) <= 1e-6
    before = round_trip.state
    out = list(round_trip.pose([{"at": [0.0, 60.0], "to": [0.0, 57.0]}], [], max_time=30))
    assert out[-1]["objective"] < out[0]["objective"]
    assert round_trip.state is not before and not check_state(fm, round_trip.state)
    assert np.array_equal(round_trip.state.x, round_trip.x)


def test_gui_session_drives_the_robot_and_shows_segment_tensions():
    from plush_opt.apps.gui.session import PosingSession, status_line
    from plush_opt.solve.friction_solve import drive, solve_forward
    p = problem(arc(0.3, stiff=False))
    session = PosingSession(p)
    for c in (3.0, 1.0):
        session.set_contraction("w", c)
    eq = session.equilibrium
    assert eq.converged and eq.friction is not None
    fm = p.plant.friction_model
    by_hand = drive(fm, drive(fm, solve_forward(fm, [0.0]).friction, [3.0]).friction, [1.0])
    assert np.max(np.abs(by_hand.x - eq.x)) <= 1e-6
    text = status_line(session)
    shown = text.split("T [N]: arc ")[1].split()[0].split("/")
    assert len(shown) == 6 and np.allclose([float(v) for v in shown], eq.friction.tension, rtol=2e-3)
    plain = PosingSession(problem(arc(0.0, stiff=False)))
    assert "/" not in status_line(plain).split("T [N]: arc ")[1]


@pytest.mark.slow
def test_solve_command_forward_records_the_path_and_bilevel_refuses(tmp_path):
    import json
    import subprocess
    import sys

    import yaml
    from spec_checker import check_result
    path = tmp_path / "arc.yaml"
    path.write_text(yaml.safe_dump(arc_with_target()))
    out = tmp_path / "f.json"
    run = subprocess.run([sys.executable, "-m", "plush_opt", "solve", str(path), "--method", "forward",
                          "-c", "w=2", "--out", str(out)], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    doc = check_result(json.loads(out.read_text()))
    assert doc["friction_path"]["steps"] == 10 and doc["friction_path"]["contractions"][-1] == {"w": 2.0}
    run = subprocess.run([sys.executable, "-m", "plush_opt", "solve", str(path), "--method", "bilevel",
                          "--out", str(tmp_path / "b.json")], capture_output=True, text=True)
    assert run.returncode != 0 and "Traceback" not in run.stderr
    assert "tendons.friction: the bilevel method" in run.stderr and not (tmp_path / "b.json").exists()


def test_the_bilevel_solver_itself_refuses_friction():
    """Not only run_control: a BilevelSolver used directly must not return
    the frictionless answer of a friction scene (nothing is solved)."""
    from pathlib import Path

    from plush_opt import load
    from plush_opt.control import BilevelSolver
    p = load(Path(__file__).resolve().parent.parent / "problems" / "gripper_friction.yaml")
    with pytest.raises(SceneError, match="tendons.friction"):
        BilevelSolver(p.model).solve(p.targets)


def test_friction_hessian_forms_agree():
    """On discs large enough for the split form, the friction model's
    Hessian (segment couplings of two discs kept as low rank) is the
    assembled one, and the equilibrium at fixed rest lengths is the same."""
    from pathlib import Path

    from plush_opt.solve.equilibrium import solve_equilibrium
    from plush_opt.fem.mesh import mesh_for_nodes
    from plush_opt.fem.model import Model
    from plush_opt.problem import load
    scene = load(Path(__file__).resolve().parent.parent / "problems" / "gripper_friction.yaml").scene
    scene = scene.replace(element="P2")
    mesh = mesh_for_nodes(scene, 700)
    split, assembled = (FrictionModel(Model(scene, mesh, hessian=f)) for f in ("split", "assembled"))
    assert split.split and not assembled.split
    c = assembled.model.lower + 0.5 * (assembled.model.upper - assembled.model.lower)
    r = assembled.start_rest_lengths()
    eq = solve_equilibrium(assembled.fixed(r), c)
    assert eq.converged
    H = assembled.evaluate(eq.x, c, r).hessian
    ev = split.evaluate(eq.x, c, r)
    assert type(ev.hessian_form).__name__ == "LowRankHessian"
    assert abs(ev.hessian - H).max() <= 1e-11 * abs(H).max()
    eq_split = solve_equilibrium(split.fixed(r), c)
    assert eq_split.converged and np.abs(eq_split.x - eq.x).max() <= 1e-9 * np.abs(eq.x).max()
