"""The history-free plant: the pose at contractions c is the Newton
equilibrium of the model (plush_opt/solve/equilibrium.py)."""

from __future__ import annotations

import dataclasses

from .branch import solve_on_branch
from .equilibrium import Equilibrium, certify, solve_equilibrium
from .plant_base import Plant, moved_note
from .sensitivity import objective_gradient, state_sensitivity


class ElasticPlant(Plant):
    """A history-free plant: the pose at c is a Newton equilibrium of the
    model (plush_opt/solve/equilibrium.py), whatever came before.

    Its committed state is the last accepted :class:`Equilibrium` (None
    before one): a :meth:`trial` stays on its stable branch; a
    :meth:`drive` solves from the ``x0`` the caller passes."""

    def state_of(self, eq: Equilibrium) -> Equilibrium:
        return eq

    def equilibrium(self, contraction, x0=None, options=None, steps=None) -> Equilibrium:
        return solve_equilibrium(self.model, contraction, x0, options, self.ipopt)

    def drive(self, contraction, x0=None, options=None, *, origin=None) -> Equilibrium:
        return solve_equilibrium(self.model, contraction, x0, options, self.ipopt)

    def trial(self, contraction, guess=None, options=None, *, origin=None) -> Equilibrium:
        here = self._state
        if here is None:
            raise ValueError("trial: nothing committed (commit the equilibrium the search is at)")
        # the committed equilibrium's factor starts the trial's Newton (a chord)
        return solve_on_branch(self.model, here.contraction, here.x, contraction, guess, options, self.ipopt,
                               chord=here.factor)

    def sensitivity(self, eq, columns=None):
        return state_sensitivity(self.model, eq, columns)

    def objective_gradient(self, eq, dO_dx, columns=None):
        return objective_gradient(self.model, eq, dO_dx)

    def finish(self, eq, path, options, *, origin=None) -> Equilibrium:
        # the pose does not depend on the path: certify it where it is
        return certify(self.model, eq) if options.eigenvalue else eq

    def certify(self, eq, options, *, origin=None) -> Equilibrium:
        return solve_equilibrium(self.model, eq.contraction, eq.x,
                                 dataclasses.replace(options, eigenvalue=True), self.ipopt)

    def recorded(self, doc, x, contraction, options, where):
        eq = solve_equilibrium(self.model, contraction, x, options, self.ipopt)
        return moved_note("the equilibrium at the recorded contractions, solved from the recorded pose",
                          eq, x)
