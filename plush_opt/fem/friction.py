"""Friction at via points: the scene's energy with its friction tendons
split into segments (docs/model.md, "Friction at via points").

A :class:`FrictionModel` is the terms of a model of the scene without its
friction tendons (exactly the ordinary :class:`~plush_opt.fem.model.Model`'s
terms) plus one :class:`~plush_opt.fem.segments.SegmentTerm` for their
segments, whose history is the segments' rest lengths r; every evaluation
sums them with :func:`~plush_opt.fem.model.sum_terms` into one Hessian
layout (the base model's plus the segments' blocks). With the rest lengths
held (:meth:`FrictionModel.fixed`) it is what the equilibrium Newton
minimises; which rest lengths hold is decided by the path-following solver
(plush_opt/solve/friction_path.py).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from ..base.linalg import Factorizer
from .hessian_layout import ViaSegments
from .free_motion import GaugedFactorizer
from .model import Evaluation, HeldTerms, Model, sum_terms
from .segments import KERNELS, SegmentTerm, via_weights

__all__ = ["KERNELS", "FixedRest", "FrictionModel", "SegmentTerm", "friction_tendons", "via_weights"]

def friction_tendons(scene, include_frictionless: bool = False) -> tuple[int, ...]:
    """Indices of the tendons the friction model splits into segments: friction
    > 0 (or any, with ``include_frictionless``) and an interior via point."""
    return tuple(i for i, t in enumerate(scene.tendons)
                 if len(t.path) >= 3 and (t.friction > 0 or include_frictionless))


#: what a FrictionModel reads of its segment term, under the same names
SEGMENT_DATA = ("n_segments", "W", "seg_p", "seg_tendon", "seg_winch", "seg_first", "seg_last",
                "assembly_length", "n_interior", "lo", "hi", "mu", "via_index", "wrap_p", "D")


class FrictionModel:
    """The scene's energy with its friction tendons split into segments.

    Attributes
    ----------
    model : the full :class:`Model` (every tendon one spring).
    base : the model of the scene without the friction tendons.
    segment_term : the :class:`~plush_opt.fem.segments.SegmentTerm` of the
        friction tendons (its held rest lengths are the start state's; an
        evaluation at rest lengths r uses a copy held at r).
    terms : the base model's terms, then the segment term.
    hessian_layout : the base model's layout plus the segments' blocks.
    tendons : scene indices of the friction tendons.
    n_segments, W, seg_p, seg_tendon, seg_winch, seg_first, seg_last,
    assembly_length, n_interior, lo, hi, mu, via_index, wrap_p, D : the
        segment term's (see :class:`~plush_opt.fem.segments.SegmentTerm`).
    factorizer : the :class:`~plush_opt.base.linalg.Factorizer` of its Hessians.
    """

    def __init__(self, model: Model, include_frictionless: bool = False):
        self.model = model
        scene, mesh = model.scene, model.mesh
        self.tendons = friction_tendons(scene, include_frictionless)
        keep = [i for i in range(model.n_tendons) if i not in self.tendons]
        self.base = Model(replace(scene, tendons=tuple(scene.tendons[i] for i in keep)),
                          replace(mesh, tendon_nodes=tuple(mesh.tendon_nodes[i] for i in keep)))
        self.n_dofs, self.n_winches, self.X = model.n_dofs, model.n_winches, model.X
        self.K, self.eps = model.tendon_stiffness, model.tendon_smoothing
        self.segment_term = term = SegmentTerm(model, self.tendons)
        self.terms = self.base.terms + (term,)
        for name in SEGMENT_DATA:
            setattr(self, name, getattr(term, name))
        # the Hessian's form follows the full model's: with large
        # attachment discs each segment's coupling of its two discs is kept
        # out as low rank (a segment here has no rank-one tendon term)
        self.split = model.split_segments
        self.hessian_layout = self.base.hessian_layout.with_via(ViaSegments(term.W, term.seg_p, self.split))
        self.unpinned = self.base.unpinned
        self.factorizer = GaugedFactorizer() if self.unpinned else Factorizer()

    # the attributes the equilibrium Newton reads
    energy_roundoff_scale = property(lambda self: self.base.energy_roundoff_scale)
    has_gravity = property(lambda self: self.base.has_gravity)
    f_gravity = property(lambda self: self.base.f_gravity)
    rest_area = property(lambda self: self.base.rest_area)

    # -- the segment term's geometry, by the names the path solver reads ---

    def rest_total(self, c) -> np.ndarray:
        """(n_segments,) a_t - c_w of each segment's tendon."""
        return self.segment_term.rest_total(c)

    def segment_lengths(self, x) -> np.ndarray:
        """(n_segments,) |P_{j+1} - P_j| at flat pose x."""
        return self.segment_term.segment_lengths(x)

    def start_rest_lengths(self) -> np.ndarray:
        """Rest lengths of the start state (all tensions equal)."""
        return self.segment_term.start_rest_lengths()

    def segments(self, x, r, c) -> dict[str, np.ndarray]:
        """Per segment data at (x, r, c): :meth:`SegmentTerm.segments`."""
        return self.segment_term.segments(x, r, c)

    def wraps(self, x) -> tuple[np.ndarray, np.ndarray]:
        """Wrap angles and their gradients: :meth:`SegmentTerm.wraps`."""
        return self.segment_term.wraps(x)

    def to_x(self, values: np.ndarray, pdofs: np.ndarray) -> np.ndarray:
        """Via point coordinates to pose coordinates: :meth:`SegmentTerm.to_x`."""
        return self.segment_term.to_x(values, pdofs)

    # -- evaluation ---------------------------------------------------------

    def evaluate(self, x, c, r, order: int = 2, seg: dict | None = None) -> Evaluation:
        """E(x; c, r) (order 0), grad_x (1), and the Hessian (2): the base
        terms and the segment term held at r, summed; ``seg``:
        :meth:`segments` at the same point, if the caller has it."""
        return self.evaluate_held(self.segment_term.held(r, seg), x, c, order)

    def evaluate_held(self, held: SegmentTerm, x, c, order: int = 2) -> Evaluation:
        """:meth:`evaluate` with the segment term ``held`` (a held copy of
        :attr:`segment_term`)."""
        c = np.asarray(c, dtype=np.float64).reshape(-1)
        if c.shape != (self.n_winches,):
            raise ValueError(f"contraction has {c.size} entries, the scene has {self.n_winches} winches")
        return sum_terms(self.terms[:-1] + (held,), self.hessian_layout,
                         np.asarray(x, dtype=np.float64).reshape(-1), c, order, gauge=self.unpinned)

    def mixed(self, x, c, r) -> np.ndarray:
        """d2E/dx dc with the rest lengths held at r, dense (n_dofs, n_winches)."""
        return self.base.mixed(x, c) + self.segment_term.held(r).mixed(np.asarray(x, dtype=np.float64), c)

    def mixed_r(self, x, r, c, seg: dict | None = None) -> np.ndarray:
        """d2E/dx dr, dense (n_dofs, n_segments)."""
        return self.segment_term.mixed_r(x, r, c, seg)

    def fixed(self, r) -> "FixedRest":
        """This model with the rest lengths held at r: what the equilibrium
        Newton minimises."""
        return FixedRest(self, self.segment_term.held(np.asarray(r, dtype=np.float64).copy()))


class FixedRest(HeldTerms):
    """A :class:`FrictionModel` with its segment term held at fixed rest
    lengths: the interface :func:`~plush_opt.solve.equilibrium.solve_equilibrium`
    expects of a model. ``r``: the held rest lengths (n_segments,)."""

    def __init__(self, fm: FrictionModel, held: SegmentTerm):
        super().__init__(fm, fm.terms[:-1] + (held,), fm.hessian_layout, fm.factorizer)
        self.fm, self.held, self.r = fm, held, held.rest

    def evaluate(self, x, c, order: int = 2) -> Evaluation:
        return self.fm.evaluate_held(self.held, x, c, order)      # (checks c's size)
