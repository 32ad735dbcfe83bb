"""Forward solves of scenes with friction at via points, and what a result
file records of them (docs/model.md, "Friction at via points").

A robot with friction is in the state its history put it in, so a forward
solve to contractions c does not ask for "the" equilibrium at c: it drives
the winches from the scene's start state (zero contraction, equal tensions)
along the straight line to c in ``steps`` equal steps, each from the state
the previous one reached (plush_opt/solve/friction_path.py), and returns the
state at the end with the path it followed. A step that fails is split in
halves by the path solver; a step that still fails ends the solve with an
honest status at the last state reached.

Every tendon's segments are recorded the same way, with or without
friction: a frictionless tendon's rest length r = a - c is shared in
proportion to its segments' lengths, r_j = |seg_j| r / l, all tensions equal
(exactly the single-spring model, :func:`segment_table`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import numpy as np

from ..base.reprs import compact_repr
from .equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from .sensitivity import implicit_derivative
from ..fem.friction import FrictionModel, via_weights
from .friction_path import (SLIP_WINCH, STICK, FrictionOptions, FrictionState, capstan, capstan_residual,
                            follow, start_state)

# Equal steps of a forward solve from the start state: the path solver
# splits any step that fails, so this only sets how finely the history is
# sampled (the friction state at the end depends on the path, barely on N
# for a straight monotone path).
DEFAULT_PATH_STEPS = 10
# Largest step of a path between two commanded contractions (control
# iterates, run steps), as a fraction of the winch's range: small enough
# that most steps keep their stick/slip modes (a failing step is split).
MAX_STEP_FRACTION = 0.1
# Central-difference step of the residuals' rate in c, relative to the
# mean segment rest length: their c-dependence at a fixed pose is smooth
# (a share phi = r / (a - c), the winch-end rest length), so the error is
# far below the sensitivity's own approximation (modes held).
RATE_STEP = 1e-6


@dataclass(frozen=True)
class FrictionEquilibrium(Equilibrium):
    """An :class:`Equilibrium` reached along a contraction path with friction.

    Attributes (besides the equilibrium's)
    --------------------------------------
    friction : the :class:`FrictionState` at the end of the path (segment
        rest lengths, tensions, stick/slip modes).
    friction_model : the :class:`FrictionModel` it belongs to.
    path : (steps, n_winches) the contractions followed, from ``origin``.
    steps_done : how many of them were reached.
    origin : where the path started, in words.
    """

    friction: FrictionState | None = field(default=None, repr=False, compare=False)
    friction_model: FrictionModel | None = field(default=None, repr=False, compare=False)
    path: np.ndarray | None = field(default=None, repr=False, compare=False)
    steps_done: int = 0
    origin: str = ("start state: zero contraction, segment rest lengths proportional to their "
                   "rest lengths (equal tensions), its equilibrium")

    __repr__ = compact_repr


def straight_path(start, contraction, steps: int) -> np.ndarray:
    """(steps, n_winches): the straight line from ``start`` to ``contraction``
    in equal steps, ending exactly at ``contraction``."""
    if int(steps) != steps or steps < 1:
        raise ValueError(f"steps: expected an integer >= 1, got {steps!r}")
    start = np.asarray(start, dtype=np.float64)
    end = np.asarray(contraction, dtype=np.float64)
    t = np.arange(1, int(steps) + 1)[:, None] / int(steps)
    path = start + t * (end - start)
    path[-1] = end
    return path


def finish(fm: FrictionModel, state: FrictionState, path: np.ndarray, steps_done: int,
           options: EquilibriumOptions | None = None, path_iterations: int = 0) -> FrictionEquilibrium:
    """The equilibrium record of a path's last state: the pose polished and
    certified at the state's rest lengths (smallest Hessian eigenvalue as
    asked by ``options``), with the state and the path attached. Its
    ``iterations`` are the polish's Newton iterations plus ``path_iterations``
    (those of the path's steps)."""
    options = options or EquilibriumOptions()
    if state.converged:
        eq = solve_equilibrium(fm.fixed(state.rest), state.contraction, state.x, options)
        converged = eq.converged
        status = (f"{eq.status}; followed {steps_done} step(s) of its path" if converged else
                  f"the path's last state did not certify: {eq.status}")
    else:
        eq = solve_equilibrium(fm.fixed(state.rest), state.contraction, state.x,
                               EquilibriumOptions(max_iterations=1, eigenvalue=False))
        converged = False
        status = (f"friction path stopped after {steps_done} of {len(path)} step(s): "
                  f"{state.status}")
    base = {f.name: getattr(eq, f.name) for f in fields(Equilibrium)}
    base.update(converged=converged, status=status, iterations=int(eq.iterations) + int(path_iterations))
    return FrictionEquilibrium(**base, friction=state, friction_model=fm, path=path, steps_done=steps_done)


def solve_forward(fm: FrictionModel, contraction, steps: int = DEFAULT_PATH_STEPS,
                  options: FrictionOptions | None = None, start: FrictionState | None = None,
                  equilibrium: EquilibriumOptions | None = None) -> FrictionEquilibrium:
    """Drive the winches from ``start`` (default the scene's start state) to
    ``contraction`` along a straight line in ``steps`` steps; the state at
    the end as a :class:`FrictionEquilibrium`."""
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    if options is None and equilibrium is not None:
        options = path_options(equilibrium)
    if start is None:
        start = start_state(fm, options)
    path = straight_path(start.contraction, c, steps)
    if not start.converged:
        return finish(fm, start, path, 0, equilibrium)
    states = follow(fm, start, path, options)
    # each step's final Newton solve (the stick/slip rounds before it are not counted)
    newton = sum(s.equilibrium.iterations for s in states if s.equilibrium is not None)
    return finish(fm, states[-1], path, sum(s.converged for s in states), equilibrium, newton)


def path_options(equilibrium: EquilibriumOptions) -> FrictionOptions:
    """The path solver's default options with the residual tolerance
    (``gtol``) and round-off allowance (``roundoff``) of ``equilibrium`` in
    its inner equilibrium solves: a caller that accepts a pose at the
    round-off floor of a fine mesh (``--accuracy``'s levels) accepts its path
    steps there too. With ``equilibrium``'s defaults these are the defaults."""
    base = FrictionOptions()
    return replace(base, equilibrium=replace(base.equilibrium, gtol=equilibrium.gtol, roundoff=equilibrium.roundoff))


def segment_table(model, x, c, eq: Equilibrium | None = None) -> list[dict]:
    """Per tendon of the scene: ``segment_rest_lengths`` and
    ``segment_tensions`` at pose x, contractions c. Friction tendons of a
    :class:`FrictionEquilibrium` from its state; every other tendon shares
    its rest length a - c in proportion to its segments' lengths (one
    spring: all tensions equal)."""
    x = np.asarray(x, dtype=np.float64).reshape(-1, 2)
    c = np.asarray(c, dtype=np.float64).reshape(-1)
    state = getattr(eq, "friction", None)
    fm = getattr(eq, "friction_model", None)
    one = model.tendon_state(x.reshape(-1), c)["tension"]
    out = []
    for t in range(model.n_tendons):
        if state is not None and t in fm.tendons:
            seg = np.flatnonzero(fm.seg_tendon == t)
            out.append({"segment_rest_lengths": state.rest[seg].tolist(),
                        "segment_tensions": state.tension[seg].tolist()})
            continue
        P = (via_weights(model, t) @ x.reshape(-1)).reshape(-1, 2)      # the via points
        lengths = np.linalg.norm(np.diff(P, axis=0), axis=1)
        rest = model.assembly_length[t] - c[model.tendon_winch[t]]
        out.append({"segment_rest_lengths": (lengths * rest / lengths.sum()).tolist(),
                    "segment_tensions": [float(one[t])] * len(lengths)})
    return out


def path_record(eq: Equilibrium, winch_names) -> dict | None:
    """The ``friction_path`` entry of a result file: how the state was
    reached (None for an equilibrium without friction)."""
    if not isinstance(eq, FrictionEquilibrium) or eq.friction is None:
        return None
    state, fm = eq.friction, eq.friction_model
    return {
        "from": eq.origin,
        "steps": int(len(eq.path)), "steps_done": int(eq.steps_done),
        "contractions": [{n: float(v) for n, v in zip(winch_names, row)} for row in eq.path],
        "modes": {fm.model.scene.tendons[t].name: [int(m) for m, k in zip(state.mode, fm.seg_tendon[fm.hi])
                                                   if k == t] for t in fm.tendons},
        "mode_legend": {"0": "stick", "1": "slip toward the winch", "-1": "slip toward the stopper"},
        "wrap_angles": state.wrap.tolist(),
    }


def path_steps(fm: FrictionModel, start, contraction) -> int:
    """Steps of the straight path from ``start`` to ``contraction``: each
    winch moves at most ``MAX_STEP_FRACTION`` of its range per step."""
    model = fm.model
    span = np.maximum(model.upper - model.lower, np.finfo(float).tiny)
    move = np.abs(np.asarray(contraction, dtype=np.float64) - np.asarray(start, dtype=np.float64)) / span
    return max(1, int(np.ceil(float(np.max(move, initial=0.0)) / MAX_STEP_FRACTION - 1e-12)))


def drive(fm: FrictionModel, state: FrictionState, contraction, options: FrictionOptions | None = None,
          equilibrium: EquilibriumOptions | None = None, origin: str | None = None) -> FrictionEquilibrium:
    """The robot at ``state`` driven to ``contraction`` along a straight
    line (:func:`path_steps` steps): its state there."""
    eq = solve_forward(fm, contraction, path_steps(fm, state.contraction, contraction), options, state,
                       equilibrium)
    return eq if origin is None else FrictionEquilibrium(
        **{f.name: getattr(eq, f.name) for f in fields(FrictionEquilibrium) if f.name != "origin"},
        origin=origin)


def _rates(fm: FrictionModel, state: FrictionState, w: int, active, mode):
    """d/dc_w of grad_x E and of the slipping points' capstan residuals at
    the state's pose and slips held: winch w reels in at its winch-end
    segments (their rest length shrinks with c_w) and its tendons' total
    rest length a - c_w shrinks (central differences)."""
    x, r, c = state.x, state.rest, state.contraction
    h = RATE_STEP * float(np.mean(r))
    out = []
    for sign in (1.0, -1.0):
        cw = c.copy()
        cw[w] += sign * h
        rw = r.copy()
        last = fm.seg_last[fm.seg_winch[fm.seg_last] == w]
        rw[last] -= sign * h
        g = fm.evaluate(x, cw, rw, 1).gradient
        f_w, f_s, *_ = capstan(fm, x, rw, cw)
        out.append((g, np.where(mode == SLIP_WINCH, f_w, f_s)[active]))
    return (out[0][0] - out[1][0]) / (2 * h), (out[0][1] - out[1][1]) / (2 * h)


def path_sensitivity(fm: FrictionModel, state: FrictionState, factor=None, columns=None) -> np.ndarray:
    """dx/dc at ``state`` in its stick/slip modes, dense (n_dofs, n_winches)
    (only ``columns`` if given, the others zero): a stuck via point keeps its
    segments' rest lengths, a slipping one moves material so as to keep its
    capstan equality. This is the derivative of a path that goes on in the
    modes of the last step; a mode change within the next step (a point
    that starts or stops slipping) is not in it.

    With every point stuck it is the implicit derivative at the state's
    rest lengths (:func:`~plush_opt.solve.sensitivity.implicit_derivative`);
    slipping points add a bordered correction through the capstan
    equalities' Schur complement."""
    x, r, c = state.x, state.rest, state.contraction
    if factor is None:
        factor = fm.factorizer.factor(fm.evaluate(x, c, r, 2).hessian_form)
    mode = state.mode
    active = mode != STICK
    cols = range(fm.n_winches) if columns is None else columns
    g_c = np.zeros((fm.n_dofs, fm.n_winches), order="F")     # each rate a contiguous column
    h_c = {}
    for w in cols:
        g_c[:, w], h_c[w] = _rates(fm, state, w, active, mode)
    held = implicit_derivative(factor, g_c, cols)        # the rest lengths held: -H^-1 dg/dc
    if not active.any():
        return np.ascontiguousarray(held)
    seg = fm.segments(x, r, c)
    Ds = fm.D[:, active].toarray()
    _, _, dh_dx, dh_dr, _ = capstan_residual(fm, x, r, c, active, mode, seg)
    HB = factor.solve(fm.mixed_r(x, r, c, seg) @ Ds)
    schur = dh_dr @ Ds - dh_dx @ HB
    out = np.zeros((fm.n_dofs, fm.n_winches))
    for w in cols:
        dd = np.linalg.lstsq(schur, -h_c[w] - dh_dx @ held[:, w], rcond=None)[0]
        out[:, w] = held[:, w] - HB @ dd
    return out
