"""The problem file's ``contact`` section -> :class:`~plush_opt.io.scene.Contact`.

What can be checked without a mesh is checked here: keys and types, the
floor's slope, each obstacle a simple polygon, d_hat > 0 and no larger
than the body, a positive barrier stiffness, friction >= 0. That the rest
pose is admissible (no boundary node on or below the floor or inside an
obstacle) needs the mesh's boundary: the contact term checks it when it is
built (plush_opt/fem/contact.py), naming the same keys.
"""

from __future__ import annotations

import numpy as np

from ..base.errors import format_number, shown
from .checker import Checker, at_index, at_key
from .mesh_input import check_ring
from .scene import Contact, Ground, Obstacle

_CONTACT_KEYS = ("ground", "obstacles", "self", "distance", "stiffness", "friction")
_GROUND_KEYS = ("height", "slope")
_OBSTACLE_KEYS = ("name", "outline")
#: a floor steeper than this is a wall: the body is on its upper side, and a
#: slope of +-90 degrees has none
MAX_SLOPE = 89.0
#: obstacles per file and outline points per obstacle: every obstacle edge is
#: a candidate for every boundary node near it
MAX_OBSTACLES, MAX_OBSTACLE_POINTS = 100, 10_000


def contact_section(ck: Checker, raw, diameter: float) -> Contact | None:
    """The validated ``contact`` section (None when absent); ``diameter`` is
    the body's (length units): d_hat may not exceed it."""
    if raw is None:
        return None
    ck.mapping(raw, "contact", _CONTACT_KEYS, required=("distance",))
    ground = _ground(ck, raw.get("ground"))
    obstacles = _obstacles(ck, raw.get("obstacles"))
    self_contact = False if raw.get("self") is None else ck.boolean(raw["self"], "contact.self")
    if ground is None and not obstacles and not self_contact:
        ck.fail("contact", "nothing to touch: give contact.ground, contact.obstacles or self: true")
    distance = ck.number(raw["distance"], "contact.distance", gt=0)
    if distance > diameter:
        ck.fail("contact.distance", f"d_hat {format_number(distance)} is larger than the body "
                f"(diameter {format_number(diameter)}): contact would push from across the body")
    stiffness = raw.get("stiffness")
    stiffness = None if stiffness is None else ck.number(stiffness, "contact.stiffness", gt=0)
    friction = 0.0 if raw.get("friction") is None else ck.number(raw["friction"], "contact.friction", ge=0)
    return Contact(ground=ground, obstacles=obstacles, self_contact=self_contact,
                   distance=distance, stiffness=stiffness, friction=friction)


def _ground(ck: Checker, raw) -> Ground | None:
    if raw is None:
        return None
    ck.mapping(raw, "contact.ground", _GROUND_KEYS)
    height = 0.0 if raw.get("height") is None else ck.number(raw["height"], "contact.ground.height")
    height = ck.point([0.0, height], "contact.ground.height")[1]       # (the coordinate limit)
    slope = 0.0 if raw.get("slope") is None else ck.number(raw["slope"], "contact.ground.slope")
    if abs(slope) > MAX_SLOPE:
        ck.fail("contact.ground.slope", f"{format_number(slope)} degrees: at most {MAX_SLOPE:g} "
                "in magnitude (steeper, the floor is a wall; use an obstacle)")
    return Ground(height=height, slope=slope)


def _obstacles(ck: Checker, raw) -> tuple[Obstacle, ...]:
    if raw is None:
        return ()
    items = ck.seq(raw, "contact.obstacles", what="list of obstacles")
    if len(items) > MAX_OBSTACLES:
        ck.fail("contact.obstacles", f"{len(items)} obstacles: at most {MAX_OBSTACLES}")
    out, seen = [], {}
    for i, item in enumerate(items):
        path = at_index("contact.obstacles", i)
        ck.mapping(item, path, _OBSTACLE_KEYS, required=("outline",))
        name = f"obstacle{i}" if item.get("name") is None else ck.name(item["name"], at_key(path, "name"))
        if name in ("ground", "self"):
            ck.fail(at_key(path, "name"), f"{shown(name)} is reserved (the result names the floor "
                    "'ground' and the body's own contacts 'self')")
        if name in seen:
            ck.fail(at_key(path, "name"), f"{shown(name)} is already the name of obstacle {seen[name]}")
        seen[name] = i
        where = at_key(path, "outline")
        outline = ck.points(item["outline"], where, min_len=3)
        if len(outline) > MAX_OBSTACLE_POINTS:
            ck.fail(where, f"{len(outline)} points: at most {MAX_OBSTACLE_POINTS}")
        check_ring(ck, outline, where)
        out.append(Obstacle(name=name, outline=np.ascontiguousarray(outline)))
    return tuple(out)
