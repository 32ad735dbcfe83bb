"""Plausibility warnings for a problem file: values that are valid but
unlikely to mean what the file wants, most often a file written in other
units than it says (``units:``, default lengths in mm, forces in N, moduli in MPa).

:func:`plausibility_warnings` returns one line per finding, each naming the
key; :func:`~plush_opt.io.problem_file.load_scene` logs them as warnings.
:func:`large_mesh_note` is the line a large mesh is announced with.
Nothing is refused or repaired here: a file in consistent other units
solves correctly, only the outputs' unit labels are then wrong (a
``units:`` key makes them right).
"""

from __future__ import annotations

import math

from ..base.errors import format_number
from ..base.geometry import body_area
from .scene import Scene
from .units import DEFAULT_UNITS

#: one millimetre and one megapascal in SI units (thresholds below are in mm and MPa
#: and compared in the file's own units, ``Scene.units``)
MM, MPA = 1e-3, 1e6
#: A body smaller than this (mm) is implausible: a robot of felt or silicone is
#: centimetres to a metre across.
MIN_BODY_SIZE = 1.0
#: The tendon law's smoothing length above this fraction of the body's size
#: blurs the slack/taut transition over the whole body (the shipped files use
#: 0.01-0.05 mm on bodies of 100-200 mm, about 0.03 %).
MAX_SMOOTHING_FRACTION = 0.02
#: An attachment disc wider than this fraction of the body is not a stopper or
#: a felt hole (the shipped radii are 1-2 mm on 100-200 mm bodies).
MAX_RADIUS_FRACTION = 0.2
#: Young's modulus above this (MPa with mm and N) is stiffer than any soft
#: body (felt about 0.02, silicone 0.1-10, hard rubber about 100): a value in Pa?
MAX_SOFT_MODULUS = 1.0e3
#: typical moduli (Pa) quoted in that warning: felt, and silicone's range
FELT_MODULUS, SILICONE_MODULI = 2e4, (1e5, 1e7)
#: Earth's gravity (m/s^2), and the multiple of it above which a gravity is
#: implausible for a robot on a bench (a file in metres with the docs' 9810 is 1000 g)
EARTH_GRAVITY, MAX_GRAVITY = 9.81, 10.0
#: A mesh estimated above this many nodes is announced when it is built
#: (fem.mesh.build_mesh): meshing and solving it takes minutes; the hard
#: limit is fem.mesh.MAX_ELEMS triangles.
LARGE_MESH_NODES = 50_000
#: CPU seconds per node of one equilibrium solve from rest, for the large-mesh
#: note's estimate: the gripper (P1) took 4.5 s at 29,973 nodes and 9.6 s at
#: 59,759 on one core (`plush-opt bench problems/gripper.yaml --sizes
#: 10000,30000,60000 --inverse-max-nodes 0 --repeats 1`, forward CPU total).
SOLVE_SECONDS_PER_NODE = 160e-6
#: Nodes per (body area / max_area) of a mesh made by the mesher, per element
#: (measured on the shipped problems at and below their own max_area: 0.84-1.0
#: for P1, 3.2-3.7 for P2; the lower ends, as fine meshes approach them).
NODES_PER_AREA = {"P1": 0.85, "P2": 3.25}


def youngs_modulus(scene: Scene) -> float:
    """E of the scene's material, from its Lame parameters."""
    mu, lam = scene.material.mu, scene.material.lam
    return mu * (3 * lam + 2 * mu) / (lam + mu)


def estimated_nodes(scene: Scene, max_area: float | None = None) -> int | None:
    """About how many nodes meshing the outline at ``max_area`` (default the
    file's) gives; None for an explicit mesh or without a max_area."""
    area = scene.max_area if max_area is None else max_area
    if scene.outline is None or area is None:
        return None
    return int(NODES_PER_AREA.get(scene.element, NODES_PER_AREA["P2"]) * body_area(scene.outline, scene.holes)
               / area)


def large_mesh_note(scene: Scene, max_area: float, refinements: int = 0) -> str | None:
    """A line announcing a mesh estimated above :data:`LARGE_MESH_NODES`
    nodes (``max_area`` refined uniformly ``refinements`` times), with the
    time of one solve from rest on it (:data:`SOLVE_SECONDS_PER_NODE`), else None."""
    n = estimated_nodes(scene, max_area / 4.0 ** refinements)
    if n is None or n <= LARGE_MESH_NODES:
        return None
    refined = f" refined {refinements} times" if refinements else ""
    seconds = SOLVE_SECONDS_PER_NODE * n
    return (f"mesh.max_area: {format_number(max_area)}{refined} gives about {n:,} {scene.element} nodes "
            f"(more than {LARGE_MESH_NODES:,}): each equilibrium solve from rest takes about {seconds:.0f} s "
            "on one core, and control or --accuracy solves many (minutes); a larger max_area is faster")


def plausibility_warnings(scene: Scene) -> list[str]:
    """One line per implausible value, each starting with the key; values are
    judged and said in the file's units (``scene.units``)."""
    out = []
    u = scene.units
    size = scene.diameter
    if u == DEFAULT_UNITS:
        units = ("outputs print lengths in mm, forces in N, moduli in MPa: is the file in other units? "
                 "say which with units: {length: ..., force: ...}")
    else:
        units = f"the file says units: length {u.length}, force {u.force}, so moduli in {u.stress}"
    if u.metres(size) < MIN_BODY_SIZE * MM:
        out.append(f"mesh: the body is {size:.3g} across, implausibly small in {u.length} ({units})")
    eps = scene.tendon_smoothing
    if eps > MAX_SMOOTHING_FRACTION * size:
        out.append(f"tendons.smoothing: {eps:.3g} is {100 * eps / size:.3g} % of the body's size "
                   f"({size:.3g}), both in {u.length}; the tendons go slack to taut over that length, meant to be a "
                   f"small fraction of the body ({units})")
    for i, t in enumerate(scene.tendons):
        if t.attachment_radius > MAX_RADIUS_FRACTION * size:
            out.append(f"tendons.list[{i}].attachment_radius: {t.attachment_radius:.3g} is "
                       f"{100 * t.attachment_radius / size:.3g} % of the body's size ({size:.3g}): "
                       "a disc that wide is not a stopper or a felt hole")
            break
    if scene.gravity is not None:
        g = u.metres(math.hypot(*map(float, scene.gravity)))
        if g > MAX_GRAVITY * EARTH_GRAVITY:
            out.append(f"gravity: {g / EARTH_GRAVITY:.3g} times Earth's gravity ({EARTH_GRAVITY / u.metres(1.0):.4g} "
                       f"{u.gravity}): is it in {_other_length(u)}/s^2? ({units})")
    e = youngs_modulus(scene)
    if math.isfinite(e) and u.pascals(e) > MAX_SOFT_MODULUS * MPA:
        out.append(f"material: Young's modulus {e:.3g} is stiffer than any soft body in {u.stress} (felt "
                   f"about {_in_stress(u, FELT_MODULUS)}, silicone {_in_stress(u, SILICONE_MODULI[0])}-"
                   f"{_in_stress(u, SILICONE_MODULI[1])}; {units})")
    return out


def _in_stress(u, pascals: float) -> str:
    return f"{pascals / u.pascals(1.0):.3g}"


def _other_length(u) -> str:
    """The length unit a misplaced value most likely came from (mm for a
    file in metres, m otherwise)."""
    return "mm" if u.length != "mm" else "m"
