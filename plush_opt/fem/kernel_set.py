"""A named set of CasADi kernels, compiled on first use and kept by its owner.

Compiling a kernel (plush_opt.base.kernels.compiled: generate C, look the
library up in the disk cache, load and verify it) costs far more than a
model's construction, so a kernel is compiled once per process and shared by
every model that uses it. The sharing is explicit: each family of kernels
has one owner object that holds its :class:`KernelSet` (an element type,
plush_opt.fem.elements; the tendon law, plush_opt.fem.tendon_law; the
via-point friction law, plush_opt.fem.friction), and a model asks that
owner for the compiled kernels. Nothing else keeps compiled kernels.
"""

from __future__ import annotations

import casadi as ca

from ..base.kernels import compiled


class KernelSet:
    """Kernels by name: ``kernels[name]`` is the compiled form of the
    Function given under that name (compiled when first asked for, then
    kept); ``kernels.symbolic[name]`` is the Function itself (for CasADi
    expressions and derivatives)."""

    def __init__(self, **functions: ca.Function):
        self.symbolic = dict(functions)
        self._compiled: dict[str, ca.Function] = {}

    def __getitem__(self, name: str) -> ca.Function:
        fn = self._compiled.get(name)
        if fn is None:
            fn = self._compiled[name] = compiled(self.symbolic[name])
        return fn

    def __repr__(self) -> str:
        return f"KernelSet({', '.join(self.symbolic)}; compiled: {', '.join(self._compiled) or 'none'})"
