"""Element and mesh from an accuracy tolerance, with an error estimate that
accounts for the convergence rate.

A finer mesh predicts the pose better and costs more per equilibrium solve
(and much more in the bilevel method). :func:`choose_mesh` solves the
equilibrium at a few contractions on a sequence of meshes, coarse to fine,
for each element type (in the order of their predicted cost, below), and
estimates the error of each level's predicted positions of a
few body points (the targets, or else the tendon stoppers and the scene's
extra points). The levels are two families of nested meshes (a graded
mesh refined uniformly, 4x the nodes per step), interleaved so that each
level has about twice the nodes of the one before; within a family

    d_k = max |y_k - y_{k+1}|,  r_k = max(d_k / d_{k-1}, r_theory),
    error_k <= SAFETY d_k / (1 - r_k)

(the remaining differences d_k + d_{k+1} + ... summed as a geometric series
with the observed ratio: Richardson extrapolation with the observed order,
bounded by the triangle inequality). ``r_theory`` is the ratio the element's
best expected order gives for the refinement, so a coincidentally small
difference never makes the estimate optimistic; a ratio near 1 (no
convergence, e.g. under a point load) gives no estimate at all. Explicit
levels (independent meshes, whose differences scatter) take the larger
ratio of both sides and need the next level's estimate to confirm theirs.
The picked level is the one with the least measured solve time whose
estimate is below the tolerance, or whose distance to such a level plus
that level's estimate is below it (:func:`bound_errors`: a coarse level
without an estimate of its own can still be shown close enough);
docs/accuracy.md has the reasoning and the measurements. The estimates
and bounds are :mod:`plush_opt.solve.accuracy_estimate`; the order in
which the default levels are solved, from each level's predicted cost,
and where the sweep stops (as soon as a level meets the tolerance) is
:mod:`plush_opt.solve.accuracy_sweep`.

:func:`transfer_pose` carries a pose from one mesh of a scene to another
(interpolation of the displacement); the finer level's solve starts from
it, so every level follows the same branch of equilibria.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time

import numpy as np

# the estimate's names are also this module's (callers import them from here)
from .accuracy_estimate import (EXPECTED_ORDER, MAX_RATIO, SAFETY, Level, Resolution,  # noqa: F401
                                _json_number, bound_errors, cheapest_meeting, estimate_each_element,
                                estimate_errors, estimate_levels, leave_out_creases, one_pose)
from .accuracy_sweep import EXTRA_BUDGET, Chain, Planner
# carrying poses between levels (callers import these from here too)
from .accuracy_carry import (BRANCH_ITERATIONS, BRANCH_PROGRESS, branch_options, carried_start,  # noqa: F401
                             solve_on_branch, transfer_pose, transfer_pose_piecewise_linear)
from .equilibrium import Equilibrium, EquilibriumOptions, solve_equilibrium
from ..base.errors import SceneError
from ..base.linalg import NotPositiveDefinite
from ..base.geometry import body_area
from ..fem.contact import rest_pushes
from ..fem.contact_boundary import crossings
from ..fem.mesh import Mesh, area_for_nodes, build_mesh
from ..fem.model import Model, build_model
from ..fem.objective import Targets
from ..io.scene import Scene
from .plant import make_plant, path_dependent
from .work import counted

log = logging.getLogger(__name__)

#: The default sweep: per element, two families of nested meshes. Family A
#: starts from the graded mesh at COARSEST x the file's max_area, family B
#: from the graded mesh with about twice its nodes; each is refined
#: uniformly (every triangle split in four) up to REFINEMENTS times. Within
#: a family each level has 4x the nodes of the one before and, the meshes
#: being nested, the differences shrink at the element's rate without the
#: scatter of meshes made independently (docs/accuracy.md); interleaved by
#: size, each level has about twice the nodes of the one before, so a level
#: picked because the one before it missed the tolerance is at most about
#: 2x too fine. The finest (A refined 3 times, 64x the coarsest's nodes)
#: is the budget of a tolerance that cannot be met.
COARSEST = 16.0
REFINEMENTS = 3
#: Family B's first mesh has about this many times family A's nodes (the
#: geometric middle of A's 4x steps).
INTERLEAVE = 2.0
#: The levels' meshes are graded towards reentrant corners, the ends of
#: pinned boundary and the tendons' attachment discs (plush_opt.fem.grading):
#: uniform levels converge there like h^1.1 whatever the element (and
#: resolve a disc only below its radius), agreeing long before they are right.
GRADED = True
#: Continuation steps from rest where a level's Newton fails (:func:`equilibrium_at`).
CONTINUATION_STEPS = 4
#: A level counts as finer than the previous one only with this many times
#: its nodes (explicit levels; family B is dropped below this).
MIN_REFINEMENT = 1.3
#: A level keeps its model (solved again at the returned contractions) up to
#: this many nodes: small models are rebuilt at a cost like their solve's,
#: while a 67,313-node P2 model holds about 260 MB.
KEEP_MODEL_NODES = 20_000
#: Element types of the sweep (explicit levels: swept in this order, P2
#: first, its cost bounding how far the P1 sweep goes; the default
#: levels: in the order of plush_opt.solve.accuracy_sweep, the first
#: element the fallback when nothing meets the tolerance).
ELEMENT_ORDER = ("P2", "P1")
#: The levels' equilibria are solved to this residual (relative to the force
#: scale), not the default 1e-10: the force scale, a 2-norm of nodal forces,
#: halves with each uniform refinement while the residual's round-off floor
#: (eps |H| |x|) grows, and on the finest graded levels the floor comes
#: within a factor of a few of 1e-10 (docs/notes/accuracy-measurements.md). A
#: residual of 1e-9 moves the compared points by about 1e-9 of the
#: displacement, far below any difference the estimate uses.
#: A positive definite pose whose residual stalls within its round-off floor
#: (plush_opt.solve.certificate.roundoff_floor) is converged as well.
LEVEL_OPTIONS = EquilibriumOptions(eigenvalue=False, gtol=1e-9, roundoff=1.0)
#: Where the pose depends on the path, each probe contraction is reached by
#: a straight path from the start state in this many steps (a plain solve
#: takes ten): every level follows the same path, so the step count only has
#: to converge, and half the steps halve the sweep's cost (gripper_friction's
#: 2,415-node P2 level: its three probes 8.4 CPU s in ten steps, 4.0 in five,
#: the poses 6e-5 mm apart). The pose at the returned contractions is
#: estimated on the path that reached it (plush_opt.solve.accuracy_path).
PROBE_PATH_STEPS = 5


def equilibrium_at(model: Model, contraction, x0=None,
                   options: EquilibriumOptions | None = None, steps: int = CONTINUATION_STEPS) -> Equilibrium:
    """Certified equilibrium at ``contraction`` from ``x0`` (default the rest
    pose); if that fails, by continuation from the rest contraction (0
    clipped to the bounds) in ``steps`` steps, each halved where it fails
    (:func:`~plush_opt.solve.equilibrium.continuation`)."""
    options = options or LEVEL_OPTIONS
    c = np.asarray(contraction, dtype=np.float64)
    if x0 is not None and not model.admissible(x0):
        x0 = None
    return solve_equilibrium(model, c, x0, dataclasses.replace(options, continuation=steps))


def level_mesh(scene: Scene, res: Resolution, announce: bool = True):
    """The mesh of the level of resolution ``res`` of ``scene`` (of its element)."""
    return build_mesh(scene, max_area=res.max_area, graded=GRADED, refinements=res.refinements, announce=announce)


def base_area(scene: Scene) -> float:
    """The max_area resolution sweeps scale: the problem file's, or 1/400 of
    the body area if the file leaves it to the mesher's angle bound."""
    if scene.outline is None:
        raise SceneError(f"{scene.source}: mesh: an explicit mesh cannot be resized")
    if scene.max_area is not None:
        return float(scene.max_area)
    body = body_area(scene.outline, scene.holes)
    return body / 400.0


def default_levels(scene: Scene, element: str = "P2",
                   refinements: int = REFINEMENTS) -> tuple[Resolution, ...]:
    """The default sweep of one element, coarse to fine: families A and B
    (see :data:`COARSEST`) interleaved, A refined up to ``refinements``
    times, B one time less. Family B is left out if no mesh has clearly
    more nodes than A's first (a scene the angle bound and its forced
    points already mesh finely)."""
    s = dataclasses.replace(scene, element=element)
    a = base_area(scene) * COARSEST
    n_a = build_mesh(s, max_area=a, graded=GRADED).n_nodes
    b, mesh_b = area_for_nodes(s, int(INTERLEAVE * n_a), graded=GRADED, rel_tol=0.1)
    with_b = b < a and mesh_b.n_nodes >= MIN_REFINEMENT * n_a
    levels = []
    for r in range(refinements + 1):
        levels.append(Resolution(a, r, a))
        if with_b and r < refinements:
            levels.append(Resolution(b, r, b))
    return tuple(levels)


def probe_points(scene: Scene) -> tuple[np.ndarray, str]:
    """Body points (rest coordinates, (k, 2)) whose predicted positions are
    compared between meshes: the targets if any, else the tendon stoppers
    and the scene's extra points."""
    if scene.targets:
        return np.array([t.at for t in scene.targets], dtype=np.float64), "targets"
    pts = [t.path[0] for t in scene.tendons] + [p for p in scene.points]
    if not pts:
        pts = list(scene.outline) if scene.outline is not None else list(scene.nodes[:4])
        return np.array(pts, dtype=np.float64), "outline vertices"
    return np.array(pts, dtype=np.float64), "tendon stoppers and points"


def probe_contractions(scene: Scene) -> np.ndarray:
    """The contractions the meshes are compared at, (m, n_winches): the
    scene's own and, for a control problem, each free winch alone at
    mid-range (the others at the scene's): the poses the controller
    combines. Not all of them at once: antagonists pulling against each
    other can drive the body past a pitchfork (two stable bent states
    close together, and which one a solve finds depends on the mesh and
    the start), and such a pose measures the branch a mesh picks, not its
    discretisation error (docs/accuracy.md)."""
    cs = [scene.contraction.copy()]
    if scene.targets:
        for w in np.flatnonzero(~scene.frozen):
            c = scene.contraction.copy()
            c[w] = 0.5 * (scene.lower[w] + scene.upper[w])
            if not any(np.array_equal(c, other) for other in cs):
                cs.append(c)
    return np.array(cs)


class RestPushes(SceneError):
    """An accuracy level whose self-contact pushes in the rest pose: its
    boundary is cut finer than ``contact.distance`` allows, and every finer
    level of its family is too (a refinement halves the segments)."""

    def __init__(self, message: str, nodes: int):
        super().__init__(message)
        self.nodes = nodes


def level_model(scene: Scene, mesh: Mesh) -> Model:
    """The model of an accuracy level; :class:`RestPushes` where its
    self-contact pushes in the rest pose (its boundary is cut finer than
    ``contact.distance``): its unloaded body would not be at rest, so its
    poses estimate nothing about the file's."""
    model = build_model(scene, mesh)
    pushes = rest_pushes(model.contact, model.X)
    if pushes is not None:
        raise RestPushes(f"{scene.source}: accuracy: on the {scene.element} mesh of {mesh.n_nodes:,} nodes, {pushes}; "
                         "self-contact needs a contact.distance below the length of the boundary's segments "
                         "on every mesh the accuracy sweep solves (a refinement halves them)", mesh.n_nodes)
    return model


def _solve_level(scene: Scene, res: Resolution, cs, points, prev: Level | None,
                 options: EquilibriumOptions, follow: bool = False, sources=()) -> Level | None:
    """Mesh ``scene`` at ``res``, time one cold solve on it, and solve at
    every contraction of ``cs`` from the previous level's poses. None if
    an explicit level is not really finer than ``prev``. With ``follow``,
    each pose follows the branch of ``prev`` (if given) and the levels
    ``sources`` (solved at the same contractions), from the first of their
    poses that carries over admissibly (:func:`carried_start`,
    :func:`branch_options`), and
    where it does not converge the level is returned off
    the branch (its pose None, ``y`` NaN) instead of solved by
    continuation."""
    t0 = time.perf_counter()
    mesh = level_mesh(scene, res)
    t_mesh = time.perf_counter() - t0
    if res.family is None and prev is not None and mesh.n_nodes < MIN_REFINEMENT * prev.mesh.n_nodes:
        # not really finer (forced points and the angle bound dominate)
        log.info("accuracy: %s max_area %.4g is not finer than the previous level: skipped",
                 scene.element, res.max_area)
        return None
    model = level_model(scene, mesh)
    probe = Targets.at_points(mesh, points, points)
    # where the pose depends on the path (friction), the pose at c is the plant's: the end of a
    # fresh path from the scene's start state (a pose alone is no start: x0 is not used)
    plant = make_plant(model) if path_dependent(scene) else None
    # the cost: one solve from rest at the file's contractions (a plain solve on this mesh),
    # not at a probe (a returned contraction can be far from rest, and its cold solve slow)
    timed = scene.contraction
    try:                          # the factorisation's symbolic analysis: setup, not timed
        model.factorizer.factor(model.evaluate(model.X, timed, order=2).hessian_form)
    except NotPositiveDefinite:   # (analysed all the same)
        pass
    with counted(model) as work:      # the cost the choices compare: counted, the same on every run
        cold = solve_equilibrium(model, timed, None, options) if plant is None else \
            plant.equilibrium(timed, options=options)
    t_solve = work.cpu_s              # (reported: it varies with what else runs on the machine)
    poses, ys = [], []
    for j, c in enumerate(cs):
        x0 = transfer_pose(prev.mesh, prev.poses[j], mesh) if prev is not None and plant is None else None
        # (a path-dependent plant has no branch to follow from a carried pose: a pose alone is no state)
        start = carried_start(model, [(lv.mesh, lv.poses[j]) for lv in ([prev] if prev is not None else [])
                                      + list(sources)]) if follow and plant is None else None
        if start is not None:
            eq = solve_on_branch(model, c, start, options)
            poses.append(eq.x if eq.converged else None)
            ys.append(probe.y(eq.x) if eq.converged else np.full((len(points), 2), np.nan))
            continue
        eq = cold if x0 is None and np.array_equal(c, timed) and cold.converged else \
            equilibrium_at(model, c, x0, options) if plant is None else \
            plant.equilibrium(c, options=options, steps=PROBE_PATH_STEPS)
        if not eq.converged:
            raise SceneError(f"{scene.source}: accuracy: no certified equilibrium at contraction "
                             f"{c.tolist()} on the {scene.element} mesh with max_area "
                             f"{res.max_area:g} refined {res.refinements} times: {eq.status}")
        poses.append(eq.x)
        ys.append(probe.y(eq.x))
    log.info("accuracy: %s max_area %.4g refined %d times, %d nodes, one solve %.3f s", scene.element,
             res.max_area, res.refinements, mesh.n_nodes, t_solve)
    return Level(scene.element, res, mesh, t_mesh, t_solve, cold.iterations, poses, np.array(ys),
                 model=model if mesh.n_nodes <= KEEP_MODEL_NODES else None,
                 crossing=crossings(model, poses, creases_only=True),
                 work=work.seconds if options.backend == "newton" else None)   # (IPOPT's own work is not counted)


def sweep(scene: Scene, element: str, levels, cs, points, tol: float, options,
           time_limit: float = math.inf, solved: dict | None = None, progress=None) -> list[Level]:
    """Levels of one element, coarse to fine, until one meets ``tol``, the
    levels run out, or a level's solve costs more than ``time_limit`` (the
    best other candidate's :attr:`Level.cost`: no finer level of this
    element can beat it).
    ``levels`` are :class:`Resolution` (or plain max_area values: an
    explicit sequence of independent meshes). ``solved`` maps (element,
    resolution) to levels solved before at the same contractions and
    points: they are reused, and the levels solved here are added.
    ``progress(line)``, if given, hears of each level solved."""
    scene = dataclasses.replace(scene, element=element)
    solved = {} if solved is None else solved
    done: list[Level] = []
    for res in levels:
        res = res if isinstance(res, Resolution) else Resolution(float(res))
        level = solved.get((element, res))
        if level is None:
            t0 = time.perf_counter()
            level = _solve_level(scene, res, cs, points, done[-1] if done else None, options)
            if level is None:
                continue
            solved[(element, res)] = level
            if progress is not None:
                progress(f"accuracy: {element} level of {level.mesh.n_nodes:,} nodes solved at {len(cs)} "
                         f"contraction(s) in {time.perf_counter() - t0:.1f} s")
        done.append(level)
        estimate_levels(done)
        if any(lv.meets(tol) for lv in done) or done[-1].cost > time_limit:
            break
    return done


def _cheapest_meeting(levels: list[Level], tol: float) -> Level | None:
    """The level of least cost (:attr:`Level.cost`) whose bound is within ``tol`` (bounds set first)."""
    bound_errors(levels)
    k = cheapest_meeting(levels, tol)
    return None if k is None else levels[k]


def planned_sweep(scene: Scene, tol: float, elements, cs, points, options, solved: dict | None = None,
                  progress=None, follow: bool = False) -> tuple[Level | None, list[Level], Planner]:
    """The default levels of ``elements`` solved in the order
    :class:`~plush_opt.solve.accuracy_sweep.Planner` gives (the cheapest
    predicted way to a level that meets ``tol``) until it stops: (the
    cheapest level meeting ``tol`` or None, the levels solved in the order
    solved, the planner: its ``stopped`` says why it stopped,
    ``not_solved()`` the levels it left). ``solved``, ``progress``: as in
    :func:`sweep`; ``follow``: each level follows the branch of the
    finest level of its element solved before it (:func:`_solve_level`)."""
    solved = {} if solved is None else solved
    chains = []
    for element in elements:
        s = dataclasses.replace(scene, element=element)
        levels = default_levels(scene, element)
        for family in dict.fromkeys(res.family for res in levels):
            n0 = build_mesh(s, max_area=family, graded=GRADED).n_nodes
            chains.append(Chain(element, tuple(res for res in levels if res.family == family), [n0]))
    plan = Planner(chains, tol)
    computed: list[Level] = []
    best = None
    while (chain := plan.pick(best)) is not None:
        res, element = chain.next, chain.element
        predicted = plan.cost.predict(element, chain.predicted_nodes(len(chain.solved))) if plan.cost.samples \
            else None
        level = solved.get((element, res))
        if level is None:
            prev = [lv for lv in computed if lv.element == element and lv.on_branch]
            others = sorted((lv for lv in {id(lv): lv for lv in [*computed, *solved.values()]}.values()
                             if lv.on_branch), key=lambda lv: -lv.mesh.n_nodes) if follow else []
            t0 = time.perf_counter()
            try:
                level = _solve_level(dataclasses.replace(scene, element=element), res, cs, points,
                                     max(prev, key=lambda lv: lv.mesh.n_nodes) if follow and prev else
                                     prev[-1] if prev else None, options, follow, others)
            except RestPushes as exc:     # this level and the finer ones of its family cannot be used
                plan.inadmissible(chain, exc.nodes, str(exc), progress)
                continue
            solved[(element, res)] = level
            if progress is not None:
                progress(f"accuracy: {element} level of {level.mesh.n_nodes:,} nodes solved at {len(cs)} "
                         f"contraction(s) in {time.perf_counter() - t0:.1f} s (one solve {level.t_solve:.2f} CPU s, "
                         f"counted {level.cost:.2f} s" + ("" if predicted is None else f", predicted {predicted:.2f}")
                         + ")"
                         + ("" if level.on_branch else ": no equilibrium near the branch it follows, left out"))
        if best is not None:
            plan.extra_spent += level.cost
        plan.solved(chain, level)
        computed.append(level)
        leave_out_creases(computed, cs, plan.left_out, progress)
        estimate_each_element(computed)
        best = _cheapest_meeting(computed, tol)
    plan.stopped = _stopped(plan, best, tol)
    if progress is not None:
        left = plan.not_solved()
        skipped = "" if not left else "; not solved: " + ", ".join(
            f"{row['element']} ~{row['predicted_nodes']:,} nodes ({row['predicted_t_solve_s']:.2g} s)"
            for row in sorted(left, key=lambda row: row["predicted_nodes"]))
        progress(f"accuracy: {plan.stopped}{skipped}")
    return best, computed, plan


def _not_used(cut: list[dict]) -> str:
    """The levels a sweep could not use (``Planner.cut`` rows), in words."""
    levels = ", ".join(f"{row['element']} {row['nodes']:,} nodes" for row in cut)
    return f"{levels} and the finer ones of their families"


def _stopped(plan: Planner, best: Level | None, tol: float) -> str:
    """Why the planned sweep stopped, in words."""
    if best is not None:
        return (f"stopped: the {best.element} level of {best.mesh.n_nodes:,} nodes meets {tol:g}, and no "
                f"level left is predicted to cost less within {EXTRA_BUDGET:g} x its cost")
    first = plan.chains[0]
    cut = "" if not plan.cut else f"; levels not used (self-contact pushes in their rest pose): {_not_used(plan.cut)}"
    return (f"stopped: no level is predicted to meet {tol:g} within the default levels (tolerance not "
            f"met): the {first.element} levels of its first family solved to the finest, "
            f"{first.solved[-1].mesh.n_nodes:,} nodes{cut}" if first.solved else
            f"stopped: no level is predicted to meet {tol:g} within the default levels (tolerance not met){cut}")


def _check_arguments(tol, levels, scene: Scene):
    if isinstance(tol, bool) or not (isinstance(tol, (int, float)) and math.isfinite(tol) and tol > 0):
        raise SceneError(f"{scene.source}: accuracy: the tolerance must be a finite number > 0, "
                         f"got {tol!r}")
    if levels is None:
        return float(tol), None
    levels = tuple(float(a) for a in levels)
    if len(levels) < 3 or any(not (a > 0 and math.isfinite(a)) for a in levels) \
            or any(b >= a for a, b in zip(levels, levels[1:])):
        raise SceneError(f"{scene.source}: accuracy: levels must be >= 3 max_area values > 0, "
                         f"strictly decreasing (coarse to fine), got {list(levels)!r}")
    return float(tol), levels


def choose_mesh(scene: Scene, tol: float, levels=None, contractions=None, points=None,
                options: EquilibriumOptions | None = None,
                elements=ELEMENT_ORDER, solved: dict | None = None) -> tuple[Mesh, dict]:
    """The element and mesh that predict the pose to within ``tol`` at the
    least cost of a solve (:attr:`Level.cost`).

    Parameters
    ----------
    scene : an outline scene (an explicit mesh is returned unchanged).
    tol : largest acceptable estimated error (length units) of the
        predicted positions of the compared points.
    levels : max_area values (length^2) of independent graded meshes,
        coarse to fine (strictly decreasing, at least 3); default: the
        nested families of :func:`default_levels`.
    contractions : (m, n_winches) contractions to compare at; default
        :func:`probe_contractions`.
    points : (k, 2) rest coordinates of the compared body points; default
        :func:`probe_points`.
    options : equilibrium options.
    elements : element types to try ("P2", "P1").
    solved : levels solved before at the same contractions and points,
        keyed (element, resolution); reused, and added to (see :func:`sweep`).

    Returns
    -------
    mesh : the chosen mesh (its ``element`` is the chosen element).
    report : dict (JSON-able): ``tolerance``, ``estimated_error`` (None if
        no level has an estimate), ``element``, ``nodes``, ``reached``
        (False: no level met ``tol``; the finest level computed is returned
        and ``estimated_error`` is the estimate of the level before it, a
        bound while the levels converge), ``status``, ``max_area``,
        ``bound_via`` (the index in ``levels`` of the level whose estimate
        the picked level's bound rests on, see :func:`bound_errors`),
        ``levels`` (per level computed: element, max_area, n_nodes,
        t_solve_s, difference_to_next, ratio, estimated_error, confirmed, withdrawn,
        error_bound, bound_via), ``points``,
        ``contractions``, ``summary``.

    Raises
    ------
    SceneError
        Bad ``tol``/``levels``, a point off the body, or a level whose
        equilibrium cannot be certified.
    """
    if scene.outline is None:
        return _explicit(scene, tol)
    best, computed, report = choose_levels(scene, tol, levels, contractions, points, options, elements, solved)
    return best.mesh, report


def choose_levels(scene: Scene, tol: float, levels=None, contractions=None, points=None,
                  options: EquilibriumOptions | None = None, elements=ELEMENT_ORDER,
                  solved: dict | None = None, progress=None, follow: bool = False) -> tuple[Level, list[Level], dict]:
    """:func:`choose_mesh` of an outline scene, with its levels: (the picked
    level, every level computed in the order of ``report["levels"]``, the
    report). The levels let the error be estimated again at other
    contractions (:func:`plush_opt.solve.accuracy_check.bounds_at`).
    ``progress(line)``, if given, hears of each level solved; ``follow``:
    default levels follow the branch of the levels solved before them
    (:func:`planned_sweep`: at a returned contraction, from its answer)."""
    options = options or LEVEL_OPTIONS
    tol, levels = _check_arguments(tol, levels, scene)
    if points is None:
        points, kind = probe_points(scene)
    else:
        points, kind = np.asarray(points, dtype=np.float64).reshape(-1, 2), "given points"
    cs = probe_contractions(scene) if contractions is None else \
        np.asarray(contractions, dtype=np.float64).reshape(-1, len(scene.winches))
    computed: list[Level] = []
    best: Level | None = None
    plan = None
    if levels is None:
        best, computed, plan = planned_sweep(scene, tol, elements, cs, points, options, solved, progress,
                                              follow)
    else:
        for element in elements:
            computed += sweep(scene, element, levels, cs, points, tol, options,
                              math.inf if best is None else best.cost, solved, progress)
            best = _cheapest_meeting(computed, tol)
    if not computed and plan is not None and plan.cut:      # not even the coarsest level can be used
        raise SceneError(plan.cut[0]["why"])
    reached = best is not None
    if not reached:
        best = _fallback(computed, elements)
    report = {
        "tolerance": tol, "estimated_error": _json_number(best.bound if reached else _bound(computed, best)),
        "element": best.element, "nodes": best.mesh.n_nodes, "reached": reached,
        "status": "met" if reached else "tolerance_not_met", "max_area": best.max_area,
        "graded": GRADED, "refinements": best.resolution.refinements,
        "n_elems": best.mesh.n_elems, "t_solve_s": best.t_solve, "work_s": best.work,
        "picked": computed.index(best), "bound_via": best.bound_via if reached else None,
        "points": kind, "n_points": int(len(points)),
        "contractions": cs.tolist(), "levels": [lv.row() for lv in computed],
    }
    if plan is not None:
        report["not_solved"] = plan.not_solved()
        report["stopped"] = plan.stopped
        report["left_out"] = plan.left_out
        report["not_admissible"] = plan.cut
    report["summary"] = summary(report)
    report["point_coordinates"] = points.tolist()
    return best, computed, report


def _explicit(scene: Scene, tol) -> tuple[Mesh, dict]:
    """An explicit mesh: returned as it is, its error not estimated."""
    _check_arguments(tol, (3.0, 2.0, 1.0), scene)
    mesh = build_mesh(scene)
    report = {"tolerance": float(tol), "estimated_error": None, "element": mesh.element.name,
              "nodes": mesh.n_nodes, "reached": False, "status": "explicit_mesh",
              "max_area": None, "graded": False, "refinements": None, "levels": [],
              "summary": "explicit mesh: its resolution is fixed and its error not estimated"}
    return mesh, report


def _fallback(computed: list[Level], elements) -> Level:
    """No level met the tolerance: the finest level of the first element
    (of any, if none of it was solved)."""
    on = [lv for lv in computed if lv.on_branch] or computed
    first = [lv for lv in on if lv.element == elements[0]] or on
    return max(first, key=lambda lv: lv.mesh.n_nodes)


def _bound(computed: list[Level], level: Level):
    """The estimate of the level before ``level`` (same element and family):
    a bound of its error while the levels converge; None if there is none."""
    same = [lv for lv in computed if lv.element == level.element
            and lv.resolution.family == level.resolution.family]
    i = same.index(level)
    return same[i - 1].estimate if i > 0 else None


def summary(report: dict) -> str:
    """One line for the user: which element and mesh, the estimate, honestly."""
    if not report.get("levels"):
        return report.get("summary", "")
    left = report.get("left_out") or []
    aside = "" if not left else \
        ("; left out of the mesh choice: contraction(s) " + ", ".join(str(r["contraction"]) for r in left)
         + ", where the body creases through itself (the scene has no contact.self)")
    row = report["levels"][report["picked"]]
    refined = f" refined {report['refinements']}x" if report.get("refinements") else ""
    where = (f"{report['element']} elements, {report['nodes']} nodes (max_area {report['max_area']:.4g}"
             f"{refined}, one solve {row['t_solve_s']:.3f} s)")
    est = report["estimated_error"]
    if report["reached"]:
        via = report.get("bound_via")
        how = "" if via in (None, report["picked"]) else \
            (f", its distance to the {report['levels'][via]['n_nodes']}-node "
             f"{report['levels'][via]['element']} level plus that level's estimate")
        return (f"{where}: estimated error of the {report['points']} {est:.3g} <= tolerance "
                f"{report['tolerance']:.3g} (the cheapest level that meets it{how}){aside}")
    if report.get("solved_again"):
        # the level the answer was solved again on, chosen at the returned contractions: the
        # probes' estimate is not what holds for the answer (its own line says that)
        there = "no estimate" if est is None else f"estimated error {est:.3g}"
        return (f"{where}, the level chosen at the returned contractions; at the probe contractions: "
                f"{there} against tolerance {report['tolerance']:.3g}{aside}")
    bound = "no estimate (the levels do not converge)" if est is None else \
        f"estimated error {est:.3g} (bound from the level before it)"
    cut = report.get("not_admissible") or []
    if cut:
        aside += (f"; levels not used: {_not_used(cut)} (self-contact pushes in their rest pose: their "
                  "boundary is cut finer than contact.distance)")
    return (f"tolerance {report['tolerance']:.3g} NOT met within the mesh levels: using the finest, "
            f"{where}; {bound}{aside}")
