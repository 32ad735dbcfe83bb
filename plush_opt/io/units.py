"""The units a problem file is written in: labels for every output, never conversions.

A problem file may say ``units: {length: m, force: N}`` (docs/problem-format.md,
reading 30); without it the units are mm and N. The numbers of the file are
used as written whatever the units say: the format's units are free but
consistent, so the solve is the same and only the words of the outputs
(summary lines, pictures, result files, warnings) follow the file.
:class:`Units` holds the two names the file chose and derives the rest
(stress = force / length^2, mass = force s^2 / length, density = mass /
length^3, with time in seconds).
"""

from __future__ import annotations

from dataclasses import dataclass

#: accepted length units and their size in metres
LENGTHS = {"um": 1e-6, "mm": 1e-3, "cm": 1e-2, "m": 1.0, "in": 0.0254}
#: accepted force units and their size in newtons
FORCES = {"uN": 1e-6, "mN": 1e-3, "N": 1.0, "kN": 1e3}
#: stresses with their own name: force N or kN over mm^2 or m^2 (engineering's pascals)
NAMED_STRESSES = {("N", "mm"): "MPa", ("N", "m"): "Pa", ("kN", "mm"): "GPa", ("kN", "m"): "kPa"}
#: masses with their own name (mass unit = force unit x s^2 / length unit, in kg)
NAMED_MASSES = {1e-3: "g", 1.0: "kg", 1e3: "t"}
#: relative tolerance when a derived mass unit is compared with a named one
_SAME = 1e-9


@dataclass(frozen=True)
class Units:
    """Names of the units of one scene: ``length`` (one of :data:`LENGTHS`)
    and ``force`` (one of :data:`FORCES`); ``stress``, ``mass``, ``density``
    and ``gravity`` follow from them with time in seconds."""

    length: str = "mm"
    force: str = "N"

    def __post_init__(self):
        for key, value, accepted in (("length", self.length, LENGTHS), ("force", self.force, FORCES)):
            if value not in accepted:
                raise ValueError(f"units.{key}: {value!r} is not one of {', '.join(accepted)}")

    @property
    def stress(self) -> str:
        """Stress (moduli): ``MPa`` for N and mm, ``Pa`` for N and m, else
        written out as ``force/length^2`` (``mN/mm^2``)."""
        return NAMED_STRESSES.get((self.force, self.length), f"{self.force}/{self.length}^2")

    @property
    def mass(self) -> str:
        """The mass unit the set implies (force x s^2 / length): ``t`` for
        N and mm, ``kg`` for N and m, else written out (``N s^2/cm``)."""
        kg = FORCES[self.force] / LENGTHS[self.length]
        for size, name in NAMED_MASSES.items():
            if abs(kg - size) <= _SAME * size:
                return name
        return f"{self.force} s^2/{self.length}"

    @property
    def density(self) -> str:
        """Density: mass / length^3 (``t/mm^3`` for N and mm, ``kg/m^3`` for N and m)."""
        mass = self.mass
        return f"{mass}/{self.length}^3" if " " not in mass else f"{self.force} s^2/{self.length}^4"

    @property
    def gravity(self) -> str:
        """Acceleration: length / s^2."""
        return f"{self.length}/s^2"

    def metres(self, value: float) -> float:
        """A length in this file's units, in metres."""
        return value * LENGTHS[self.length]

    def pascals(self, value: float) -> float:
        """A stress in this file's units, in pascals."""
        return value * FORCES[self.force] / LENGTHS[self.length] ** 2

    def as_dict(self) -> dict:
        """Every name, for result files: length, force, stress, mass, density, gravity, time."""
        return {"length": self.length, "force": self.force, "stress": self.stress, "mass": self.mass,
                "density": self.density, "gravity": self.gravity, "time": "s"}


DEFAULT_UNITS = Units()


def units_of(doc) -> Units:
    """The units of a result document (its ``units`` object; mm and N for a
    result written without one, or by another program). Names outside the
    accepted sets fall back to the defaults' words: a label, never a failure."""
    raw = doc.get("units") if isinstance(doc, dict) else None
    if not isinstance(raw, dict):
        return DEFAULT_UNITS
    length, force = raw.get("length"), raw.get("force")
    return Units(length=length if length in LENGTHS else DEFAULT_UNITS.length,
                 force=force if force in FORCES else DEFAULT_UNITS.force)
