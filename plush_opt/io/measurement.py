"""Measurement file (format ``plush-opt-measurements/1``, docs/problem-format.md)
-> validated :class:`Measurements`, for calibration.

Read by the one guarded reader and checked with the one :class:`Checker`,
so a bad file gets the same one-line errors as a problem file. The scene
it names (relative to the measurement file) is loaded too: the poses must
give every winch of that scene, and the markers must lie on its body.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..base.errors import format_number, format_point
from ..base.geometry import classify_points, locate_in_triangles
from .scene import Scene
from .checker import Checker, at_index, at_key
from .problem_file import load_scene
from .yaml_reader import read_yaml

FORMAT = "plush-opt-measurements/1"
DEFAULT_SIGMA = 1.0               # the spec's default measurement noise (length units)
# sigma below this fraction of the body's diameter: the coincidence tolerance
# of points; residuals over it would overflow the fit's sums of squares
MIN_SIGMA = 1e-9
# a seen marker this many body diameters from its rest place is a typo (and
# would overflow the fit): no soft robot travels that far
MAX_TRAVEL = 10.0

_TOP_KEYS = ("format", "problem", "markers", "poses", "sigma")
_POSE_KEYS = ("contractions", "positions")


@dataclass(frozen=True)
class Measurements:
    """Markers seen on a robot at several winch settings.

    Attributes
    ----------
    source : the file name (for messages).
    problem_path : the scene's problem file, resolved.
    scene : that scene, validated.
    markers : (n_markers, 2) body points, rest coordinates.
    contractions : (n_poses, n_winches), in the scene's winch order.
    positions : (n_poses, n_markers, 2) measured positions; NaN where unseen.
    sigma : measurement noise, length units.
    """

    source: str
    problem_path: Path
    scene: Scene
    markers: np.ndarray
    contractions: np.ndarray
    positions: np.ndarray
    sigma: float

    @property
    def n_poses(self) -> int:
        return self.contractions.shape[0]

    @property
    def n_markers(self) -> int:
        return self.markers.shape[0]

    @property
    def seen(self) -> np.ndarray:
        """(n_poses, n_markers) bool: the marker was seen in that pose."""
        return np.all(np.isfinite(self.positions), axis=2)


def load_measurements(path) -> Measurements:
    """Read and validate a measurement file and the scene it names.

    Raises
    ------
    SceneError
        One line starting with the file name (or the problem file's name,
        for an error in the scene) naming the key and list index.
    """
    path = Path(path)
    source = os.path.basename(os.fspath(path)) or os.fspath(path)
    data = read_yaml(path, what="measurement file", source=source)
    ck = Checker(source)
    ck.document(data, _TOP_KEYS, required=("format", "problem", "markers", "poses"))
    fmt = ck.string(data["format"], "format")
    if fmt != FORMAT:
        ck.fail("format", f"expected exactly '{FORMAT}', got {fmt!r}")
    problem = ck.name(data["problem"], "problem")
    problem_path = (path.parent / problem).resolve() if not Path(problem).is_absolute() else Path(problem)
    if not problem_path.is_file():
        ck.fail("problem", f"no problem file {problem!r} next to the measurement file")
    scene = load_scene(problem_path)
    sigma = data.get("sigma")
    sigma = DEFAULT_SIGMA if sigma is None else ck.number(sigma, "sigma", gt=0)
    if sigma < MIN_SIGMA * scene.diameter:
        ck.fail("sigma", f"{format_number(sigma)} is below {MIN_SIGMA:g} of the body's diameter "
                f"({format_number(scene.diameter)}): no camera resolves that")
    markers = ck.points(data["markers"], "markers", min_len=1)
    _check_markers_on_body(ck, scene, markers)
    poses = ck.seq(data["poses"], "poses", min_len=1, what="list of poses")
    contractions = np.empty((len(poses), len(scene.winches)))
    positions = np.full((len(poses), len(markers), 2), np.nan)
    for i, pose in enumerate(poses):
        where = at_index("poses", i)
        ck.mapping(pose, where, _POSE_KEYS, required=_POSE_KEYS)
        contractions[i] = _contractions(ck, scene, pose["contractions"], at_key(where, "contractions"))
        positions[i] = _positions(ck, pose["positions"], at_key(where, "positions"), len(markers))
        _check_positions_near(ck, scene, markers, positions[i], at_key(where, "positions"))
    seen = np.all(np.isfinite(positions), axis=2)
    if not seen.any():
        ck.fail("poses", "no marker is seen in any pose (every position is null)")
    return Measurements(source, problem_path, scene, markers, contractions, positions, sigma)


def _contractions(ck: Checker, scene: Scene, raw, where: str) -> np.ndarray:
    names = scene.winch_names
    ck.mapping(raw, where, names)
    out = np.empty(len(names))
    for w, winch in enumerate(scene.winches):
        key = at_key(where, winch.name)
        if raw.get(winch.name) is None:
            ck.fail(key, "missing: every pose gives every winch's contraction")
        out[w] = ck.number(raw[winch.name], key)
        lo, hi = winch.bounds
        if not lo <= out[w] <= hi:
            ck.fail(key, f"{out[w]:g} is outside the winch's bounds [{lo:g}, {hi:g}] in {scene.source}")
    return out


def _positions(ck: Checker, raw, where: str, n_markers: int) -> np.ndarray:
    raw = ck.seq(raw, where, what="list of marker positions [[x, y] or null, ...]")
    if len(raw) != n_markers:
        ck.fail(where, f"expected {n_markers} entries (one per marker, null if unseen), got {len(raw)}")
    out = np.full((n_markers, 2), np.nan)
    for k, p in enumerate(raw):
        if p is not None:
            out[k] = ck.point(p, at_index(where, k))
    return out


def _check_positions_near(ck: Checker, scene: Scene, markers, positions, where: str):
    """A seen marker within :data:`MAX_TRAVEL` body diameters of its rest place."""
    far = np.linalg.norm(positions - markers, axis=1) > MAX_TRAVEL * scene.diameter
    bad = np.flatnonzero(far)          # NaN (unseen) compares False
    if bad.size:
        k = int(bad[0])
        ck.fail(at_index(where, k), f"point {format_point(positions[k])} is more than {MAX_TRAVEL:g} body "
                f"diameters ({MAX_TRAVEL * scene.diameter:.4g}) from its marker's rest place")


def _check_markers_on_body(ck: Checker, scene: Scene, markers: np.ndarray):
    tol = scene.tolerance
    if scene.nodes is not None:
        tri, _ = locate_in_triangles(scene.nodes[scene.triangles], markers, tol)
        outside = tri < 0
    else:
        outside = classify_points(markers, [scene.outline, *scene.holes], tol) < 0
    bad = np.flatnonzero(outside)
    if bad.size:
        k = int(bad[0])
        ck.fail(at_index("markers", k), f"point {format_point(markers[k])} lies outside the body "
                f"of {scene.source}")
