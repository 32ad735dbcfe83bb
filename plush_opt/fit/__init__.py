"""Model fitting (``plush-opt calibrate``): fit scene parameters (Young's
modulus, tendon assembly offsets, ...) to markers measured on a real robot
(docs/calibration.md). Not the board file's ticks per length, which is
:mod:`plush_opt.board.board_file`.

``calibrate(meas)`` is the whole job; :mod:`.parameters` says how each
parameter enters the energy, :mod:`.predict` gives the markers and their
exact sensitivities, :mod:`.solve` is the Levenberg-Marquardt fit,
:mod:`.report` the honest summary and :mod:`.edit` writes the fitted
problem file.
"""

from .parameters import DEFAULT_FIT, KINDS, Parameter, Values, parse_fit
from .solve import FitOptions, FitResult, fit

__all__ = ["DEFAULT_FIT", "KINDS", "FitOptions", "FitResult", "Parameter", "Values", "fit",
           "parse_fit"]
