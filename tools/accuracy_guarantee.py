"""Check what ``solve --accuracy TOL`` guarantees, against fine P2 solves, and what it costs.

Usage: python tools/accuracy_guarantee.py [SCENE ...] [--tols 1 0.25 0.05] [--jobs 1]
       [--work DIR] [--out FILE.md] [--timeout 900] [--force] [--write-doc]

SCENE is a problem file, optionally with the contractions the solve starts
from (a forward solve: where it solves): ``path.yaml@name=value,name=value``.
Default: every file of problems/ and the two scenes of tests/data.

For each scene and tolerance (one row, run in its own process, at most
``--timeout`` seconds; the rows run as a batch, plush_opt.batch, ``--jobs``):

1. ``plush-opt solve SCENE --accuracy TOL`` in that process, after its
   imports: its exit code, what it claims at the returned contractions
   (``accuracy.at_result``: met, estimated error) and its CPU seconds.
2. An independent reference at the returned contractions: the P2 levels
   of the sweep's family A (a graded mesh refined uniformly) with at least
   the returned mesh's nodes solved afresh there (the first from the
   returned pose carried over, each finer one from the one before: the same
   branch of equilibria; none coarser than the answer, which near a fold
   can settle in another state; carried admissibly,
   plush_opt.solve.accuracy_carry.carried_start, and a pose that does not
   carry over so is not started from (the next is); a level that ends more
   than TOL from the one before is solved again from the same start by a
   Newton homotopy that keeps its start's state (relieved_equilibrium),
   then from the answer carried over, by Newton and the homotopy (after a
   level the homotopy alone found, the homotopy first), and the nearest
   kept: where several stable states hold at the returned contractions,
   the reference is the fine solve in the answer's state, `same_state`),
   refined until it has at
   least REF_NODES_FACTOR x the returned mesh's nodes and its own estimated
   error (the tail after it, at its observed rate) is at most REF_FRACTION x
   TOL, or until REF_MAX_NODES. Where the pose depends on the path
   (friction), each level replays the path the returned pose was reached
   by (its ``friction_path``) instead, from the start: no level carries
   another's pose, so the levels coarser than the answer count towards the
   reference's own estimate too (the answer's own level, the one before it
   and the one after it estimate the last; a jump is still only one
   between levels at least as fine as the answer).
3. The returned pose's error against it: the largest distance of the
   compared points (the targets, else the tendon stoppers and the scene's
   points, as docs/accuracy.md defines them; what the guarantee covers), and
   the largest distance over the returned mesh's nodes (the reference's
   displacement interpolated there; reported, not guaranteed).
4. The cost: the CPU seconds of the ``--accuracy`` run against a plain
   solve (the same command without ``--accuracy``) on the mesh it returned,
   plus one plain solve on each level it solved (those solved at the
   returned contractions and the P2 levels a P1-based claim was checked
   against included): a forward solve at the returned contractions, the
   pose each level gives the estimate there (with friction: the plant's
   fresh path to them): the ratio.

Each row is kept as JSON in ``--work`` (default out/accuracy_guarantee): a
second run reuses the rows there unless ``--force``. The table (markdown,
and CSV beside it) goes to ``--out``; ``--write-doc`` also rewrites the
block of docs/accuracy.md between ``<!-- accuracy-guarantee -->`` and
``<!-- /accuracy-guarantee -->`` with it, the command and the date.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import dataclasses
import datetime
import functools
import io
import json
import math
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "accuracy.md"
DEFAULT_SCENES = [str(p.relative_to(ROOT)) for p in sorted((ROOT / "problems").glob("*.yaml"))] + \
    ["tests/data/crescent.yaml", "tests/data/thin_strip.yaml@pull=30"]
#: the reference has at least this many times the returned mesh's nodes (one uniform refinement
#: has about 4x; a little less on a curved outline)
REF_NODES_FACTOR = 3.5
#: ... and its own estimated error at most this fraction of TOL (errors against it are that uncertain)
REF_FRACTION = 0.1
#: ... or it stops at this many nodes (memory and time: a P2 solve of that size takes a minute)
REF_MAX_NODES = 400_000
#: the time a row may take at most by default (seconds): longer rows are recorded as such
TIMEOUT = 900.0
#: the cost the guarantee allows: --accuracy within about this many times a plain solve plus its levels
COST_FACTOR = 5.0
FIELDS = ("scene", "tol", "exit", "met", "estimate", "element", "nodes", "resolves", "error_points",
          "error_nodes", "ref_nodes", "ref_error", "cpu_accuracy_s", "cpu_plain_s", "cpu_levels_s",
          "n_levels", "ratio", "wall_s", "floor_certified", "verdict", "note")


def parse_scene(spec: str) -> tuple[Path, list[str]]:
    """``path.yaml@a=1,b=2`` -> (path, ["--contraction", "a=1", ...])."""
    path, _, given = spec.partition("@")
    args = []
    for pair in filter(None, given.split(",")):
        args += ["--contraction", pair]
    return Path(path), args


# -- one row, in its own process -------------------------------------------------------------------

def reference(scene, contraction, mesh_returned, x_returned, nodes_returned: int, tol: float, waypoints=None,
              heard=None):
    """The P2 reference at ``contraction``: (mesh, pose, own estimated error
    or None, its jumps, its crease or None). See the module's docstring,
    step 2. Its crease: (nodes, where) of the first level whose pose crosses
    itself in a crease (a scene without self-contact, the product's rule
    for a fold, ``result_file.crossing_of``): that fine solve passes
    through itself, so it is no reference, and the levels stop there. Its jumps:
    (coarser nodes, finer nodes, distance at the points) of consecutive
    levels more than ``tol`` apart, all at least as fine as the answer's:
    there the reference left one state for another (several stable ones at
    ``contraction``), or is far from converged; its own estimate rests on
    its last levels alone. Where the
    pose depends on the path (friction), each level replays the returned
    path instead, from the start, the levels coarser than the answer
    included (``waypoints``: the control run's start and iterates; None:
    a forward solve's fresh path; plush_opt.solve.accuracy_path.replay).
    ``heard(nodes, distance)``, if given, hears of each level solved (the
    distance at the points to the level before it, or None)."""
    from plush_opt.solve.accuracy_path import replay
    from plush_opt.solve.plant import make_plant, path_dependent
    from plush_opt.fem.mesh import build_mesh
    from plush_opt.fem.model import build_model
    from plush_opt.fem.objective import Targets
    from plush_opt.solve.accuracy import EXPECTED_ORDER, GRADED, MAX_RATIO, SAFETY, base_area, probe_points
    from plush_opt.base.errors import SceneError
    from plush_opt.solve.result_file import crossing_of
    s = dataclasses.replace(scene, element="P2")
    points, _ = probe_points(scene)
    area = base_area(scene) * 16.0          # the sweep's family A (plush_opt.solve.accuracy.COARSEST)
    floor_ratio = 0.25 ** (EXPECTED_ORDER["P2"] / 2.0)
    prev_mesh, prev_x, ys, diffs = mesh_returned, x_returned, [], []
    mesh = x = None
    own = None
    jumps = []
    replayed = path_dependent(scene)
    relieved = False                # whether the level before was reached by the homotopy alone
    for r in range(8):
        m = build_mesh(s, max_area=area, graded=GRADED, refinements=r, announce=False)
        if m.n_nodes > REF_MAX_NODES:
            break
        if m.n_nodes < nodes_returned and not replayed:
            # coarser than the returned mesh: near a fold such a level can settle in another
            # stable state from the answer, which the finer levels would then follow (a replayed
            # path starts each level afresh: its coarser levels count towards the own estimate)
            continue
        model = build_model(s, m)
        at = Targets.at_points(m, points, points)
        if replayed:
            eq = replay(make_plant(model), waypoints, contraction)
        else:
            # (the level before at the points: the last level's, or the answer's before the first)
            y_prev = ys[-1] if ys else Targets.at_points(mesh_returned, points, points).y(x_returned)
            sources = [(prev_mesh, prev_x)] + ([(mesh_returned, x_returned)] if prev_mesh is not mesh_returned else [])
            eq, relieved = same_state(model, contraction, sources, at.y, y_prev, tol, relieved)
        if not eq.converged and m.n_nodes < nodes_returned:
            # (a coarser level only adds to the own estimate: without it, the levels from the answer's)
            print(f"reference: P2 {m.n_nodes:,} nodes not converged ({eq.status}): left out",
                  file=sys.stderr, flush=True)
            ys, diffs = [], []
            continue
        if not eq.converged:
            raise SceneError(f"reference: no certified P2 equilibrium on {m.n_nodes} nodes: {eq.status}")
        prev_nodes = mesh.n_nodes if mesh is not None else None
        mesh, x = m, eq.x
        print(f"reference: P2 {m.n_nodes:,} nodes solved", file=sys.stderr, flush=True)
        ys.append(at.y(x))
        prev_mesh, prev_x = m, x
        if len(ys) >= 2:
            diffs.append(float(np.linalg.norm(ys[-1] - ys[-2], axis=-1).max()))
            if diffs[-1] > tol and prev_nodes >= nodes_returned:
                jumps.append((prev_nodes, m.n_nodes, diffs[-1]))
        if heard is not None:
            heard(m.n_nodes, diffs[-1] if len(ys) >= 2 else None)
        where = crossing_of(model, x, creases_only=True)
        if where is not None:
            print(f"reference: P2 {m.n_nodes:,} nodes crosses itself: {where}", file=sys.stderr, flush=True)
            return mesh, x, None, jumps, (m.n_nodes, where)
        if len(diffs) >= 2 and diffs[-2] > 0:
            q = max(diffs[-1] / diffs[-2], floor_ratio)
            own = SAFETY * q * diffs[-1] / (1.0 - q) if q < MAX_RATIO else None
        if m.n_nodes >= REF_NODES_FACTOR * nodes_returned and own is not None and own <= REF_FRACTION * tol:
            break
    return mesh, x, own, jumps, None


def same_state(model, contraction, sources, y_of, y_prev, tol: float, relieved: bool = False):
    """A reference level's equilibrium at ``contraction`` in the state of
    the level before (several stable states can hold an object at the same
    contractions, and Newton from a carried pose can walk from one to
    another: docs/notes/accuracy-measurements.md, gripper_object at
    ``TOL`` 1). ``sources``: (mesh,
    flat pose) pairs, the level before first, then the answer; each is
    carried over admissibly (a P2 pose carried as it is can invert an
    element or cross a contact, and equilibrium_at would then start from
    rest, in another state) and solved from, the next only while none has
    stayed within ``tol`` of ``y_prev`` (the level before at the compared
    points, ``y_of(x)`` this level's), each by Newton and, where that ends
    farther, again by the Newton homotopy that keeps its start's state
    (plush_opt.solve.accuracy_carry.relieved_equilibrium); with
    ``relieved`` (the level before needed it: Newton walked there) each
    start by the homotopy first. Returns (the first that stayed, else the
    converged one nearest ``y_prev``, its jump then reported, else the
    first; whether the homotopy found it). A source that carries over
    admissibly by neither interpolation (an element of this level inverted:
    the source's pose is nearly creased there) is not solved from (from
    rest instead, Newton walks the whole way and can reach another state);
    only where no source carries over is the level solved from rest (by
    continuation, ``equilibrium_at``)."""
    from plush_opt.solve.accuracy import LEVEL_OPTIONS, carried_start, equilibrium_at
    from plush_opt.solve.accuracy_carry import relieved_equilibrium, transfer_pose_piecewise_linear
    found, starts = [], []
    for i, (m, x) in enumerate(sources):
        x0, source = carried_start(model, [(m, x)]), "the level before" if i == 0 else "the answer"
        if x0 is None:
            why = model.violation(transfer_pose_piecewise_linear(m, x, model.mesh))
            print(f"reference: P2 {model.mesh.n_nodes:,} nodes: the pose of {source} does not carry over "
                  f"admissibly ({why}): not solved from", file=sys.stderr, flush=True)
        else:
            starts.append((x0, source))
    starts = starts or [(None, "rest")]
    order = ("homotopy", "newton") if relieved else ("newton", "homotopy")
    attempts = [(x0, how, source) for x0, source in starts for how in (order if x0 is not None else ("newton",))]
    for k, (x0, how, _) in enumerate(attempts):
        eq = equilibrium_at(model, contraction, x0, LEVEL_OPTIONS) if how == "newton" else \
            relieved_equilibrium(model, contraction, x0, LEVEL_OPTIONS)
        d = float(np.linalg.norm(y_of(eq.x) - y_prev, axis=-1).max()) if eq.converged else math.inf
        if d <= tol:
            return eq, how == "homotopy"
        found.append((d, eq, how))
        if k + 1 < len(attempts):
            print(f"reference: P2 {model.mesh.n_nodes:,} nodes: {d:.3g} from the level before ({how}); "
                  "solving again: {1} from {2}".format(*attempts[k + 1]), file=sys.stderr, flush=True)
    d, eq, how = min(found, key=lambda f: f[0])
    return (eq, how == "homotopy") if math.isfinite(d) else (found[0][1], found[0][2] == "homotopy")


def plain_cost(scene, element: str, max_area: float, graded: bool, refinements: int, given, method: str):
    """CPU seconds of a plain solve on one mesh (meshing, the model, the
    solve: ``method`` from the contractions ``given``), and the mesh."""
    from plush_opt.apps.solve_command import solve_loaded
    from plush_opt.fem.mesh import build_mesh
    from plush_opt.problem import from_scene
    s = dataclasses.replace(scene, element=element)
    t0 = time.process_time()
    mesh = build_mesh(s, max_area=max_area, graded=graded, refinements=refinements, announce=False)
    solve_loaded(from_scene(s, mesh), given, method)
    return time.process_time() - t0, mesh


def count_floor_certified() -> list:
    """From now on, count the solves in this process that the round-off
    floor certified (stalled above gtol, converged by
    plush_opt.solve.certificate.at_roundoff_floor): returns a one-element
    list holding the count so far."""
    import plush_opt.solve.equilibrium as equilibrium
    real, count = equilibrium.at_roundoff_floor, [0]

    def counted(model, eq, options):
        out = real(model, eq, options)
        count[0] += out.converged and not eq.converged
        return out
    equilibrium.at_roundoff_floor = counted
    return count


def levels_solved(mesh_accuracy: dict) -> list[dict]:
    """Every mesh level the run solved, once each (element, max_area,
    refinements): the sweep's, those solved at the returned contractions
    (a sweep gone on there replaces the report's levels) and the P2 levels
    a P1-based claim was checked against."""
    rows = list(mesh_accuracy.get("levels", []))
    for r in mesh_accuracy.get("at_result", []):
        rows += r.get("levels", []) + (r.get("cross_check") or {}).get("levels", [])
    return list({(lv["element"], lv["max_area"], lv["refinements"]): lv for lv in rows}.values())


def scene_label(path: Path, contraction_args: list[str]) -> str:
    """A row's scene as the table names it: the file's name, and the given contractions."""
    return path.name + ("" if not contraction_args else "@" + ",".join(contraction_args[1::2]))


def run_row(path: Path, contraction_args: list[str], tol: float, partial=None) -> dict:
    """One row (the module's docstring, steps 1-4), in this process;
    ``partial(row, phase)``, if given, hears the row so far before each
    later phase (what a row stopped by its timeout still knows)."""
    partial = partial or (lambda row, phase: None)
    import tempfile
    from plush_opt.apps.cli import main as cli
    from plush_opt.fem.objective import Targets
    from plush_opt.io import load_scene
    from plush_opt.solve.accuracy import probe_points, transfer_pose
    row = {"scene": scene_label(path, contraction_args), "tol": tol}
    floor = count_floor_certified()
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "result.json"
        t0, w0 = time.process_time(), time.perf_counter()
        said = io.StringIO()
        with contextlib.redirect_stderr(said):
            code = cli(["-q", "solve", str(path), "--accuracy", f"{tol:g}", "--out", str(out), *contraction_args])
        row["cpu_accuracy_s"], row["wall_s"] = time.process_time() - t0, time.perf_counter() - w0
        row["exit"] = code
        print(f"--accuracy {tol:g}: exit {code}, {row['cpu_accuracy_s']:.1f} CPU s", file=sys.stderr, flush=True)
        row["floor_certified"] = floor[0]       # the --accuracy run's solves only
        if not out.exists():
            line = (said.getvalue().strip().splitlines() or ["no result written"])[-1]
            refused = code == 2 and "--accuracy" in line
            row["verdict"], row["note"] = ("refused" if refused else "NO"), line.removeprefix("plush-opt: ")
            return row
        doc = json.loads(out.read_text())
    acc = doc.get("accuracy", {})
    at = acc.get("at_result") or {}
    row.update(met=at.get("met"), estimate=at.get("estimated_error"), element=acc.get("element"),
               nodes=acc.get("nodes"), resolves=at.get("resolves"), fold=at.get("crosses_itself"))
    partial(row, "the plain solves")
    levels = levels_solved(doc["mesh_accuracy"])
    row["n_levels"] = len(levels)
    scene = load_scene(path)
    given = [(a.split("=")[0], float(a.split("=")[1])) for a in contraction_args[1::2]]
    # the plain solves: the same command without --accuracy on the returned mesh, and on each level
    # it solved a forward solve at the returned contractions (mesh, model and solve each): a level's
    # solve where the estimate is made (the file's contractions, often rest, cost next to nothing)
    returned = list(doc["contractions"].items())
    row["cpu_levels_s"] = sum(plain_cost(scene, lv["element"], lv["max_area"], acc["graded"], lv["refinements"],
                                         returned, "forward")[0] for lv in levels)
    row["cpu_plain_s"], mesh = plain_cost(scene, acc["element"], acc["max_area"], acc["graded"],
                                          acc["refinements"] or 0, given, doc["method"])
    x = np.asarray(doc["nodes"], dtype=np.float64).reshape(-1)
    if mesh.n_nodes != len(doc["nodes"]):
        row["verdict"], row["note"] = "NO", f"the accuracy block rebuilds {mesh.n_nodes} nodes, not {len(doc['nodes'])}"
        return row
    names = [w.name for w in scene.winches]
    c = np.array([doc["contractions"][n] for n in names])
    row["ratio"] = row["cpu_accuracy_s"] / (row["cpu_plain_s"] + row["cpu_levels_s"])
    if row["fold"] is not None:        # folded through itself there: no converged answer to refer to
        row["verdict"], row["note"] = verdict(row)
        return row
    # the reference at the returned contractions
    partial(row, "the reference")
    # friction: the reference replays the path the returned pose was reached by (its friction_path)
    waypoints = None if doc["method"] == "forward" or "friction_path" not in doc else \
        np.array([[row[n] for n in names] for row in doc["friction_path"]["contractions"]])
    row["ref_levels"] = []

    def heard(nodes, distance):            # (a row stopped in its reference says how far it got)
        row["ref_levels"].append([nodes, distance])
        partial(row, "the reference")

    ref_mesh, x_ref, own, jumps, crease = reference(scene, c, mesh, x, mesh.n_nodes, tol, waypoints, heard)
    row["ref_jumps"] = [list(j) for j in jumps]
    if crease is not None:             # (the fine solve passes through itself: nothing to compare with)
        row["ref_crease"] = {"nodes": crease[0], "where": crease[1]}
        row["verdict"], row["note"] = verdict(row)
        return row
    points, _ = probe_points(scene)
    y = Targets.at_points(mesh, points, points).y(x)
    y_ref = Targets.at_points(ref_mesh, points, points).y(x_ref)
    row["error_points"] = float(np.linalg.norm(y - y_ref, axis=-1).max())
    carried = transfer_pose(ref_mesh, x_ref, mesh)
    row["error_nodes"] = float(np.linalg.norm((x - carried).reshape(-1, 2), axis=-1).max())
    row["ref_nodes"], row["ref_error"] = ref_mesh.n_nodes, own
    row["verdict"], row["note"] = verdict(row)
    return row


def reference_so_far(row: dict) -> str:
    """The reference levels a stopped row had solved, in words ("" for none):
    their P2 nodes and each one's distance at the points to the one before."""
    levels = row.get("ref_levels") or []
    if not levels:
        return ""
    said = [f"{n:,}" + ("" if d is None else f" ({d:.3g} from the one before)") for n, d in levels]
    return " (its P2 levels solved: " + ", ".join(said) + ")"


def known_before_the_reference(row: dict) -> list[str]:
    """What already rules a row out before its reference is solved (its
    exit code, no claim, its cost): said first where the row is stopped."""
    why = [f"exit {row['exit']}"] if row.get("exit") not in (None, 0) else []
    if row.get("met") is False:
        why.append("not met at the returned contractions")
    if row.get("ratio") is not None and row["ratio"] > COST_FACTOR:
        why.append(f"cost above {COST_FACTOR:g}x")
    return why


def verdict(row: dict) -> tuple[str, str]:
    """"yes" when every part of the guarantee holds (exit 0, met, within TOL
    of the reference, cost within COST_FACTOR), else "NO" and why."""
    why = []
    if row["exit"] != 0:
        why.append(f"exit {row['exit']}")
    if not row.get("met"):
        why.append("not met at the returned contractions")
    if row.get("fold") is not None:
        why.append(f"the body crosses itself at the returned contractions ({row['fold']['element']} level of "
                   f"{row['fold']['nodes']:,} nodes): no converged answer, no reference")
    if row.get("error_points") is not None and row["error_points"] > row["tol"]:
        why.append("error above TOL")
    if row.get("ref_crease") is not None:
        why.append(f"the reference crosses itself at the returned contractions (P2 level of "
                   f"{row['ref_crease']['nodes']:,} nodes, {row['ref_crease']['where']}): no reference")
    if row.get("ref_error") is None and row.get("fold") is None and row.get("ref_crease") is None:
        why.append("reference's own error unknown")
    elif row.get("error_points") is not None and row["error_points"] + row["ref_error"] > row["tol"] >= \
            row["error_points"]:
        why.append("within TOL only up to the reference's own error")
    if row.get("ratio") is not None and row["ratio"] > COST_FACTOR:
        why.append(f"cost above {COST_FACTOR:g}x")
    for coarse, fine, distance in row.get("ref_jumps") or ():
        why.append(f"the reference moved {distance:.3g} between its levels of {coarse:,} and {fine:,} nodes "
                   "(another state?)")
    return ("yes" if not why else "NO"), "; ".join(why)


def row_main(argv) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--row", required=True)
    ap.add_argument("--tol", type=float, required=True)
    ap.add_argument("--to", type=Path, required=True)
    args = ap.parse_args(argv)
    path, cargs = parse_scene(args.row)
    from plush_opt.base.files import write_json_atomic
    partial_to = args.to.with_suffix(".partial")
    row = run_row(path, cargs, args.tol, lambda row, phase: write_json_atomic(partial_to, {**row, "phase": phase}))
    write_json_atomic(args.to, row)
    partial_to.unlink(missing_ok=True)
    return 0


# -- the batch -------------------------------------------------------------------------------------

def row_file(work: Path, spec: str, tol: float) -> Path:
    name = re.sub(r"[^A-Za-z0-9_.=-]+", "_", Path(spec.partition("@")[0]).stem + "_" + spec.partition("@")[2])
    return work / f"{name.strip('_')}_tol{tol:g}.json"


def launch(job: tuple, timeout: float) -> dict:
    """One row in a process of its own (``job``: scene spec, TOL, row file),
    ended after ``timeout`` seconds; returns the row."""
    spec, tol, to = job
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, __file__, "--row", spec, "--tol", f"{tol:g}", "--to", str(to)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        _, err = proc.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()
        part = to.with_suffix(".partial")
        row = json.loads(part.read_text()) if part.exists() else {"scene": scene_label(*parse_scene(spec)), "tol": tol}
        phase = row.pop("phase", "the --accuracy run")
        row.update(verdict="NO", note="; ".join(known_before_the_reference(row)
                                                 + [f"not finished within {timeout:.0f} s: stopped in {phase}"
                                                    + reference_so_far(row)]))
        if "wall_s" not in row:
            row["wall_s"] = time.perf_counter() - t0
        from plush_opt.base.files import write_json_atomic
        write_json_atomic(to, row)
        return row
    if proc.returncode != 0 or not to.exists():
        from plush_opt.base.files import write_text_atomic
        write_text_atomic(failed_file(to), err)
        return failed_row(spec, tol, to)
    return json.loads(to.read_text())


def failed_file(to: Path) -> Path:
    """Where a row whose process failed keeps its error output."""
    return to.with_suffix(".failed")


def failed_row(spec: str, tol: float, to: Path) -> dict:
    """The row of a process that ended without its row file: NO, and the
    last line of its error output (kept in :func:`failed_file`)."""
    err = failed_file(to).read_text() if failed_file(to).exists() else ""
    last = (err.strip().splitlines() or ["no output"])[-1]
    return {"scene": spec, "tol": tol, "verdict": "NO",
            "note": f"the row failed: {last} (its output: {failed_file(to).name})"}


def fmt(v, spec=".3g") -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return "inf" if math.isinf(v) else format(v, spec)
    return str(v)


def table(rows: list[dict]) -> str:
    head = ("| scene | TOL | exit | met (claimed) | estimate | returned mesh | error at the points | "
            "max error over nodes | reference (P2 nodes, own error) | CPU s: --accuracy / plain + levels (n) "
            "| ratio | solves certified at the round-off floor | guarantee holds |")
    out = [head, "|" + "---|" * 13]
    for r in rows:
        mesh = "-" if r.get("element") is None else f"{r['element']} {r['nodes']:,}" + (
            f" (solved again {r['resolves']}x)" if r.get("resolves") else "")
        ref = "-" if r.get("ref_nodes") is None else f"{r['ref_nodes']:,}, {fmt(r.get('ref_error'), '.2g')}"
        cost = "-" if r.get("cpu_plain_s") is None else (
            f"{r['cpu_accuracy_s']:.1f} / {r['cpu_plain_s']:.2f} + {r['cpu_levels_s']:.2f} ({r['n_levels']})")
        holds = r["verdict"] + ("" if not r.get("note") else f": {r['note']}")
        out.append(f"| {Path(r['scene']).name.replace(' @', '@')} | {fmt(r['tol'], 'g')} | {fmt(r.get('exit'))} | "
                   f"{fmt(r.get('met'))} | {fmt(r.get('estimate'))} | {mesh} | {fmt(r.get('error_points'))} | "
                   f"{fmt(r.get('error_nodes'))} | {ref} | {cost} | {fmt(r.get('ratio'), '.2f')} | "
                   f"{fmt(r.get('floor_certified'))} | {holds} |")
    return "\n".join(out)


def write_doc(text: str) -> None:
    from plush_opt.base.files import rewrite_block
    try:
        rewrite_block(DOC, "<!-- accuracy-guarantee -->", "<!-- /accuracy-guarantee -->", text)
    except ValueError as exc:
        raise SystemExit(str(exc)) from None


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if "--row" in argv:
        return row_main(argv)
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=DEFAULT_SCENES)
    ap.add_argument("--tols", nargs="+", type=float, default=[1.0, 0.25, 0.05])
    ap.add_argument("--jobs", "-j", type=int, default=1, help="rows at once (default 1)")
    ap.add_argument("--work", type=Path, default=ROOT / "out" / "accuracy_guarantee",
                    help="folder of the rows' JSON (kept: a second run reuses them)")
    ap.add_argument("--out", type=Path, default=None, help="markdown table (a .csv beside it)")
    ap.add_argument("--timeout", type=float, default=TIMEOUT, help="seconds a row may take (then stopped)")
    ap.add_argument("--force", action="store_true", help="run every row again")
    ap.add_argument("--write-doc", action="store_true", help="rewrite the block of docs/accuracy.md")
    ap.add_argument("--no-run", action="store_true",
                    help="run nothing: the table of the rows in --work (a row not there: not run)")
    args = ap.parse_args(argv)
    from plush_opt.batch import run_batch
    from plush_opt.batch.progress import Progress
    from plush_opt.base.files import write_text_atomic
    args.work.mkdir(parents=True, exist_ok=True)
    # the cheap rows first: the largest tolerance first, the scenes in the order given
    jobs = [(spec, tol, row_file(args.work, spec, tol)) for tol in sorted(args.tols, reverse=True)
            for spec in args.scenes]
    todo = [] if args.no_run else [j for j in jobs if args.force or not j[2].exists()]
    if todo:
        batch = run_batch(functools.partial(launch, timeout=args.timeout), todo, jobs=args.jobs,
                          progress=Progress("accuracy_guarantee", lambda i: f"{todo[i][0]} TOL {todo[i][1]:g}"))
        batch.raise_if_interrupted()
    rows = []
    for spec, tol, to in sorted(jobs, key=lambda j: (args.scenes.index(j[0]), -j[1])):
        if to.exists():
            row = json.loads(to.read_text())
        elif failed_file(to).exists():
            row = failed_row(spec, tol, to)
        else:
            row = {"scene": spec, "tol": tol, "verdict": "NO", "note": "not run" if args.no_run else
                   "the row failed (no row file)"}
        rows.append(row)            # (a stopped row's file has what it knew: launch)
    date = datetime.date.today().isoformat()
    scenes = "" if args.scenes == DEFAULT_SCENES else " " + " ".join(args.scenes)
    text = (f"Made by `python tools/accuracy_guarantee.py{scenes} --tols {' '.join(f'{t:g}' for t in args.tols)}"
            f"` on {date}: the guarantee holds in {sum(r['verdict'] == 'yes' for r in rows)} of "
            f"{sum(r['verdict'] != 'refused' for r in rows)} rows"
            + (f" ({sum(r['verdict'] == 'refused' for r in rows)} more refused, one line each)"
               if any(r["verdict"] == "refused" for r in rows) else "") + ".\n\n"
            + table(rows))
    print(text)
    if args.out:
        write_text_atomic(args.out, text + "\n")
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        w.writerows(rows)
        write_text_atomic(args.out.with_suffix(".csv"), buf.getvalue())
    if args.write_doc:
        write_doc(text)
    return 0 if all(r["verdict"] in ("yes", "refused") for r in rows) else 1


if __name__ == "__main__":
    sys.exit(main())
