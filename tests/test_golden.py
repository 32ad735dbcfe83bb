"""Golden results: every control method on every shipped problem ends
where it ended when tests/golden/control.txt was written (regenerate with
tools/make_golden.py, only for an intended change), so a refactor cannot
drift silently."""

from __future__ import annotations

import pytest

from shipped import ROOT, problem

pytestmark = pytest.mark.slow  # every control method on every shipped problem

GOLDEN = ROOT / "tests" / "golden" / "control.txt"
# the loops stop at gtol/ftol: a refactor that keeps the arithmetic keeps
# every digit; this leaves room for summation-order round-off only
REL = 1e-7


def _cases():
    for line in GOLDEN.read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, method, converged, reason, objective, *cs = line.split()
            yield pytest.param(name, method, converged == "True", reason, float(objective),
                               {k: float(v) for k, v in (c.split("=") for c in cs)},
                               id=f"{name}-{method}")


@pytest.mark.parametrize("name, method, converged, reason, objective, contractions", list(_cases()))
def test_control_matches_the_golden_result(name, method, converged, reason, objective, contractions):
    p = problem(name)
    r = p.control(method=method)
    assert (r.converged, r.reason) == (converged, reason), r.status
    assert r.objective == pytest.approx(objective, rel=REL, abs=1e-12)
    span = {n: hi - lo for n, lo, hi in zip(p.winch_names, p.model.lower, p.model.upper)}
    for n, c in contractions.items():
        assert r.contractions[n] == pytest.approx(c, rel=REL, abs=REL * span[n]), n
    # the result is a certified, stable pose within the bounds
    assert r.equilibrium.converged and r.equilibrium.min_eigenvalue > 0
