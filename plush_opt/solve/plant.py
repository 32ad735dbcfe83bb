"""The plant: the forward model of one scene as one object that owns its
history (docs/plant.md).

A plant answers what the body does when its winches are driven: the pose
(an :class:`~plush_opt.solve.equilibrium.Equilibrium`) at contractions c,
how that pose moves with c, and the final certified pose of a path. Some
physics carries history (friction at via points: the pose at c depends on
how the winches got there), so a plant keeps a **committed state** and

* :meth:`Plant.drive` reaches contractions c *from* the committed state
  (following the path in steps where the physics is path-dependent), and
  returns the equilibrium there without committing it;
* :meth:`Plant.commit` makes an equilibrium the new committed state: a
  caller commits only what it accepts (a control iterate, a pose shown,
  a run step), never a trial;
* :meth:`Plant.reset` sets (or clears) the committed state, and
  :meth:`Plant.fork` gives a plant of the same physics with its own
  history, so that one problem can serve several histories.

:func:`make_plant` is the one place that asks whether a scene has friction
(at via points or at contacts); :func:`path_dependent` gives its answer
for a scene before any model is built (the accuracy sweep builds one per
mesh level). Control and the apps ask the plant (``path_dependent``,
:meth:`Plant.require_history_free`, ``history_note``) or that function,
never the scene.
"""

from __future__ import annotations

from ..base.errors import SceneError
from ..fem.friction import friction_tendons
from ..fem.model import Model
from .contact_plant import ContactFrictionPlant
from .elastic_plant import ElasticPlant
from .friction_plant import FrictionPlant
from .friction_solve import path_record, segment_table
from .plant_base import Plant

__all__ = ["ContactFrictionPlant", "ElasticPlant", "FrictionPlant", "Plant", "make_plant", "path_dependent",
           "path_record", "segment_table"]


def path_dependent(scene) -> bool:
    """Whether ``scene``'s plant is path-dependent (friction at via points
    or at contacts), read off the scene alone: what :func:`make_plant`
    decides, without building the model."""
    return bool(friction_tendons(scene)) or _contact_friction(scene)


def _contact_friction(scene) -> bool:
    return scene.contact is not None and scene.contact.friction > 0


def make_plant(model: Model, *, segmented: bool = False) -> "Plant":
    """The plant of ``model``'s scene: the one place that decides whether
    the scene's physics is path-dependent.

    Parameters
    ----------
    model : the energy :class:`~plush_opt.fem.model.Model`.
    segmented : split every tendon with an interior via point into
        segments, frictionless ones too (they slip freely: the same poses
        as one spring, with the tension of every segment reported), for
        paths that report both end tensions of every tendon (the sweep).

    Returns
    -------
    A :class:`~plush_opt.solve.contact_plant.ContactFrictionPlant` when the
    contact has friction (``segmented`` or not); a :class:`~plush_opt.solve.friction_plant.FrictionPlant`
    when a tendon has friction and an interior via point (or ``segmented``);
    else an :class:`ElasticPlant`. Nothing is committed: the plant starts at the
    scene's start state.
    """
    contact_friction = _contact_friction(model.scene)
    if contact_friction and friction_tendons(model.scene):
        raise SceneError(f"{model.scene.source}: contact.friction: friction at contacts and friction at via "
                         "points in one scene are not supported together; set one of them to 0")
    if contact_friction:        # (segmented or not: its tendons are frictionless springs, one tension each)
        return ContactFrictionPlant(model)
    if segmented or friction_tendons(model.scene):
        return FrictionPlant(model, include_frictionless=segmented)
    return ElasticPlant(model)
