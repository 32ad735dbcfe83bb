"""``plush-opt bench --peers``: the forward solve against FElupe and
scikit-fem on the same mesh and material, timed side by side.

The problem: a shipped scene's body and mesh with its tendons, winches and
targets removed and gravity added (:data:`PEER_DENSITY`, :data:`PEER_GRAVITY`):
plane-strain compressible Neo-Hookean, psi = mu/2 (|F|^2 - 2) - mu ln J +
lam/2 (ln J)^2 per unit volume times the thickness, the pinned nodes held by
the scene's pin springs k/2 |x - X|^2 and the element weights shared among
their nodes. FElupe and scikit-fem assemble the elastic part (their own
kernels and assembly, one quadrature point per linear triangle, as ours);
the pin springs and the gravity load, the same arrays for all three, are
added to their vector and matrix. Their Newton loop is the plain one (full
steps, FElupe's ``newtonrhapson``) on the same factorisation as ours
(:class:`~plush_opt.base.linalg.Factorizer`: CHOLMOD, the same ordering,
simplicial or supernodal by the same rule, the symbolic analysis done once
before the timed runs, as ours), stopping where ours does: |residual| below
``gtol`` times our force scale. Ours is :func:`solve_equilibrium` as shipped
(line search, certificate: its last factorisation certifies the pose).

The solvers are run in turn within each repeat (interleaved), CPU times
(``time.process_time``: one BLAS thread, so a shared machine slows each
alike); each run's pose is compared with ours. FElupe and scikit-fem are
the optional ``[bench]`` extra.
"""

from __future__ import annotations

import dataclasses
import importlib.util
import time

import numpy as np
import scipy.sparse as sp

from ..base.linalg import Factorizer
from ..fem.mesh import build_mesh, mesh_for_nodes
from ..io import load_scene
from ..problem import from_scene
from ..solve.equilibrium import EquilibriumOptions, solve_equilibrium
from .timing import timed_into

#: body density of the peer problem [t/mm^3]: 100 kg/m^3, a fibre-filled felt body
PEER_DENSITY = 1e-10
#: gravity of the peer problem [mm/s^2], downwards
PEER_GRAVITY = (0.0, -9810.0)
#: the peers' Newton gives up after this many iterations (ours has its own limit)
PEER_MAX_ITERATIONS = 100
#: the peers available, by the module each needs
PEERS = {"felupe": "felupe", "scikit-fem": "skfem"}


def available_peers() -> list[str]:
    """The peers whose package is installed (the ``[bench]`` extra)."""
    return [name for name, module in PEERS.items() if importlib.util.find_spec(module) is not None]


def peer_problem(problem, nodes: int, element: str = "P1"):
    """(scene, mesh, problem) of the peer comparison: the problem file's
    body and mesh (about ``nodes`` nodes; 0: the file's mesh) under gravity,
    without tendons."""
    scene = load_scene(problem).replace(element=element)
    scene = scene.replace(tendons=(), winches=(), targets=(), gravity=np.array(PEER_GRAVITY),
                          material=dataclasses.replace(scene.material, density=PEER_DENSITY))
    mesh = build_mesh(scene) if nodes == 0 else mesh_for_nodes(scene, nodes)
    return scene, mesh, from_scene(scene, mesh)


class _Loads:
    """What every solver shares: rest pose, pinned dofs and their spring,
    the gravity load and the stopping threshold, all from our model."""

    def __init__(self, model, threshold: float):
        pins = next(t for t in model.terms if t.name == "pins")
        gravity = next(t for t in model.terms if t.name == "gravity")
        self.X, self.n_dofs = model.X.copy(), model.n_dofs
        self.pin_dofs, self.k_pin = pins.dofs, pins.stiffness
        self.f_ext = gravity.force
        self.threshold = threshold
        diag = np.zeros(self.n_dofs)
        diag[self.pin_dofs] = self.k_pin
        self.K_pin = sp.diags(diag, format="csc")

    def residual(self, r_elastic, u):
        r = r_elastic - self.f_ext
        r[self.pin_dofs] += self.k_pin * u[self.pin_dofs]
        return r


class _PerPattern:
    """Our :class:`Factorizer`, one per sparsity pattern a peer's matrix
    takes (its assembly drops the entries that are exactly zero at the rest
    pose, so its first matrix has fewer), each keeping its symbolic
    analysis, as our model's one pattern does."""

    def __init__(self):
        self._by_pattern: dict = {}

    def factor(self, K):
        key = (K.shape, K.indptr.tobytes(), K.indices.tobytes())
        return self._by_pattern.setdefault(key, Factorizer()).factor(K)


def _newton(assemble, loads: _Loads, factorizer: _PerPattern) -> dict:
    """Full Newton steps on displacements u (n_dofs,) from zero, one
    factorisation per step by ``factorizer`` (ours: the same backend,
    CHOLMOD mode and ordering as ours, each pattern's symbolic analysis
    kept from one solve to the next as our model's is), until |r| <= threshold;
    ``assemble(u) -> (r_elastic, K_elastic)``. Returns u, iterations and
    the CPU seconds of assembly and factorisation + solve."""
    u = np.zeros(loads.n_dofs)
    its, t_asm, t_fac = 0, 0.0, 0.0
    while True:
        t = time.process_time()
        r_el, K_el = assemble(u)
        r = loads.residual(r_el, u)
        t_asm += time.process_time() - t
        if np.linalg.norm(r) <= loads.threshold or its >= PEER_MAX_ITERATIONS:
            break
        t = time.process_time()
        K = (K_el + loads.K_pin).tocsc()
        K.sort_indices()
        u = u - factorizer.factor(K).solve(r)
        t_fac += time.process_time() - t
        its += 1
    return {"u": u, "iterations": its, "factorisations": its, "assembly_s": t_asm, "factor_s": t_fac,
            "converged": bool(np.linalg.norm(r) <= loads.threshold)}


def _felupe_assembler(model, mesh, loads: _Loads):
    import felupe as fem
    mat = model.scene.material
    fmesh = fem.Mesh(points=mesh.X.copy(), cells=mesh.elements.astype(np.int64), cell_type="triangle")
    region = fem.RegionTriangle(fmesh)
    field = fem.FieldContainer([fem.FieldPlaneStrain(region, dim=2)])
    solid = fem.SolidBody(fem.NeoHookeCompressible(mu=mat.mu * mat.thickness, lmbda=mat.lam * mat.thickness),
                          field)

    def assemble(u):
        field[0].values[:] = u.reshape(-1, 2)
        r = np.asarray(solid.assemble.vector(field).toarray()).ravel()
        return r, solid.assemble.matrix(field)
    return assemble


def _skfem_assembler(model, mesh, loads: _Loads):
    from skfem import Basis, BilinearForm, ElementTriP1, ElementVector, LinearForm, MeshTri, asm
    from skfem.helpers import ddot, det, grad, identity, inv, transpose
    mat = model.scene.material
    mu, lam = mat.mu * mat.thickness, mat.lam * mat.thickness
    basis = Basis(MeshTri(mesh.X.T.copy(), mesh.elements.T.copy()), ElementVector(ElementTriP1()), intorder=1)
    # our flat order [x0, y0, x1, y1, ...] -> scikit-fem's dofs
    order = np.asarray(basis.nodal_dofs).T.reshape(-1)

    def kinematics(w):
        F = grad(w["u"]) + identity(grad(w["u"]))
        return F, transpose(inv(F)), np.log(det(F))

    @LinearForm
    def force(v, w):
        F, FinvT, lnJ = kinematics(w)
        return ddot(mu * (F - FinvT) + lam * lnJ * FinvT, grad(v))

    @BilinearForm
    def stiffness(du, v, w):
        F, FinvT, lnJ = kinematics(w)
        dF = grad(du)
        dP = mu * dF + (mu - lam * lnJ) * _matmul(FinvT, _matmul(transpose(dF), FinvT)) + lam * ddot(FinvT, dF) * FinvT
        return ddot(dP, grad(v))

    def assemble(u):
        us = np.zeros(basis.N)
        us[order] = u
        field = basis.interpolate(us)
        r, K = asm(force, basis, u=field), asm(stiffness, basis, u=field)
        return r[order], K[order][:, order]
    return assemble


def _matmul(A, B):
    """A B of 2-tensor fields (2, 2, elements, points)."""
    return np.einsum("ij...,jk...->ik...", A, B)


_ASSEMBLERS = {"felupe": _felupe_assembler, "scikit-fem": _skfem_assembler}


def _ours(model) -> dict:
    """Our solve, with the CPU time of its evaluations (energy, gradient,
    Hessian: the assembly) and of its factorisations (with their solves'
    share left out: those are timed with the rest) counted inside it."""
    fz = model.factorizer
    plain_eval, plain_factor = model.evaluate, fz.factor
    parts = {"assembly_s": 0.0, "factor_s": 0.0, "factorisations": 0}
    model.evaluate = timed_into(parts, plain_eval, "assembly_s")
    fz.factor = timed_into(parts, plain_factor, "factor_s", "factorisations")
    try:
        eq = solve_equilibrium(model, np.zeros(model.n_winches), options=EquilibriumOptions(eigenvalue=False))
    finally:
        del model.evaluate, fz.factor
    return {"u": eq.x - model.X, "iterations": eq.iterations, "converged": bool(eq.converged),
            "equilibrium": eq, **parts}


def bench_peers(problem, sizes, repeats: int, progress, element: str = "P1") -> list[dict]:
    """For each size: ours, FElupe and scikit-fem (those installed), in turn
    ``repeats`` times; one row per solver with the median CPU time, the
    iterations, the factorisations, and our time over theirs."""
    peers = available_peers()
    rows = []
    for nodes in sizes:
        scene, mesh, prob = peer_problem(problem, nodes, element)
        model = prob.model
        progress(f"peers @ {mesh.n_nodes} nodes: {', '.join(['plush_opt'] + peers)}")
        ref = _ours(model)
        threshold = EquilibriumOptions().gtol * ref["equilibrium"].force_scale
        loads = _Loads(model, threshold)
        runs = {"plush_opt": lambda: _ours(model)}
        for name in peers:
            assemble = _ASSEMBLERS[name](model, mesh, loads)
            runs[name] = lambda a=assemble, f=_PerPattern(): _newton(a, loads, f)
            runs[name]()              # untimed, as ours above: the symbolic analysis, first-call set-up
        times = {name: [] for name in runs}
        last = {}
        for _ in range(repeats):
            for name, run in runs.items():
                t = time.process_time()
                last[name] = run()
                times[name].append(time.process_time() - t)
        ours = float(np.median(times["plush_opt"]))
        size = float(np.abs(ref["u"]).max())
        for name, out in last.items():
            med = float(np.median(times[name]))
            rows.append({"problem": scene.name, "nodes": mesh.n_nodes, "elements": mesh.n_elems, "solver": name,
                         "time_s": med, "iterations": out["iterations"], "factorisations": out["factorisations"],
                         "converged": out["converged"],
                         "max_difference": float(np.abs(out["u"] - ref["u"]).max()) / max(size, 1e-300),
                         "ours_over_this": ours / med, "assembly_s": out.get("assembly_s"),
                         "factor_s": out.get("factor_s")})
    return rows


def render_peers(rows, command: str, repeats: int) -> list[str]:
    """The Markdown section of the peer comparison."""
    if not rows:
        return []
    lines = ["", "## Against FElupe and scikit-fem", "",
             f"`{command}`: the body and mesh of `{rows[0]['problem']}` under gravity (density "
             f"{PEER_DENSITY:g} t/mm^3), no tendons; plane-strain Neo-Hookean; each solver run in turn, "
             f"median CPU time of {repeats}; the same factorisation (CHOLMOD, mode by our rule) and stopping "
             "rule (apps/bench_peers.py). "
             "Ours includes the certificate (its last factorisation); its factorisation column "
             "leaves out the solves, the peers' includes them. Difference: the largest "
             "displacement difference from ours over our largest displacement.", "",
             "| nodes | solver | CPU time [ms] | Newton iterations | factorisations | assembly [ms] | "
             "factorisation + solve [ms] | ours / this | difference | converged |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    ms = lambda v: "—" if v is None else f"{1e3 * v:.1f}"  # noqa: E731
    for r in rows:
        lines.append(f"| {r['nodes']} | {r['solver']} | {ms(r['time_s'])} | {r['iterations']} | "
                     f"{r['factorisations']} | {ms(r['assembly_s'])} | {ms(r['factor_s'])} | "
                     f"{r['ours_over_this']:.2f} | {r['max_difference']:.1e} | {'yes' if r['converged'] else 'NO'} |")
    return lines
