"""Shared helpers of the hard-case suite: the scenes of problems/hard/,
an independent re-check of the equilibrium certificate, and small
assertions used by every test.

The re-check does not trust the solver's own flags: it re-evaluates the
energy at the returned pose, recomputes the relative residual, and tests
positive definiteness of the Hessian with a dense Cholesky of
``H - tol I`` with ``tol = 10 eps |H|_inf``, the size of the round-off
in a computed eigenvalue. A Hessian whose smallest eigenvalue is within
round-off of zero (a free rigid mode, a hinge) is *not* positive definite
by this test, even if a sparse factorisation happened to succeed.
"""

from __future__ import annotations

import functools
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from plush_opt.solve.equilibrium import EquilibriumOptions
from plush_opt.io import load_scene
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from plush_opt.fem.objective import Targets

ROOT = Path(__file__).resolve().parents[2]
HARD = ROOT / "problems" / "hard"
INVALID = HARD / "invalid"
SHIPPED = ROOT / "problems"
GTOL = EquilibriumOptions().gtol
BACKENDS = ("newton", "ipopt")


def backend_marks(backend: str) -> list:
    """Marks of a test parameter that solves with ``backend``: IPOPT's
    solves of these scenes take seconds each (``pytest -m "not slow"``
    leaves them out), Newton's a fraction of one."""
    return [pytest.mark.slow] if backend == "ipopt" else []


#: BACKENDS as test parameters, with their marks
BACKEND_PARAMS = [pytest.param(b, marks=backend_marks(b)) for b in BACKENDS]

#: hard scenes that build a model (the under-pinned ones are refused, or
#: should be: see test_hard_scenes.py)
SOLVABLE = ("near_inversion", "buckling", "stiff_tendons", "slack_taut",
            "contradictory_targets", "unreachable_target", "inverted_explicit",
            "sliver_explicit")
UNDERPINNED = ("underpinned_one_pin", "underpinned_one_node", "underpinned_island",
               "underpinned_hinge")


def hard_names() -> list[str]:
    """Every scene file of problems/hard/ (not the invalid ones), by stem."""
    return sorted(p.stem for p in HARD.glob("*.yaml"))


def path_of(name: str) -> Path:
    p = HARD / f"{name}.yaml"
    return p if p.exists() else SHIPPED / f"{name}.yaml"


@functools.lru_cache(maxsize=None)
def built(name: str):
    """(scene, mesh, model, targets) of problems/hard/<name>.yaml (or a
    shipped problem of that name), built once per session."""
    scene = load_scene(path_of(name))
    mesh = build_mesh(scene)
    model = build_model(scene, mesh)
    return scene, mesh, model, Targets.from_mesh(mesh, scene)


def build(scene):
    """(mesh, model, targets) of a scene variant (not cached)."""
    mesh = build_mesh(scene)
    model = build_model(scene, mesh)
    return mesh, model, Targets.from_mesh(mesh, scene)


def eq_options(backend: str, **kw) -> EquilibriumOptions:
    return EquilibriumOptions(backend=backend, **kw)


def header(path: Path) -> str:
    """The leading comment block of a problem file, without the '# '."""
    lines = []
    for line in path.read_text().splitlines():
        if not line.startswith("#"):
            break
        lines.append(line[2:] if line.startswith("# ") else line[1:])
    return "\n".join(lines)


# -- the certificate, re-checked ------------------------------------------------

def pd_margin(H) -> float:
    """Round-off size of a computed eigenvalue of symmetric H: 10 eps |H|_inf."""
    A = H.toarray() if hasattr(H, "toarray") else np.asarray(H)
    return 10 * np.finfo(float).eps * float(np.abs(A).sum(axis=1).max())


def positive_definite(H) -> bool:
    """H - margin I has a Cholesky factor (numpy, dense)."""
    A = H.toarray() if hasattr(H, "toarray") else np.asarray(H)
    try:
        np.linalg.cholesky(A - pd_margin(A) * np.eye(A.shape[0]))
    except np.linalg.LinAlgError:
        return False
    return True


def smallest_eigenvalue(model, x, c) -> float:
    H = model.evaluate(x, c).hessian.toarray()
    return float(np.linalg.eigvalsh(H)[0])


def recheck(model, eq, gtol: float = GTOL) -> list[str]:
    """What is wrong with calling ``eq`` a certified equilibrium (empty
    list if nothing): admissibility, relative residual, positive
    definiteness, all recomputed from the model."""
    problems = []
    ev = model.evaluate(eq.x, eq.contraction)
    if not ev.admissible:
        return [f"pose not admissible (min J {model.jacobians(eq.x).min():.3g})"]
    rel = float(np.linalg.norm(ev.gradient)) / ev.force_scale
    if not rel <= gtol * (1 + 1e-9):
        problems.append(f"relative residual {rel:.3g} > gtol {gtol:g}")
    if abs(rel - eq.relative_residual) > 1e-6 * max(rel, gtol):
        problems.append(f"reported relative residual {eq.relative_residual:.3g}, recomputed {rel:.3g}")
    if not positive_definite(ev.hessian):
        lam = float(np.linalg.eigvalsh(ev.hessian.toarray())[0])
        problems.append(f"Hessian not positive definite beyond round-off (lambda_min {lam:.3g}, "
                        f"margin {pd_margin(ev.hessian):.3g})")
    return problems


def assert_certified(model, eq, what: str = ""):
    assert eq.converged, f"{what}: not converged: {eq.status}"
    problems = recheck(model, eq)
    assert not problems, f"{what}: claims converged ({eq.status}) but: {'; '.join(problems)}"


def assert_honest(model, eq, what: str = ""):
    """Converged only if the certificate holds; any returned pose (converged
    or not) admissible unless the status says it is not; a status always."""
    assert isinstance(eq.status, str) and eq.status.strip(), f"{what}: empty status"
    if eq.converged:
        assert_certified(model, eq, what)
    elif "not admissible" not in eq.status:
        J = model.jacobians(eq.x)
        assert np.all(np.isfinite(eq.x)) and J.min() > 0, \
            f"{what}: returned a pose with min J = {J.min():.3g} ({eq.status})"


def assert_within_bounds(model, c, what: str = ""):
    c = np.asarray(c)
    assert np.all(c >= model.lower) and np.all(c <= model.upper), \
        f"{what}: contraction {c.tolist()} outside bounds " \
        f"{model.lower.tolist()}..{model.upper.tolist()}"


# -- the command line -----------------------------------------------------------

def cli(*args, cwd=None, timeout=120) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "plush_opt", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=timeout)


def expect_line(path: Path) -> str:
    """The ``# expect: REGEX`` line of an invalid problem file."""
    for line in path.read_text(errors="replace").splitlines():
        if line.startswith("# expect: "):
            return line[len("# expect: "):]
    raise AssertionError(f"{path.name}: no '# expect:' line")


def assert_one_line_error(p: subprocess.CompletedProcess, name: str, pattern: str | None = None):
    """Exit 2, exactly one stderr line starting 'plush-opt: error: NAME: ',
    matching ``pattern``, no traceback."""
    err = p.stderr.strip()
    assert p.returncode == 2, f"exit {p.returncode}, stderr: {p.stderr!r}"
    assert "Traceback" not in p.stderr, p.stderr
    assert len(err.splitlines()) == 1, f"more than one line: {p.stderr!r}"
    assert err.startswith(f"plush-opt: error: {name}: "), err
    if pattern is not None:
        assert re.search(pattern, err), f"{err!r} does not match {pattern!r}"
