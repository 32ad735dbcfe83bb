"""What the comparison runs: methods, tolerance presets, mesh factors, and
the record of one run."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

METHODS = ("reparam", "clip", "bilevel")
ELEMENTS = ("P1", "P2")
TOLERANCES = ("loose", "default", "tight")
# A problem whose finest factor already gives this fraction of large_nodes
# gets no extra level (it is "about" that size).
LARGE_SHORTFALL = 0.8

#: Tolerance presets per method family (options fields).
GRADIENT_TOL = {"loose": {"ftol": 1e-3, "gtol": 1e-3}, "default": {},
                "tight": {"ftol": 1e-12, "gtol": 1e-10}}
# The reduced-space bilevel method stops by IPOPT's tol (its scaled KKT
# error) or by the loop's projected-gradient test gtol, whichever is met
# first: the presets move both with the loop's gtol.
BILEVEL_TOL = {"loose": {"tol": 1e-4, "acceptable_tol": 1e-3, "gtol": 1e-3},
               "default": {}, "tight": {"tol": 1e-10, "gtol": 1e-10}}


@dataclass(frozen=True)
class CompareSettings:
    """What :func:`run_compare` runs.

    Attributes
    ----------
    mesh_factors : max_area multipliers of the problem's own mesh, coarse to
        fine; must contain ``main_factor``.
    main_factor : the mesh of the main table and the tolerance sweep.
    tolerances : tolerance presets swept on the main mesh (names of
        GRADIENT_TOL / BILEVEL_TOL).
    max_time : seconds per run at most (None: no limit).
    resolve_bilevel_iterates : after the main bilevel run, solve the
        equilibrium at each IPOPT iterate's contractions (not timed) to show
        what sending IPOPT's iterates to the robot would do.
    repeat : run each case this many times and keep the run of median
        time (wall times of runs this short are noisy on a shared machine;
        the report says how many samples each time is); setup is taken
        from the first run, which pays it.
    large_nodes : also run the mesh sweep at about this many nodes (a
        finer max_area chosen per problem) when the finest factor stays
        below LARGE_SHORTFALL of it; None: no such level.
    elements : element types of the mesh sweep (every factor with each);
        the main runs use the problem file's element.
    reference_factor : max_area of the P2 reference, as a multiple of the
        file's (away from the corners and attachment discs its mesh is
        graded towards: a graded P2 level at 1/4 of the file's max_area is
        nearer the limit than a uniform one at 1/16, docs/accuracy.md):
        every run's error is measured against the reference's pose at the
        run's contractions.
    check_factor : a coarser graded P2 level (multiple of the file's
        max_area) whose distance from the reference is reported as the
        check of the reference's own convergence (it must be far below the
        errors measured).
    """

    mesh_factors: tuple = (4.0, 1.0, 0.25)
    main_factor: float = 1.0
    tolerances: tuple = TOLERANCES
    max_time: float | None = 120.0
    resolve_bilevel_iterates: bool = True
    repeat: int = 3
    large_nodes: int | None = 3000
    elements: tuple = ELEMENTS
    reference_factor: float = 1 / 4
    check_factor: float = 1.0

    def __post_init__(self):
        if not (isinstance(self.repeat, int) and self.repeat >= 1):
            raise ValueError(f"repeat: expected an integer >= 1, got {self.repeat!r}")
        f = tuple(float(v) for v in self.mesh_factors)
        if not f or any(b >= a for a, b in zip(f, f[1:])) or any(v <= 0 for v in f):
            raise ValueError(f"mesh_factors: expected decreasing numbers > 0, got {self.mesh_factors!r}")
        if float(self.main_factor) not in f:
            raise ValueError(f"main_factor: {self.main_factor!r} is not one of mesh_factors {f}")
        bad = [t for t in self.tolerances if t not in TOLERANCES]
        if bad or "default" not in self.tolerances:
            raise ValueError(f"tolerances: expected a subset of {TOLERANCES} with 'default', "
                             f"got {self.tolerances!r}")
        if not self.elements or any(e not in ELEMENTS for e in self.elements):
            raise ValueError(f"elements: expected a subset of {ELEMENTS}, got {self.elements!r}")
        if not (0 < self.reference_factor < self.check_factor):
            raise ValueError(f"reference_factor, check_factor: expected 0 < reference_factor < "
                             f"check_factor, got {self.reference_factor!r}, {self.check_factor!r}")
        object.__setattr__(self, "mesh_factors", f)

    @classmethod
    def full(cls) -> "CompareSettings":
        return cls()

    @classmethod
    def coarse(cls) -> "CompareSettings":
        """A quick smoke run: coarser meshes, two tolerance presets, a coarse
        graded reference (graded P2 at twice the file's max_area is still
        finer than the P1 sweep it checks)."""
        return cls(mesh_factors=(8.0, 4.0, 2.0), main_factor=4.0, tolerances=("loose", "default"),
                   max_time=30.0, resolve_bilevel_iterates=False, repeat=1, large_nodes=None,
                   elements=("P1",), reference_factor=2.0, check_factor=4.0)


@dataclass
class Run:
    """One method on one problem, mesh and tolerance."""

    problem: str
    method: str
    sweep: str                 # 'main', 'tolerance' or 'mesh'
    tolerance: str
    element: str
    mesh_factor: float
    max_area: float | None
    n_nodes: int
    n_elems: int
    converged: bool = False
    reason: str = ""
    status: str = ""
    objective: float = math.nan
    rms_target_error: float = math.nan
    contraction: np.ndarray | None = None
    t_solve: float = math.nan
    t_setup: float = 0.0
    iterations: int = 0
    equilibrium_solves: int = 0
    bound_violation: float = math.nan
    stable: bool = False
    saddle_flagged: bool = False
    model_error: float = math.nan
    fine_target_error: float = math.nan
    reference_difference: float = math.nan           # RMS, reference against its check level
    reference_crease: str = ""                      # where the reference (or its check) creases: no errors
    pareto: bool = False
    curve: list = field(default_factory=list)      # (t, O, dispatchable)
    resolved: list = field(default_factory=list)   # bilevel iterates re-solved: (t, O)
    ipopt_history: tuple | None = None              # (t_start, IPOPT iterations)
    x: np.ndarray | None = None
    mesh: object = None
