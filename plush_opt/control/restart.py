"""Restart moves of the gradient loop: where it would stop, look a little
further before giving up (used by :class:`~plush_opt.control.gradient.Controller`)."""

from __future__ import annotations

import logging

import numpy as np

from .result import ControlIterate
from .slack import take_up

log = logging.getLogger("plush_opt.control.gradient")


def restart_move(ctl, last: ControlIterate):
    """Where the loop would stop, look a little further before giving up.

    Two situations fool a local method here:

    * a winch whose tendons are all slack has a zero gradient: nothing
      tells the loop whether pulling would help;
    * a winch held at a bound by its gradient may only see the first
      millimetres of pull, which engage the "wrong" tendon first (one
      slack at rest, say), although pulling further helps a lot.

    For those winches, the slack is reeled in (up to the point where the
    tightest tendon just enters the smoothing zone, which leaves the pose
    unchanged); and, when the loop has not even halved O since the
    targets were set (the trap shows as a loop stuck near its start), a
    few probes go inwards by 5, 15 and 40 % of the range, each a
    certified equilibrium taken only if it lowers O by 0.1 %. Each winch
    gets this once per set of targets.

    Returns the move's (contractions, certified equilibrium), or None.
    """
    names = ctl.model.winch_names
    slack = ctl._slack_winches(last)
    # the bound trap shows as a loop stuck near where it started; a loop
    # that has already made most of its progress is at a real optimum
    stuck = last.objective > ctl.options.stuck_fraction * ctl._objective_at_start
    held = [names.index(n) for n in last.active_bounds] if stuck else []
    cand = [w for w in dict.fromkeys(slack + held) if w not in ctl._restarted]
    if not cand:
        return None
    lower, upper = ctl.model.lower, ctl.model.upper
    span = upper - lower
    for w in cand:
        # a winch counts as tried once its moves are spent or one is
        # taken; the others keep their turn for the next stop
        ctl._restarted.add(w)
        for frac in (0.0, *ctl.options.probe_fractions):
            c = last.contraction.copy()
            if w in slack:
                c[w] = take_up(ctl.model, last.x, last.contraction, w)
                inward = 1.0
            elif frac == 0.0:
                continue
            else:
                inward = 1.0 if c[w] <= lower[w] + 0.5 * span[w] else -1.0
            c[w] = float(np.clip(c[w] + inward * frac * span[w], lower[w], upper[w]))
            if c[w] == last.contraction[w]:
                continue
            eq = ctl._solve(c, last.x)
            if not eq.converged:
                continue
            value = ctl.targets.value(eq.x)
            if frac == 0.0:
                # slack reeled in: keep it if pulling now helps
                grad, _, _ = ctl._gradient(eq, False)
                if grad[w] < 0 and value <= last.objective * (1 + 1e-9):
                    log.info("took up the slack of %s", names[w])
                    return c, eq
            elif value < last.objective * (1 - ctl.options.probe_gain):
                log.info("probe: moving %s to %.4g lowered O", names[w], c[w])
                return c, eq
    return None
