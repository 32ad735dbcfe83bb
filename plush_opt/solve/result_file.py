"""Result files (``plush-opt-result/1``): self-contained JSON (written atomically by
:mod:`plush_opt.base.files`).

The file holds the model (rest mesh, material, pins, tendons, winches,
targets) as well as the solution, so anyone can rebuild E and O from it
with numpy alone (tests/spec_checker.py does exactly that).
"""

from __future__ import annotations

import math

from .contact_plant import ContactEquilibrium
from .equilibrium import Equilibrium
from .friction_solve import path_record, segment_table
from ..base.errors import SceneError
from ..fem import contact_report
from ..fem.contact_boundary import crossings
from ..fem.contact_friction import ContactFrictionTerm
from ..fem.model import Model
from ..fem.objective import Targets
from ..io.checker import Checker, at_index, at_key, describe, parse_json

FORMAT = "plush-opt-result/1"
# The spec names forward, reparam and bilevel; clip (the gradient loop with
# clipped bounds, the baseline) is recorded as itself (docs/problem-format.md).
METHODS = ("forward", "reparam", "clip", "bilevel")
MAX_RESULT_BYTES = 1 << 30     # a result of the largest mesh (4M triangles) is well under


def _tendon_entry(tendon, path, assembly_length, weights) -> dict:
    """One entry of ``model.tendons.list``; with an attachment radius, each
    via point's nodes and weights (``points``, in path order)."""
    entry = {"name": tendon.name, "winch": tendon.winch, "nodes": path.tolist(),
             "assembly_length": float(assembly_length), "assembly_offset": tendon.assembly_offset}
    if tendon.attachment_radius > 0:
        entry["attachment_radius"] = tendon.attachment_radius
        entry["points"] = [{"nodes": weights.indices[a:b].tolist(), "weights": weights.data[a:b].tolist()}
                           for a, b in zip(weights.indptr[:-1], weights.indptr[1:])]
    return entry


def model_dict(model: Model, targets: Targets) -> dict:
    """The spec's ``model`` section."""
    scene = model.scene
    mat = scene.material
    return {
        "rest_nodes": model.X.reshape(-1, 2).tolist(),
        "element": model.element.name,
        "triangles": model.mesh.elements.tolist(),       # 3 (P1) or 6 (P2) nodes per row
        "material": {"mu": mat.mu, "lambda": mat.lam, "thickness": mat.thickness,
                     "density": mat.density},
        "gravity": None if scene.gravity is None else list(map(float, scene.gravity)),
        "pins": {"stiffness": scene.pin_stiffness, "nodes": model.pin_nodes.tolist()},
        "tendons": {
            "stiffness": scene.tendon_stiffness,
            "smoothing": scene.tendon_smoothing,
            # assembly_length includes the tendon's assembly_offset (an extra
            # key, so a reader can tell it from the rest path length)
            "list": [_tendon_entry(t, p, a, W) for t, p, a, W in
                     zip(scene.tendons, model.tendon_paths, model.assembly_length, model.via_weights)],
        },
        "winches": [{"name": w.name, "bounds": [float(w.bounds[0]), float(w.bounds[1])],
                     "frozen": bool(f)}
                    for w, f in zip(scene.winches, scene.frozen)],
        "targets": [{"triangle": int(e), "barycentric": b.tolist(), "to": q.tolist(),
                     "weight": float(w)}
                    for e, b, q, w in zip(targets.triangles, targets.beta, targets.to, targets.weight)],
        **({"contact": contact_report.section(model.contact)} if model.contact is not None else {}),
    }


def _finite(v):
    """JSON has no inf/nan: report them as null."""
    if v is None:
        return None
    v = float(v)
    return v if math.isfinite(v) else None


def contact_block(model: Model, eq: Equilibrium) -> dict:
    """The result's ``contact`` block at ``eq`` (with friction at contacts,
    the friction of the step that reached it, and the path followed)."""
    friction = None
    if isinstance(eq, ContactEquilibrium) and eq.contact is not None:
        friction = ContactFrictionTerm(model.contact, eq.contact.lag)
    block = {**contact_report.report(model.contact, eq.x, friction),
             "free_motions": model.free_motions(eq.x, eq.contraction, () if friction is None else (friction,))}
    if isinstance(eq, ContactEquilibrium) and eq.path is not None:
        block["path"] = {"from": eq.origin, "steps": int(len(eq.path)), "steps_done": int(eq.steps_done),
                         "contractions": [{n: float(v) for n, v in zip(model.winch_names, row)}
                                          for row in eq.path]}
    return block


def crossing_of(model: Model, x, creases_only: bool = False) -> str | None:
    """Where pose ``x`` crosses itself (with ``creases_only``: creases), in
    words, in a scene whose body may (no ``contact.self``); None where it
    does not or may not."""
    return next(iter(crossings(model, [x], creases_only)), None)


def result_dict(model: Model, targets: Targets, eq: Equilibrium, *, method: str,
                converged: bool, status: str, total_s: float, solve_s: float,
                iterations: int, extra: dict | None = None) -> dict:
    """The spec's result document for one solve."""
    if method not in METHODS:
        raise ValueError(f"method: expected one of {METHODS}, got {method!r}")
    segments = segment_table(model, eq.x, eq.contraction, eq)
    # the tension at the winch (a friction tendon's winch-end segment)
    tension = [s["segment_tensions"][-1] for s in segments]
    doc = {
        "format": FORMAT,
        "problem": model.scene.name,
        "method": method,
        "converged": bool(converged),
        "status": status,
        "contractions": {n: float(c) for n, c in zip(model.winch_names, eq.contraction)},
        "nodes": eq.x.reshape(-1, 2).tolist(),
        # the spec: O at the nodes, 0 for a forward solve (whose targets, if
        # the file has any, are reported apart as targets_objective)
        "objective": 0.0 if method == "forward" else float(targets.value(eq.x)),
        "residual_norm": _finite(eq.residual_norm),
        "min_hessian_eigenvalue": _finite(eq.min_eigenvalue),
        "timing": {"total_s": float(total_s), "solve_s": float(solve_s),
                   "iterations": int(iterations)},
        "model": model_dict(model, targets),
        # extras (allowed by the spec)
        "equilibrium": {
            "backend": eq.backend, "converged": bool(eq.converged), "status": eq.status,
            "energy": _finite(eq.energy), "force_scale": _finite(eq.force_scale),
            "relative_residual": _finite(eq.relative_residual),
            "positive_definite": bool(eq.positive_definite),
            "newton_iterations": int(eq.iterations),
            "linear_solver": model.factorizer.backend,
        },
        "tendon_tension": {t.name: float(v) for t, v in zip(model.scene.tendons, tension)},
        "target_error": targets.errors(eq.x).tolist(),
        "targets_objective": float(targets.value(eq.x)),
        # the file's unit names (labels: the numbers are as the file wrote them)
        "units": model.scene.units.as_dict(),
    }
    for entry, seg, t in zip(doc["model"]["tendons"]["list"], segments, model.scene.tendons):
        entry.update(seg, friction=float(t.friction))
    if model.contact is not None:
        doc["contact"] = contact_block(model, eq)
    crossing = crossing_of(model, eq.x)
    if crossing is not None:
        doc["self_crossing"] = crossing
    record = path_record(eq, model.winch_names)
    if record is not None:
        doc["friction_path"] = record
    if extra:
        doc.update(extra)
    return doc


def control_result_dict(result, *, total_s: float | None = None, extra: dict | None = None) -> dict:
    """The spec's result document for a :class:`~plush_opt.control.result.ControlResult`."""
    stats = result.stats
    if stats.solver == "ipopt":
        details = {"bilevel": stats.details.to_dict()} if stats.details is not None else {}
    else:
        details = {"control": {"equilibrium_solves": stats.equilibrium_solves,
                               "newton_iterations": stats.newton_iterations,
                               "active_bounds": list(result.active_bounds),
                               "frozen": list(result.frozen)}}
    return result_dict(result.model, result.targets, result.equilibrium, method=result.method,
                       converged=result.converged, status=result.status,
                       total_s=stats.t_wall if total_s is None else total_s, solve_s=stats.t_wall,
                       iterations=stats.iterations,
                       extra={"reason": result.reason, **details, **(extra or {})})


class _ModelChecker(Checker):
    """The problem file's mesh checks, their keys renamed to a result file's."""

    RENAME = (("mesh.nodes", "model.rest_nodes"), ("mesh.triangles", "model.triangles"),
              ("mesh.element", "model.element"), ("mesh", "model"))

    def fail(self, path: str, message: str):
        for old, new in self.RENAME:
            if path == old or path.startswith((old + "[", old + ".")):
                path = new + path[len(old):]
                break
        super().fail(path, message.replace("mesh.triangles[", "model.triangles["))


def read_result(path) -> dict:
    """The document of a result file, checked where the package reads it
    back (``plush-opt export --result``): ``format``, ``problem``,
    ``contractions`` (winch -> finite number), ``nodes`` (finite points, one
    per rest node), ``model.element``, ``model.rest_nodes`` and
    ``model.triangles`` (a valid mesh, as a problem file's explicit mesh),
    ``model.tendons.list`` (mappings with a ``name``, and finite
    ``segment_rest_lengths`` where given), ``units`` (accepted names) where given. Anything else is one
    :class:`SceneError` line naming the file and the key; nothing is repaired."""
    from ..io.mesh_input import explicit_mesh
    from ..io.problem_file import units_section
    ck = Checker(path)
    try:
        with open(path, "rb") as fh:
            raw = fh.read(MAX_RESULT_BYTES + 1)
    except OSError as exc:
        raise SceneError(f"{path}: cannot read the result file: {exc.strerror or exc}") from None
    if len(raw) > MAX_RESULT_BYTES:
        ck.fail("", f"larger than {MAX_RESULT_BYTES} bytes: not a result file of plush-opt solve")
    doc = parse_json(raw, ck)
    if not isinstance(doc, dict):
        ck.fail("", f"expected a JSON object (a result file of plush-opt solve), got {describe(doc)}")
    ck.mapping(doc, "", tuple(doc), required=("format", "problem", "contractions", "nodes", "model"))
    if doc["format"] != FORMAT:
        ck.fail("format", f"expected {FORMAT!r}, got {describe(doc['format'])}")
    ck.name(doc["problem"], "problem")
    c = doc["contractions"]
    ck.numbers(c, "contractions", tuple(c) if isinstance(c, dict) else ())
    model = ck.mapping(doc["model"], "model", tuple(doc["model"]) if isinstance(doc["model"], dict) else (),
                       required=("element", "rest_nodes", "triangles", "tendons"))
    explicit_mesh(_ModelChecker(path), ck.string(model["element"], "model.element"), model["rest_nodes"],
                  model["triangles"])
    nodes = ck.points(doc["nodes"], "nodes", min_len=1)
    if len(nodes) != len(model["rest_nodes"]):
        ck.fail("nodes", f"{len(nodes)} points, but model.rest_nodes has {len(model['rest_nodes'])}")
    _check_tendon_entries(ck, model["tendons"])
    if doc.get("units") is not None:
        units_section(ck, doc["units"], result=True)
    return doc


def _check_tendon_entries(ck: Checker, tendons) -> None:
    ck.mapping(tendons, "model.tendons", tuple(tendons) if isinstance(tendons, dict) else (), required=("list",))
    for i, entry in enumerate(ck.seq(tendons["list"], "model.tendons.list", what="list of tendons")):
        key = at_index("model.tendons.list", i)
        ck.mapping(entry, key, tuple(entry) if isinstance(entry, dict) else (), required=("name",))
        ck.name(entry["name"], at_key(key, "name"))
        if entry.get("friction") is not None:
            ck.number(entry["friction"], at_key(key, "friction"), ge=0)
        if "segment_rest_lengths" in entry:
            rest = ck.seq(entry["segment_rest_lengths"], at_key(key, "segment_rest_lengths"), min_len=1)
            for j, r in enumerate(rest):
                ck.number(r, at_index(at_key(key, "segment_rest_lengths"), j), gt=0)
