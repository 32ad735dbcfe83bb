"""The gradient loop on a scene with friction at via points: control that
knows the robot's history (docs/control.md, docs/model.md).

With friction the pose at contractions c depends on how the robot got
there, so the loop keeps the robot's friction state (pose and segment rest
lengths, plush_opt/solve/friction_path.py) besides its contractions:

* it starts from a given state (where a run left the robot) or from the
  scene's start state driven to the starting contractions;
* every trial point of the line search is reached by driving the robot
  from the current iterate's state along the straight line to it, so the
  accepted iterates are the states the robot passes through when driven
  in that order;
* the gradient is dO/dc in the current stick/slip modes (stuck via points
  keep their segments' rest lengths, slipping ones keep their capstan
  equality): the derivative of a continuation in the modes of the last
  step. A mode change within the next step is not in it (approximated);
  the line search then judges the step by the state actually reached.

The bilevel method has no such history (one KKT system for the pose at the
final contractions): it refuses a friction scene (:func:`refuse_bilevel`).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..solve.equilibrium import EquilibriumOptions
from ..base.errors import SceneError
from ..fem.friction import FrictionModel
from ..solve.friction_path import FrictionState
from ..solve.friction_solve import (DEFAULT_PATH_STEPS, FrictionEquilibrium, drive, finish, has_friction,
                              path_sensitivity, solve_forward)
from .gradient import ControlOptions, Controller

CONTROL_ORIGIN = "the control run's starting state, then its accepted iterates in order"


def refuse_bilevel(model) -> None:
    """The bilevel method on a friction scene: one clear error saying why
    (a :class:`SceneError`: the file's friction and the method chosen do not
    go together; nothing is solved)."""
    raise SceneError(f"{model.scene.source}: tendons.friction: the bilevel method solves for the pose at "
                      "the final contractions alone, but with friction at via points the pose depends on "
                      "the path the winches took; use --method reparam or clip (they follow the path)")


def gradient_controller(model, targets, contraction=None, frozen=None, x0=None,
                        options: ControlOptions | None = None, *, friction: FrictionModel | None = None,
                        start: FrictionState | None = None) -> Controller:
    """The gradient loop the scene needs: a :class:`FrictionController`
    with friction at via points (``friction`` its model if built, ``start``
    the robot's friction state, default the scene's start state driven to
    ``contraction``; ``x0`` is not used: a pose alone is not a friction
    state), else a :class:`Controller` (``start`` not used)."""
    if friction is None and has_friction(model):
        friction = FrictionModel(model)
    if friction is None:
        return Controller(model, targets, contraction, frozen, x0, options)
    return FrictionController(model, friction, targets, contraction, frozen, start, options)


class FrictionController(Controller):
    """:class:`Controller` whose iterates follow the robot's path.

    Parameters (besides the loop's; ``x0`` is replaced by ``start``)
    ------------------------------------------------------------------
    friction : the scene's :class:`FrictionModel`.
    start : the robot's friction state to start from (default: the scene's
        start state driven to ``contraction`` in ``DEFAULT_PATH_STEPS``).
    """

    follows_friction = True

    def __init__(self, model, friction: FrictionModel, targets, contraction=None, frozen=None,
                 start: FrictionState | None = None, options: ControlOptions | None = None):
        super().__init__(model, targets, contraction, frozen, None, options)
        self.fm = friction
        self.state = start           # the robot's state at the current iterate

    def _solve(self, c, x0, options: EquilibriumOptions | None = None) -> FrictionEquilibrium:
        options = options or self.options.equilibrium
        if self.state is None:       # the first solve: from the scene's start state
            eq = solve_forward(self.fm, c, DEFAULT_PATH_STEPS, equilibrium=options)
        else:
            eq = drive(self.fm, self.state, c, equilibrium=options, origin=CONTROL_ORIGIN)
        self._solves += 1
        self._newton += eq.iterations
        return eq

    def _start(self):
        first = super()._start()
        self.state = self._eq.friction
        return first

    def _accept(self, xi_t, eq, last):
        super()._accept(xi_t, eq, last)
        self.state = eq.friction

    def _jump(self, c, eq):
        self.state = eq.friction
        return super()._jump(c, eq)

    def _gradient(self, eq: FrictionEquilibrium, need_jacobian: bool):
        """dO/dc in the current stick/slip modes (and Gauss-Newton's Jacobian)."""
        free = np.flatnonzero(~self.frozen)
        dxdc = path_sensitivity(self.fm, eq.friction, eq.factor, columns=free)
        if need_jacobian:
            B = self.targets.selection(self.model.n_dofs)
            J = np.repeat(np.sqrt(self.targets.weight), 2)[:, None] * (B @ dxdc)
            grad = J.T @ self.targets.residual(eq.x)
            grad[self.frozen] = 0.0
            return grad, J, dxdc
        grad = dxdc.T @ self.targets.gradient(eq.x)
        grad[self.frozen] = 0.0
        return grad, None, None

    def result(self, eigenvalue: bool = True):
        """As :meth:`Controller.result`; the final state is certified at its
        segment rest lengths and carries the path of accepted iterates."""
        if not self._finished:
            for _ in self.iterates():
                pass
        last = self.history[-1]
        eq = self._certified(eigenvalue)
        self.history[-1] = dataclasses.replace(last, equilibrium=eq)
        self._eq = eq
        return super().result(eigenvalue=False)

    def _certified(self, eigenvalue: bool) -> FrictionEquilibrium:
        path = np.array([it.contraction for it in self.history])
        eq = finish(self.fm, self.state, path, len(path),
                    EquilibriumOptions(eigenvalue=eigenvalue, escape_saddles=False))
        return dataclasses.replace(eq, origin=CONTROL_ORIGIN)
