"""Forward solves of scenes with friction at via points, and what a result
file records of them (docs/model.md, "Friction at via points").

A robot with friction is in the state its history put it in, so a forward
solve to contractions c does not ask for "the" equilibrium at c: it drives
the winches from the scene's start state (zero contraction, equal tensions)
along the straight line to c in ``steps`` equal steps, each from the state
the previous one reached (plush_opt/friction_path.py), and returns the
state at the end with the path it followed. A step that fails is split in
halves by the path solver; a step that still fails ends the solve with an
honest status at the last state reached.

Every tendon's segments are recorded the same way, with or without
friction: a frictionless tendon's rest length r = a - c is shared in
proportion to its segments' lengths, r_j = |seg_j| r / l, all tensions equal
(exactly the single-spring model, :func:`segment_table`).
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields

import numpy as np

from .equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from .friction import FrictionModel, friction_tendons
from .friction_path import FrictionOptions, FrictionState, follow, start_state

# Equal steps of a forward solve from the start state: the path solver
# splits any step that fails, so this only sets how finely the history is
# sampled (the friction state at the end depends on the path, barely on N
# for a straight monotone path).
DEFAULT_PATH_STEPS = 10


@dataclass(frozen=True)
class FrictionEquilibrium(Equilibrium):
    """An :class:`Equilibrium` reached along a contraction path with friction.

    Attributes (besides the equilibrium's)
    --------------------------------------
    friction : the :class:`FrictionState` at the end of the path (segment
        rest lengths, tensions, stick/slip modes).
    friction_model : the :class:`FrictionModel` it belongs to.
    path : (steps, n_winches) the contractions followed, from the start state.
    steps_done : how many of them were reached.
    """

    friction: FrictionState | None = field(default=None, repr=False, compare=False)
    friction_model: FrictionModel | None = field(default=None, repr=False, compare=False)
    path: np.ndarray | None = field(default=None, repr=False, compare=False)
    steps_done: int = 0


def has_friction(model) -> bool:
    """The scene has a tendon with friction and an interior via point."""
    return bool(friction_tendons(model.scene))


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
           options: EquilibriumOptions | None = None) -> FrictionEquilibrium:
    """The equilibrium record of a path's last state: the pose polished and
    certified at the state's rest lengths (smallest Hessian eigenvalue as
    asked by ``options``), with the state and the path attached."""
    options = options or EquilibriumOptions()
    if state.converged:
        eq = solve_equilibrium(fm.fixed(state.rest), state.contraction, state.x, options)
        converged = eq.converged
        status = (f"{eq.status}; followed {steps_done} step(s) from the start state" if converged else
                  f"the path's last state did not certify: {eq.status}")
    else:
        eq = solve_equilibrium(fm.fixed(state.rest), state.contraction, state.x,
                               EquilibriumOptions(max_iterations=1, eigenvalue=False))
        converged = False
        status = (f"friction path stopped after {steps_done} of {len(path)} step(s): "
                  f"{state.status}")
    base = {f.name: getattr(eq, f.name) for f in fields(Equilibrium)}
    base.update(converged=converged, status=status)
    return FrictionEquilibrium(**base, friction=state, friction_model=fm, path=path, steps_done=steps_done)


def solve_forward(fm: FrictionModel, contraction, steps: int = DEFAULT_PATH_STEPS,
                  options: FrictionOptions | None = None, start: FrictionState | None = None,
                  equilibrium: EquilibriumOptions | None = None) -> FrictionEquilibrium:
    """Drive the winches from ``start`` (default the scene's start state) to
    ``contraction`` along a straight line in ``steps`` steps; the state at
    the end as a :class:`FrictionEquilibrium`."""
    c = np.asarray(contraction, dtype=np.float64).reshape(-1)
    if start is None:
        start = start_state(fm, options)
    path = straight_path(start.contraction, c, steps)
    if not start.converged:
        return finish(fm, start, path, 0, equilibrium)
    states = follow(fm, start, path, options)
    return finish(fm, states[-1], path, sum(s.converged for s in states), equilibrium)


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
    for t, nodes in enumerate(model.tendon_paths):
        if state is not None and t in fm.tendons:
            seg = np.flatnonzero(fm.seg_tendon == t)
            out.append({"segment_rest_lengths": state.rest[seg].tolist(),
                        "segment_tensions": state.tension[seg].tolist()})
            continue
        lengths = np.linalg.norm(np.diff(x[np.asarray(nodes)], axis=0), axis=1)
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
        "from": "start state: zero contraction, segment rest lengths proportional to their rest "
                "lengths (equal tensions), its equilibrium",
        "steps": int(len(eq.path)), "steps_done": int(eq.steps_done),
        "contractions": [{n: float(v) for n, v in zip(winch_names, row)} for row in eq.path],
        "modes": {fm.model.scene.tendons[t].name: [int(m) for m, k in zip(state.mode, fm.seg_tendon[fm.hi])
                                                   if k == t] for t in fm.tendons},
        "mode_legend": {"0": "stick", "1": "slip toward the winch", "-1": "slip toward the stopper"},
        "wrap_angles": state.wrap.tolist(),
    }
