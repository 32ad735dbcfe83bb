"""Where each term of the Hessian lands: the CSC pattern of one model and,
for each contribution, its slot in the data array (computed once per mesh;
each evaluation is a few bincounts).

Element and pin terms sit on node dofs. Tendon terms are z-space entries
(z = [x; attachment points], plush_opt/fem/attachments.py): those between node
dofs go to their slot directly; those touching an attachment point spread
over its nodes (W^T H_z W) through one sparse matrix. The segments of
via-point friction (:class:`ViaSegments`) sit on via points P = W x and
land as W^T H_P W, after everything else.

Three forms (Model's ``hessian`` argument):

- ``assembled``: everything in one sparse matrix;
- ``rank_one``: each tendon's U'' l' l'^T kept apart as a low-rank term
  (:class:`~plush_opt.base.low_rank.LowRankHessian`): with attachment discs it
  couples every disc of the tendon with every other, densely;
- ``split``: also each segment's coupling of its two ends. A segment's
  U' l'' is [[K, -K], [-K, K]] on its two ends (K 2 x 2, positive
  semi-definite); it is written as 2 diag(K, K), which stays in the sparse
  part (one disc at a time), minus [I; I] K [I, I], which joins the low-rank
  term. The sparse part then holds no block coupling two discs, and is at
  least as positive definite as with the whole segment term in it.
  A disc with more than :data:`STANDIN_MIN_DISC_NODES` nodes (a graded
  mesh fills one beside a pinned end with hundreds) would put the square
  of its node count into the factor: its 2 diag(K) sits in the sparse part
  on the disc's heaviest node alone (a stand-in, as positive definite as a
  point load's), and the difference, W^T 2K W - e^T 2K e (rank 4: the
  disc's rows W and the node's rows e), joins the low-rank term.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp

from ..base.low_rank import LowRankHessian

#: the forms (Model's ``hessian`` argument; "auto" is decided by the model)
FORMS = ("assembled", "rank_one", "split")
# In the split form a disc with more nodes than this has a stand-in in the
# sparse part (above): its dense block would cost (2 n)^2 entries there and
# more in the factor, the stand-in 4 solves per factorisation.
STANDIN_MIN_DISC_NODES = 200


def segment_pairs(seg_dofs: np.ndarray, A: sp.csr_matrix) -> sp.csr_matrix:
    """Q's rows of split segments: per segment (ends' coordinates ``seg_dofs``
    (m, 4) in the space A maps from node dofs) the two rows a_d + b_d."""
    m = len(seg_dofs)
    pair = sp.csr_matrix((np.ones(4 * m), (np.tile(np.arange(2 * m), 2),
                                           np.r_[seg_dofs[:, :2].ravel(), seg_dofs[:, 2:].ravel()])),
                         shape=(2 * m, A.shape[0]))
    return (pair @ A).tocsr()


class _Scatter:
    """Adds values into a few slots of a long data array: ``add(data, w)``
    is ``data += np.bincount(slots, w, minlength=len(data))`` bit for bit
    (each slot's values summed in the same order, from zero), without
    allocating and adding a whole array for a handful of slots."""

    def __init__(self, slots: np.ndarray):
        self._where, self._inverse = np.unique(slots, return_inverse=True)
        self.size = len(slots)

    def add(self, data: np.ndarray, weights: np.ndarray) -> None:
        data[self._where] += np.bincount(self._inverse, weights=weights, minlength=len(self._where))


class _RowScatter:
    """``data += S @ v`` bit for bit for a sparse S (nnz, m) with few nonzero
    rows: only those rows are multiplied and added."""

    def __init__(self, S: sp.csr_matrix):
        self._rows = np.flatnonzero(np.diff(S.indptr))
        self._S = S[self._rows]

    def add(self, data: np.ndarray, v: np.ndarray) -> None:
        data[self._rows] += self._S @ v


def pair_blocks(K: np.ndarray) -> np.ndarray:
    """M's block of split segments: minus each segment's K (m, 2, 2) on the
    diagonal, (2m, 2m) (and of stand-ins, with either sign)."""
    m = len(K)
    M = np.zeros((m, 2, m, 2))
    M[np.arange(m), :, np.arange(m), :] = -K
    return M.reshape(2 * m, 2 * m)


@dataclass(frozen=True)
class ViaSegments:
    """Segments whose ends are via points P = W x (the segmented tendons of
    via-point friction, plush_opt/fem/segments.py): each one's Hessian
    (4 x 4 in its ends' coordinates ``seg_p`` (count, 4) of P) lands as
    W^T H W. ``split``: as the tendons' segments in the split form, its
    coupling of its two ends joins the low-rank term (2 diag(K, K) stays)."""

    W: sp.csr_matrix
    seg_p: np.ndarray
    split: bool

    @property
    def count(self) -> int:
        return len(self.seg_p)

    def entries(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(rows, cols, weight, entry) in node dofs: entry 16 s + 4 a + b of
        the segments' flat Hessians lands at (rows, cols) times weight."""
        W, rows, cols, entry, weight = self.W, [], [], [], []
        blocks = ([(a, b) for a in (0, 1) for b in (0, 1)] + [(a, b) for a in (2, 3) for b in (2, 3)]
                  if self.split else [(a, b) for a in range(4) for b in range(4)])
        for s in range(self.count):
            for a, b in blocks:
                ra, rb = W.getrow(self.seg_p[s, a]), W.getrow(self.seg_p[s, b])
                rows.append(np.repeat(ra.indices, len(rb.indices)))
                cols.append(np.tile(rb.indices, len(ra.indices)))
                weight.append(np.outer(ra.data, rb.data).ravel())
                entry.append(np.full(len(ra.indices) * len(rb.indices), 16 * s + 4 * a + b))
        cat = lambda a, dtype: np.concatenate(a) if a else np.zeros(0, dtype)  # noqa: E731
        return cat(rows, np.int64), cat(cols, np.int64), cat(weight, np.float64), cat(entry, np.int64)


class HessianLayout:
    """The Hessian's pattern and scatter slots for one model.

    ``elem_dofs`` (n_elems, k) and ``pin_dofs`` in node dofs; ``points``
    the model's TendonPoints; ``seg_dofs`` (n_segments, 4) and
    ``tendon_dofs`` (n_tendons, local, padded with -1) in z-space dofs;
    ``via`` the segmented tendons' via segments (:class:`ViaSegments`), or
    None. ``low_rank`` and ``split`` describe the tendons' part; via
    segments in their split form add to the low-rank term too.
    """

    def __init__(self, n_dofs: int, elem_dofs, pin_dofs, points, seg_dofs, tendon_dofs, form: str,
                 via: ViaSegments | None = None):
        if form not in FORMS:
            raise ValueError(f"Hessian form {form!r}: expected one of {', '.join(FORMS)}")
        self._args = (n_dofs, elem_dofs, pin_dofs, points, seg_dofs, tendon_dofs, form)
        self.via = via
        self.n = n = n_dofs
        self.form = form
        self.low_rank = form != "assembled" and len(seg_dofs) > 0
        self.split = self.low_rank and form == "split"
        self._points, self._seg_dofs, self._tendon_dofs = points, seg_dofs, tendon_dofs
        self._A_sparse, self._standin_dofs = self._standin()
        k = elem_dofs.shape[1]
        rows = [np.repeat(elem_dofs, k, axis=1).ravel(), pin_dofs]
        cols = [np.tile(elem_dofs, (1, k)).ravel(), pin_dofs]
        self._direct, spread = {}, []
        kinds = self._tendon_kinds() if len(seg_dofs) else []
        for name, zr, zc in kinds:
            direct = (zr < n) & (zc < n)
            self._direct[name] = None if direct.all() else direct
            rows.append(zr[direct])
            cols.append(zc[direct])
            spread.append((len(zr) - int(direct.sum()),)
                          + points.expand(zr[~direct], zc[~direct], self._A_sparse))
        rows += [x[2] for x in spread]
        cols += [x[3] for x in spread]
        if via is not None:
            via_rows, via_cols, via_weight, via_entry = via.entries()
            rows.append(via_rows)
            cols.append(via_cols)
        sizes = [len(x) for x in rows]
        keys = np.concatenate(cols) * n + np.concatenate(rows)
        unique_keys, slot = np.unique(keys, return_inverse=True)
        ucols, urows = np.divmod(unique_keys, n)
        self.indptr = np.concatenate([[0], np.cumsum(np.bincount(ucols, minlength=n))]).astype(np.int32)
        self.indices = urows.astype(np.int32)
        self.nnz = len(unique_keys)
        self._keys = unique_keys               # col * n + row of each slot, ascending
        parts = np.split(slot, np.cumsum(sizes)[:-1])
        self._slot_elem, self._pins = parts[0], _Scatter(parts[1])
        self._slot = {name: _Scatter(parts[2 + i]) for i, (name, _, _) in enumerate(kinds)}
        self._spread = None
        if spread:
            # the spread entries index the concatenation, kind by kind, of
            # the entries that are not direct
            offsets = np.cumsum([0] + [x[0] for x in spread])
            self._spread = _RowScatter(sp.csr_matrix(
                (np.concatenate([x[4] for x in spread]),
                 (np.concatenate(parts[2 + len(kinds):2 + len(kinds) + len(spread)]),
                  np.concatenate([x[1] + o for x, o in zip(spread, offsets)]))),
                shape=(self.nnz, offsets[-1])))
        if self.low_rank:
            self._build_low_rank()
        if via is not None:
            self._via_expand = _RowScatter(sp.csr_matrix((via_weight, (parts[-1], via_entry)),
                                                         shape=(self.nnz, 16 * via.count)))
            self._via_pairs = segment_pairs(via.seg_p, via.W) if via.split else None

    def with_via(self, via: ViaSegments) -> "HessianLayout":
        """This layout (same terms, same form) with the via segments ``via``
        too: the pattern is the union, each contribution lands where it
        did plus the segments' blocks."""
        return HessianLayout(*self._args, via=via)

    def _standin(self) -> tuple[sp.csr_matrix, np.ndarray]:
        """A with the rows of each large disc's point moved to its heaviest
        node (the sparse part's map), and the z-dofs of those points (none
        outside the split form)."""
        pts, n = self._points, self.n
        W = pts.extra_dofs                        # row 2k + d: point k, coordinate d
        counts = np.diff(W.indptr)[::2]
        large = np.flatnonzero(counts > STANDIN_MIN_DISC_NODES)
        if not self.split or not len(large):
            return pts.A, np.zeros(0, np.int64)
        heaviest = np.array([W.indices[a + np.argmax(W.data[a:W.indptr[2 * k + 1]])]
                             for k, a in zip(large, W.indptr[2 * large])])     # dof 2i of node i
        zdofs = (n + 2 * large[:, None] + np.arange(2)).ravel()
        keep = np.ones(pts.A.shape[0])
        keep[zdofs] = 0.0
        moved = sp.csr_matrix((np.ones(len(zdofs)), (zdofs, (heaviest[:, None] + np.arange(2)).ravel())),
                              shape=pts.A.shape)
        A = (sp.diags(keep) @ pts.A + moved).tocsr()
        A.eliminate_zeros()
        return A, zdofs

    def _tendon_kinds(self) -> list[tuple[str, np.ndarray, np.ndarray]]:
        """The z-space (row, col) entries of each kind of tendon term."""
        s, L = self._seg_dofs, self._tendon_dofs
        if self.split:
            ends = np.concatenate([s[:, :2], s[:, 2:]], axis=0)
            kinds = [("ends", np.repeat(ends, 2, axis=1).ravel(), np.tile(ends, (1, 2)).ravel())]
        else:
            kinds = [("seg", np.repeat(s, 4, axis=1).ravel(), np.tile(s, (1, 4)).ravel())]
        if not self.low_rank:
            # each tendon's dense l' l'^T block (the low-rank forms keep it
            # apart: their memory stays linear in the via points)
            r = np.repeat(L, L.shape[1], axis=1).ravel()
            c = np.tile(L, (1, L.shape[1])).ravel()
            self._outer_valid = (r >= 0) & (c >= 0)
            kinds.append(("outer", r[self._outer_valid], c[self._outer_valid]))
        return kinds

    def _build_low_rank(self):
        """The low-rank term's constant parts: per segment (when split) the
        two rows (a_d + b_d) of its ends' coordinates as node coordinates,
        and where tendon t's length gradient l' sits (one row each)."""
        n_tendons = self._tendon_dofs.shape[0]
        m = len(self._seg_dofs) if self.split else 0
        self._pairs = segment_pairs(self._seg_dofs[:m], self._points.A)
        self._valid = self._tendon_dofs.ravel() >= 0
        self._l_rows = np.repeat(np.arange(n_tendons), self._tendon_dofs.shape[1])[self._valid]
        self._l_cols = self._tendon_dofs.ravel()[self._valid]
        # large discs: their rows of A and of the stand-in, and which
        # segment ends (seg_dofs' first half, then its second) sit on each
        large = self._standin_dofs
        self._standin_rows = sp.vstack([self._points.A[large], self._A_sparse[large]], format="csr")
        ends = np.r_[self._seg_dofs[:m, 0], self._seg_dofs[:m, 2]]
        pos = np.searchsorted(large, ends)
        hit = pos < len(large)
        hit[hit] = large[pos[hit]] == ends[hit]
        self._end_on = np.where(hit, pos, -1)

    def assemble(self, elem_hess: np.ndarray, pin_stiffness: float, seg_hess=None, length_grad=None,
                 dtension=None, via_hess=None, contact_hess=None, friction_hess=None):
        """The Hessian from its terms: element Hessians (flat), the pin
        stiffness, and with tendons each segment's U' l'' (n_segments, 16),
        each tendon's l' on its local dofs (n_tendons, local) and U''; with
        via segments (:class:`ViaSegments`) each one's Hessian in its ends'
        via point coordinates (count, 4, 4); with contact, its pairs'
        Hessian and with contact friction its (COO entries on node dofs,
        ``row``, ``col``, ``data``, whose pattern follows the pairs in
        contact), added last.
        A CSC matrix, or a LowRankHessian."""
        data = np.bincount(self._slot_elem, weights=elem_hess, minlength=self.nnz)
        self._pins.add(data, np.full(self._pins.size, pin_stiffness))
        if seg_hess is not None:
            K = seg_hess.reshape(-1, 4, 4)[:, :2, :2]
            terms = {"ends": np.concatenate([2 * K, 2 * K]).ravel()} if self.split else {"seg": seg_hess.ravel()}
            if not self.low_rank:
                outer = dtension[:, None, None] * length_grad[:, :, None] * length_grad[:, None, :]
                terms["outer"] = outer.ravel()[self._outer_valid]
            rest = []
            for name, values in terms.items():
                d = self._direct[name]
                self._slot[name].add(data, values if d is None else values[d])
                if d is not None:
                    rest.append(values[~d])
            if rest:
                self._spread.add(data, np.concatenate(rest))
        if via_hess is not None:
            self._via_expand.add(data, (2 * via_hess if self.via.split else via_hess).ravel())
        outside = []
        for extra in (contact_hess, friction_hess):
            if extra is not None and extra.nnz:
                # into the pattern's slots where it has them (a floor's node
                # blocks, pairs of mesh neighbours): the pattern stays fixed
                extra = extra if hasattr(extra, "row") else extra.tocoo()
                slot = self.slots(extra.row, extra.col)
                if np.all(slot >= 0):
                    np.add.at(data, slot, extra.data)
                else:
                    outside.append(extra)
        H = sp.csc_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))
        for extra in outside:
            H = (H + sp.csc_matrix((extra.data, (extra.row, extra.col)), shape=H.shape)).tocsc()
            H.sort_indices()
        Q, M = self._low_rank_term(K, length_grad, dtension) if self.low_rank else (None, None)
        # the tendons' own rows (after the segments' pairs): what moves fastest
        fast = (self._pairs.shape[0], self._pairs.shape[0] + len(dtension)) if self.low_rank else None
        if via_hess is not None and self.via.split:
            Qv, Mv = self._via_pairs, pair_blocks(via_hess[:, :2, :2])
            Q, M = (Qv, Mv) if Q is None else (sp.vstack([Q, Qv], format="csr"), sla.block_diag(M, Mv))
        return H if Q is None else LowRankHessian(H, Q, M, fast)

    @functools.cached_property
    def diagonal_slots(self) -> np.ndarray:
        """(n,) where each diagonal entry (i, i) sits in the pattern's data,
        -1 where the pattern has none (a gauge reads the diagonal there)."""
        return self.slots(np.arange(self.n), np.arange(self.n))

    def slots(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Where the entries (rows, cols) sit in the pattern's data, -1
        where the pattern has none."""
        key = np.asarray(cols, dtype=np.int64) * self.n + np.asarray(rows, dtype=np.int64)
        pos = np.minimum(np.searchsorted(self._keys, key), self.nnz - 1)
        return np.where(self._keys[pos] == key, pos, -1)

    def _low_rank_term(self, K, length_grad, dtension) -> tuple[sp.csr_matrix, np.ndarray]:
        """Q and M of the terms kept apart: minus each segment's
        [I; I] K [I, I] (when split), plus each tendon's U'' l' l'^T."""
        A, m2 = self._points.A, self._pairs.shape[0]
        lz = sp.csr_matrix((length_grad.ravel()[self._valid], (self._l_rows, self._l_cols)),
                           shape=(len(dtension), A.shape[0]))
        Q = sp.vstack([self._pairs, lz @ A, self._standin_rows], format="csr")
        n_s = len(self._standin_dofs)
        M = np.diag(np.r_[np.zeros(m2), dtension, np.zeros(2 * n_s)])
        if self.split:
            M[:m2, :m2] = pair_blocks(K)
        if n_s:
            # each large disc's 2K (summed over the segment ends on it):
            # + on the disc's rows, - on its stand-in's
            S = np.zeros((n_s // 2, 2, 2))
            on = self._end_on >= 0
            np.add.at(S, self._end_on[on] // 2, 2 * np.concatenate([K, K])[on])
            j = m2 + len(dtension)
            M[j:j + n_s, j:j + n_s] = -pair_blocks(S)
            M[j + n_s:, j + n_s:] = pair_blocks(S)
        return Q, M
