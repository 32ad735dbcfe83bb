"""Starting points of a calibration from several starts: the scene's
values and others spread around them, the same on every machine.

Only the parameters in a nonlinear coordinate move (Young's modulus and
tendon stiffness in log, Poisson's ratio in logit): the fit is nearly
linear in the offsets (lengths), so a start away from them finds no other
minimum, and their unit is the scene's.
"""

from __future__ import annotations

import numpy as np

from .parameters import from_theta, to_theta

#: log-coordinate half-width of the spread of moduli and stiffnesses: starts from 1/3x to 3x
LOG_SPREAD = float(np.log(3.0))
#: logit half-width for Poisson's ratio: nu from about 0.14 to 0.41 around 0.3
LOGIT_SPREAD = 1.5
#: the most starts a calibration takes (each one is a whole fit)
MAX_STARTS = 256
_PRIMES = (2, 3, 5, 7, 11, 13, 17, 19, 23, 29)


def _halton(k: int, base: int) -> float:
    """The k-th element (k >= 1) of the van der Corput sequence in ``base``, in (0, 1)."""
    f, out = 1.0, 0.0
    while k:
        f /= base
        out += f * (k % base)
        k //= base
    return out


def starting_values(base, params, n_starts: int) -> list:
    """``n_starts`` :class:`~plush_opt.fit.parameters.Values`: ``base``
    first, then points of a Halton sequence over the box of
    :data:`LOG_SPREAD` / :data:`LOGIT_SPREAD` around it in the moved
    parameters (see the module's docstring)."""
    if not 1 <= n_starts <= MAX_STARTS:
        raise ValueError(f"n_starts: expected 1..{MAX_STARTS}, got {n_starts!r}")
    spread = {"youngs_modulus": LOG_SPREAD, "tendon_stiffness": LOG_SPREAD, "poisson_ratio": LOGIT_SPREAD}
    moved = [p for p in params if p.kind in spread]
    out = [base]
    for k in range(1, n_starts):
        v = base
        for dim, p in enumerate(moved):
            # index k + 1: the sequence's first point is the centre, the base itself
            u = 2.0 * _halton(k + 1, _PRIMES[dim % len(_PRIMES)]) - 1.0    # in (-1, 1)
            v = v.with_value(p, from_theta(p, to_theta(p, base.get(p)) + spread[p.kind] * u))
        out.append(v)
    return out


def fit_cost(meas, result, huber: float | None) -> float:
    """The cost the fit minimised at ``result.after`` (half the sum of
    squared normalised residuals, or the Huber cost): what ranks starts."""
    from .solve import _Residuals
    return _Residuals(meas, result.fitted_poses, huber)(result.after)[0]
