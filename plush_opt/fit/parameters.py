"""The scene parameters a calibration can fit, and how each enters E.

Each parameter is fitted in an internal coordinate ``theta``: log for
positive ones (Young's modulus, tendon stiffness), a logit for Poisson's
ratio (0 < nu < 1/2), the value itself for lengths (offsets). For each,
:func:`mixed_columns` gives d2E/dx dtheta exactly from the model's
kernels (:meth:`~plush_opt.fem.model.Model.parameter_mixed`,
:meth:`~plush_opt.fem.model.Model.mixed`): no finite differences.

A winch's zero offset z shifts its contraction: the robot is at c + z
when it reports c. It is exactly a common shift of that winch's tendons'
assembly offsets (G = l - a - d + c + z), so the fitted problem file
carries it as d - z on each of those tendons.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ..base.errors import SceneError
from ..fem.model import Model
from ..io.scene import Material, Scene

KINDS = ("youngs_modulus", "poisson_ratio", "tendon_stiffness", "assembly_offset", "winch_offset")
DEFAULT_FIT = ("youngs_modulus", "assembly_offset")
#: Poisson's ratio is kept this far inside (0, 1/2) so its logit stays finite
NU_MARGIN = 1e-6


@dataclass(frozen=True)
class Parameter:
    """One fitted number: ``kind`` (one of KINDS), ``index`` (tendon or
    winch index for offsets, else None) and its display ``name``."""

    kind: str
    index: int | None
    name: str


@dataclass(frozen=True)
class Values:
    """Every fittable value of a scene (natural units)."""

    youngs_modulus: float
    poisson_ratio: float
    tendon_stiffness: float
    assembly_offset: np.ndarray        # (n_tendons,)
    winch_offset: np.ndarray           # (n_winches,)

    @classmethod
    def of_scene(cls, scene: Scene) -> "Values":
        mu, lam = scene.material.mu, scene.material.lam
        return cls(mu * (3 * lam + 2 * mu) / (lam + mu), lam / (2 * (lam + mu)),
                   scene.tendon_stiffness,
                   np.array([t.assembly_offset for t in scene.tendons], dtype=np.float64),
                   np.zeros(len(scene.winches)))

    def get(self, p: Parameter) -> float:
        v = getattr(self, p.kind)
        return float(v if p.index is None else v[p.index])

    def with_value(self, p: Parameter, value: float) -> "Values":
        if p.index is None:
            return replace(self, **{p.kind: float(value)})
        arr = getattr(self, p.kind).copy()
        arr[p.index] = value
        return replace(self, **{p.kind: arr})

    @property
    def mu(self) -> float:
        return self.youngs_modulus / (2 * (1 + self.poisson_ratio))

    @property
    def lam(self) -> float:
        nu = self.poisson_ratio
        return self.youngs_modulus * nu / ((1 + nu) * (1 - 2 * nu))


def parse_fit(scene: Scene, spec: str | list[str] | None) -> tuple[Parameter, ...]:
    """The parameters named by ``--fit``: kinds (every tendon's or winch's
    offset for ``assembly_offset`` and ``winch_offset``) or ``KIND:NAME``
    for one tendon's or winch's. Order: as given, duplicates dropped."""
    items = list(DEFAULT_FIT) if spec is None else (
        [s.strip() for s in spec.split(",")] if isinstance(spec, str) else list(spec))
    tendons = [t.name for t in scene.tendons]
    winches = list(scene.winch_names)
    out: list[Parameter] = []
    for item in items:
        kind, _, which = item.partition(":")
        if kind not in KINDS:
            raise SceneError(f"--fit: unknown parameter {item!r} (choose from {', '.join(KINDS)}; "
                             "offsets also as assembly_offset:TENDON or winch_offset:WINCH)")
        names = tendons if kind == "assembly_offset" else winches if kind == "winch_offset" else None
        if names is None:
            if which:
                raise SceneError(f"--fit: {kind} is one number for the scene; {item!r} names one")
            out.append(Parameter(kind, None, kind))
            continue
        if which and which not in names:
            what = "tendon" if kind == "assembly_offset" else "winch"
            raise SceneError(f"--fit: {item!r}: no {what} named {which!r} ({', '.join(names)})")
        for i, n in enumerate(names):
            if not which or n == which:
                out.append(Parameter(kind, i, f"{kind}:{n}"))
    unique = tuple(dict.fromkeys(out))
    if not unique:
        raise SceneError("--fit: no parameters to fit")
    return unique


# -- internal coordinates ----------------------------------------------------

def to_theta(p: Parameter, value: float) -> float:
    if p.kind in ("youngs_modulus", "tendon_stiffness"):
        return math.log(value)
    if p.kind == "poisson_ratio":
        s = min(max(2 * value, NU_MARGIN), 1 - NU_MARGIN)
        return math.log(s / (1 - s))
    return float(value)


def from_theta(p: Parameter, theta: float) -> float:
    if p.kind in ("youngs_modulus", "tendon_stiffness"):
        return math.exp(theta)
    if p.kind == "poisson_ratio":
        return 0.5 / (1 + math.exp(-theta))
    return float(theta)


def dvalue_dtheta(p: Parameter, value: float) -> float:
    """d value / d theta at ``value`` (the delta method's factor)."""
    if p.kind in ("youngs_modulus", "tendon_stiffness"):
        return value
    if p.kind == "poisson_ratio":
        return value * (1 - 2 * value)
    return 1.0


def values_from_theta(base: Values, params, theta) -> Values:
    v = base
    for p, t in zip(params, theta):
        v = v.with_value(p, from_theta(p, t))
    return v


def scene_with(scene: Scene, values: Values) -> Scene:
    """The scene with these material, tendon stiffness and assembly offsets
    (winch offsets act on the contractions, not the scene)."""
    mat = scene.material
    tendons = tuple(replace(t, assembly_offset=float(d))
                    for t, d in zip(scene.tendons, values.assembly_offset))
    return scene.replace(material=Material(values.mu, values.lam, mat.thickness, mat.density),
                         tendon_stiffness=values.tendon_stiffness, tendons=tendons)


def mixed_columns(model: Model, values: Values, params, x, c) -> np.ndarray:
    """d2E/dx dtheta at (x, c), dense (n_dofs, n_params)."""
    pm = model.parameter_mixed(x, c)
    E, nu = values.youngs_modulus, values.poisson_ratio
    cols = []
    for p in params:
        if p.kind == "youngs_modulus":        # mu, lambda proportional to E
            col = (values.mu * pm["mu"] + values.lam * pm["lambda"]) / E
        elif p.kind == "poisson_ratio":
            dmu = -E / (2 * (1 + nu) ** 2)
            dlam = E * (1 + 2 * nu**2) / ((1 + nu) * (1 - 2 * nu)) ** 2
            col = dmu * pm["mu"] + dlam * pm["lambda"]
        elif p.kind == "tendon_stiffness":
            col = pm["tendon_stiffness"]
        elif p.kind == "assembly_offset":
            col = pm["assembly_offset"][:, p.index]
        else:                                 # winch offset: d/dz = d/dc
            col = model.mixed(x, c)[:, p.index]
        cols.append(col * dvalue_dtheta(p, values.get(p)))
    return np.stack(cols, axis=1)


def effective_offsets(values: Values, model: Model) -> np.ndarray:
    """Each tendon's assembly offset with its winch's zero offset folded in
    (d - z_w): what the fitted problem file records."""
    return values.assembly_offset - values.winch_offset[model.tendon_winch]
