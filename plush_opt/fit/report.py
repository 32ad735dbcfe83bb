"""The report of a model fit (``plush-opt calibrate --report``, format
``plush-opt-calibration/1``): what was fitted, how well, and how sure.

Per pose the RMS marker error (length units: root mean square of the
distances between measured and predicted markers) before and after, and
``rms_sigma``, the RMS of the normalised coordinates (y - measured) / sigma
(1 for a perfect model and honest sigma). chi^2 is summed over the fitted
poses' seen coordinates; its expectation is dof = coordinates - parameters.
"""

from __future__ import annotations

import numpy as np

from .parameters import effective_offsets
from .solve import FitResult

FORMAT = "plush-opt-calibration/1"


def pose_errors(meas, y: np.ndarray) -> list[dict]:
    """RMS errors of each pose between predicted markers ``y`` and the measurements."""
    out = []
    for i in range(meas.n_poses):
        seen = meas.seen[i]
        d = y[i, seen] - meas.positions[i, seen]
        n = int(seen.sum())
        out.append({"rms": float(np.sqrt(np.mean(np.sum(d**2, axis=1)))) if n else None,
                    "rms_sigma": float(np.sqrt(np.mean(d**2)) / meas.sigma) if n else None,
                    "markers_seen": n})
    return out


def chi2(meas, y: np.ndarray, fitted: np.ndarray) -> float:
    seen = meas.seen & fitted[:, None]
    return float(np.sum(((y - meas.positions)[seen] / meas.sigma) ** 2))


def report_dict(meas, result: FitResult, *, fitted_file: str | None = None,
                huber: float | None = None) -> dict:
    """The report document (JSON-ready)."""
    params = result.params
    before, after = pose_errors(meas, result.before.y), pose_errors(meas, result.after.y)
    fitted = result.fitted_poses
    n_coords = int(2 * np.sum(meas.seen & fitted[:, None]))
    dof = n_coords - len(params)
    se = result.standard_errors
    corr = result.correlation
    return {
        "format": FORMAT,
        "measurements": meas.source,
        "problem": meas.scene.name,
        "fitted_file": fitted_file,
        "identifiable": result.identifiable,
        "converged": result.converged,
        "status": result.status,
        "warnings": list(result.warnings),
        "sigma": meas.sigma,
        "parameters": [{"name": p.name, "kind": p.kind,
                        "initial": result.before.values.get(p),
                        "fitted": result.after.values.get(p) if result.identifiable else None,
                        "standard_error": float(s) if result.identifiable else None}
                       for p, s in zip(params, se)],
        "correlation": None if corr is None else np.round(corr, 6).tolist(),
        "assembly_offsets_written": {
            t.name: float(d) for t, d in zip(meas.scene.tendons,
                                             effective_offsets(result.after.values, result.after.model))
        } if result.identifiable else None,
        "poses": [{"index": i, "held_out": bool(not fitted[i]),
                   "rms_before": b["rms"], "rms_after": a["rms"],
                   "rms_sigma_before": b["rms_sigma"], "rms_sigma_after": a["rms_sigma"],
                   "markers_seen": a["markers_seen"]}
                  for i, (b, a) in enumerate(zip(before, after))],
        "chi2_before": chi2(meas, result.before.y, fitted),
        "chi2": chi2(meas, result.after.y, fitted),
        "dof": dof,
        "reduced_chi2": chi2(meas, result.after.y, fitted) / dof if dof > 0 else None,
        "huber": huber,
        "iterations": result.iterations,
        "equilibrium_solves": result.solves,
        "timing": {"fit_s": result.t_wall},
    }


def summary_text(doc: dict) -> str:
    """The report in a few lines, for stdout."""
    lines = [f"{doc['problem']}: calibration from {doc['measurements']}: {doc['status']}"]
    if doc["identifiable"]:
        w = max(len(p["name"]) for p in doc["parameters"])
        for p in doc["parameters"]:
            lines.append(f"  {p['name']:<{w}}  {p['initial']:.6g} -> {p['fitted']:.6g} "
                         f"+- {p['standard_error']:.2g}")
    for pose in doc["poses"]:
        tag = " (held out)" if pose["held_out"] else ""
        if pose["rms_before"] is None:
            continue
        if not doc["identifiable"]:
            lines.append(f"  pose {pose['index']}{tag}: RMS marker error {pose['rms_before']:.4g} "
                         f"({pose['rms_sigma_before']:.2f} sigma per coordinate), not fitted")
            continue
        lines.append(f"  pose {pose['index']}{tag}: RMS marker error {pose['rms_before']:.4g} -> "
                     f"{pose['rms_after']:.4g} ({pose['rms_sigma_after']:.2f} sigma per coordinate)")
    red = doc["reduced_chi2"]
    if doc["identifiable"]:
        lines.append(f"  chi^2 {doc['chi2_before']:.4g} -> {doc['chi2']:.4g} for {doc['dof']} "
                     "degrees of freedom" + (f" (reduced {red:.3g})" if red is not None else ""))
    lines += [f"  warning: {w}" for w in doc["warnings"]]
    return "\n".join(lines)
