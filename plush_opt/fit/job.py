"""The whole calibration: measurements in, fit, fitted problem file out."""

from __future__ import annotations

import math

import numpy as np

from ..solve.equilibrium import EquilibriumOptions
from ..base.errors import PlushError, SceneError
from ..io.measurement import Measurements
from ..io.problem_file import scene_from_dict
from ..io.yaml_reader import read_yaml
from ..fem.mesh import build_mesh
from .edit import edit_problem_text, fitted_changes
from .parameters import Values, effective_offsets, parse_fit
from .predict import Predictor
from .solve import FitOptions, FitResult, fit

#: the fitted file must read back to the fitted values within this relative error
READBACK_TOL = 1e-8


def calibrate(meas: Measurements, fit_spec=None, options: FitOptions | None = None, *,
              max_area: float | None = None, mesh=None,
              equilibrium: EquilibriumOptions | None = None, start: Values | None = None) -> FitResult:
    """Fit the parameters named by ``fit_spec`` (default: Young's modulus
    and every tendon's assembly offset) to ``meas``.

    Starts from ``start`` (default: the scene's values, winch zero offsets
    from 0; see :func:`~plush_opt.fit.starts.starting_values`), on the
    scene's mesh (or one of triangles up to ``max_area``, or ``mesh``).
    """
    options = options or FitOptions()
    for i in options.holdout:
        if not 0 <= i < meas.n_poses:
            raise SceneError(f"--holdout: pose {i} does not exist ({meas.source} has poses "
                             f"0..{meas.n_poses - 1})")
    if len(set(options.holdout)) >= meas.n_poses:
        raise SceneError("--holdout: every pose is held out; nothing is left to fit")
    if options.huber is not None and not options.huber > 0:
        raise SceneError(f"--huber: expected a threshold > 0 (in sigma units), got {options.huber:g}")
    params = parse_fit(meas.scene, fit_spec)
    mesh = build_mesh(meas.scene, max_area) if mesh is None else mesh
    predictor = Predictor(meas, mesh, params, Values.of_scene(meas.scene) if start is None else start,
                          equilibrium)
    return fit(predictor, options)


def fitted_text(meas: Measurements, result: FitResult) -> str:
    """The input problem file's text with the fitted keys changed, checked
    by reading it back."""
    text = meas.problem_path.read_text(encoding="utf-8")
    data = read_yaml(meas.problem_path, what="problem file")
    values = result.after.values
    offsets = effective_offsets(values, result.after.model)
    new = edit_problem_text(text, fitted_changes(data, values, offsets, result.params))
    _check_readback(new, meas, values, offsets)
    return new


def _check_readback(text: str, meas: Measurements, values: Values, offsets: np.ndarray):
    import yaml
    scene = scene_from_dict(yaml.safe_load(text), meas.problem_path.name)
    back = Values.of_scene(scene)
    pairs = [(back.youngs_modulus, values.youngs_modulus), (back.poisson_ratio, values.poisson_ratio),
             (back.tendon_stiffness, values.tendon_stiffness),
             *zip(back.assembly_offset, offsets)]
    for got, want in pairs:
        if not math.isclose(got, want, rel_tol=READBACK_TOL, abs_tol=READBACK_TOL * 1e-3):
            raise PlushError(f"the fitted problem file reads back {got!r} where {want!r} was "
                             "written (a bug)")
