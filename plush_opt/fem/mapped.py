"""A small CasADi kernel evaluated over many columns (elements, segments,
tendons) into numpy arrays, through the buffer interface (no DM
conversion per call).

Below :data:`COMPILE_MAPPED_MIN` columns the kernel (already compiled on
its own, plush_opt/base/kernels.py) is mapped and called once per column.
From there on a compiled loop over a chunk of columns does the work: one C
call per chunk instead of one per column, several times faster for the
elastic kernels (docs/benchmarks.md), with the same arithmetic per
column. The chunk is one of :data:`COMPILED_CHUNKS`, so that a few
libraries per kernel serve every mesh size; the last chunk is padded with
copies of the last column and its results dropped.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np

from ..base.kernels import compiled

#: from this many columns the compiled loop beats one call per column, its
#: last chunk's padding included (its build, a fraction of a second per
#: kernel and chunk, is done once and cached on disk)
COMPILE_MAPPED_MIN = 256
#: the compiled loop's chunks (columns per call): a small one for small
#: meshes, where padding one large chunk would cost more than the calls
#: saved, and a large one where the call's overhead vanishes
COMPILED_CHUNKS = (512, 2048)
#: one call of the compiled loop costs about what this many columns do (the
#: arguments and results set per chunk, for the P1 elastic kernels: four
#: chunks of 512 took about a quarter longer than one of 2,048)
CHUNK_CALL_COLUMNS = 190


def chunk_for(count: int) -> int:
    """The chunk of :data:`COMPILED_CHUNKS` whose padded columns and calls
    cost least for ``count`` columns."""
    return min(COMPILED_CHUNKS, key=lambda c: math.ceil(count / c) * (c + CHUNK_CALL_COLUMNS))


class Mapped:
    """``fn`` (one column in, one column out) mapped over ``count``
    columns; ``constants`` {input index: (count, ...) array} are set once;
    ``symbolic``: ``fn``'s uncompiled form, which enables the compiled loop
    from :data:`COMPILE_MAPPED_MIN` columns.

    ``self(arg0, n_out)``: ``arg0`` (count, ...) the per-column first input;
    returns the first ``n_out`` outputs, flat, column after column."""

    def __init__(self, fn: ca.Function, count: int, constants: dict[int, np.ndarray],
                 symbolic: ca.Function | None = None):
        self.count = count
        self._col_out = [fn.nnz_out(i) for i in range(fn.n_out())]
        self._col_in = [fn.nnz_in(i) for i in range(fn.n_in())]
        self.chunk, self.fn = count, None
        if count == 0:              # CasADi maps over no columns with an error: nothing to evaluate
            return
        if symbolic is not None and count >= COMPILE_MAPPED_MIN:
            chunk = chunk_for(count)
            loop = symbolic.map(chunk, "serial")
            built = compiled(loop)
            if built is not loop:   # (no compiler: the per-column calls below)
                self.fn, self.chunk = built, chunk
        if self.fn is None:
            self.fn = fn.map(count, "serial")
        self.chunks = math.ceil(count / self.chunk)
        self.buf, self._eval = self.fn.buffer()
        self._constants = {i: self._padded(value, i) for i, value in constants.items()}
        if self.chunks == 1:
            for i, arr in self._constants.items():
                self.buf.set_arg(i, memoryview(arr))

    def _padded(self, value, i: int) -> np.ndarray:
        """Input ``i`` for every column, flat and contiguous, padded to whole
        chunks with copies of the last column."""
        flat = np.ascontiguousarray(value, dtype=np.float64).reshape(-1)
        short = self.chunks * self.chunk - self.count
        if short == 0:
            return flat
        width = self._col_in[i]
        return np.concatenate([flat, np.tile(flat[-width:], short)])

    def __call__(self, arg0: np.ndarray, n_out: int) -> list[np.ndarray]:
        if self.count == 0:
            return [np.empty(0) for _ in range(n_out)]
        arg0 = self._padded(arg0, 0)
        outs = [np.empty(self.chunks * self.chunk * self._col_out[i]) for i in range(n_out)]
        for k in range(self.chunks):
            self._set(0, arg0, k)
            if self.chunks > 1:
                for i, arr in self._constants.items():
                    self._set(i, arr, k)
            for i, out in enumerate(outs):
                size = self.chunk * self._col_out[i]
                self.buf.set_res(i, memoryview(out[k * size:(k + 1) * size]))
            self._eval()
        return [out[:self.count * self._col_out[i]] for i, out in enumerate(outs)]

    def _set(self, i: int, arr: np.ndarray, k: int) -> None:
        size = self.chunk * self._col_in[i]
        self.buf.set_arg(i, memoryview(arr[k * size:(k + 1) * size]))
