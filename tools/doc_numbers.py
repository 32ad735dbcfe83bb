"""Write the numbers the docs quote from the code that produces them.

    .venv/bin/python tools/doc_numbers.py            # rewrite every block
    .venv/bin/python tools/doc_numbers.py --check    # exit 1 if a cheap block is stale
    .venv/bin/python tools/doc_numbers.py --only accuracy-pick   # one block (expensive ones too)

A block in a doc is the text between ``<!-- doc-numbers: NAME -->`` and
``<!-- /doc-numbers: NAME -->``; this script computes NAME's text and puts
it there (a block may appear in several docs). Cheap blocks (seconds) are
checked by ``tests/test_doc_numbers.py``; expensive ones carry the command
and the date they were made, and ``--check`` leaves them out unless named
with ``--only``.
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import re
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
sys.path.insert(0, str(ROOT / "tools"))

from plush_opt.base.files import read_between, replace_between, write_text_atomic  # noqa: E402


def api_tour() -> str:
    """docs/api.md's four calls, with the contractions control returns."""
    import plush_opt
    p = plush_opt.load(ROOT / "problems" / "gripper.yaml")
    result = p.control(method="reparam")
    shown = ", ".join(f'"{n}": {v:.3f}...' for n, v in result.contractions.items())
    return f"""```python
import plush_opt

p = plush_opt.load("problems/gripper.yaml")   # scene -> mesh -> model -> targets, built once
eq = p.equilibrium({{"left": 10.0}})            # the pose at these contractions
eq.x, eq.converged, eq.status                 # flat pose [x0, y0, x1, y1, ...], certificate, reason

result = p.control(method="reparam")          # contractions that bring the body to the targets
result.contractions                           # {{{shown}}}
result.objective, result.x, result.reason     # O (length^2), the certified pose, why it stopped
result.save("r.json")                         # the result file of docs/problem-format.md
```"""


def friction_sweep() -> str:
    """The acceptance sweep (tools/bench_friction.py's path, one run): its steps and loop area."""
    import bench_friction as bf
    from plush_opt import load
    from plush_opt.fem.friction import FrictionModel
    from plush_opt.solve.friction_path import follow, start_state
    problem = load(bf.PROBLEM, max_area=bf.MAX_AREA)
    fm = FrictionModel(problem.model)
    start = start_state(fm)
    path = bf.sweep_path(problem)
    states = follow(fm, start, path)
    ok = sum(s.converged for s in states)
    done = "every step converged and checked" if ok == len(path) else f"{ok} of {len(path)} steps converged"
    return (f"`tools/bench_friction.py` (`problems/gripper_friction.yaml` at {problem.mesh.n_nodes:,} nodes, "
            f"grip 0 -> {bf.TO:g} -> 0 mm in {bf.STEPS} + {bf.STEPS} steps from the start state): "
            f"{done}; loop area of the bar's left tip {bf.loop_area(problem, [start] + states):.2f} mm^2. "
            "The tool also prints how many factorisations and evaluations the steps took, and their times: "
            "the counts move with the linear algebra's round-off (a via point at the edge of its friction cone "
            "sticks with one factoriser and slips with another, every state checked; the loop's area "
            "moves in its fourth digit), the times with the host: run it (the dated measurements in "
            "docs/benchmarks.md, \"Friction sweep\", were made on earlier code).")


def friction_loops(pictures: bool = False) -> str:
    """The hysteresis loops of `plush-opt sweep` on gripper_friction.yaml (and,
    with ``pictures``, docs/img/gripper_friction_loop.png from the same run)."""
    from plush_opt import load
    from plush_opt.apps.sweep import run_sweep, sweep_path
    from plush_opt.apps.sweep_plot import loop_area, plot_sweep
    p = load(ROOT / "problems" / "gripper_friction.yaml")
    _, states = run_sweep(p, sweep_path(p, "grip", 15.0, 0.0, 10, {}))
    assert all(s.converged for s in states), "the sweep did not converge"
    if pictures:
        plot_sweep(p, states, "grip", DOCS / "img" / "gripper_friction_loop.png")
    w = p.winch_names.index("grip")
    c = np.array([s.contraction[w] for s in states])
    X = p.mesh.X
    d = np.array([[np.linalg.norm(s.nodes[n] - X[n]) for n in p.mesh.point_nodes] for s in states])
    areas = [abs(loop_area(c, d[:, k])) for k in range(d.shape[1])]
    at12 = [i for i, v in enumerate(c) if abs(v - 12.0) < 1e-9]
    d_in, d_back = (float(d[i, 0]) for i in at12)
    n0 = p.mesh.point_nodes[0]
    back = float(np.linalg.norm(states[-1].nodes[n0] - states[0].nodes[n0]))
    t = p.scene.tendons[0]
    return (f"On `problems/gripper_friction.yaml` (mu = {t.friction:g}, attachment radius "
            f"{t.attachment_radius:g} mm, {p.mesh.n_nodes:,} nodes), `plush-opt sweep "
            f"problems/gripper_friction.yaml --winch grip --to 15 --back 0 --steps 10 --out S.csv --plot S.png` "
            f"(grip 0 -> 15 -> 0 in 10 + 10 steps) gives the loops of `docs/img/gripper_friction_loop.png`, areas "
            f"{', '.join(f'{a:.3g}' for a in areas)} mm^2 for its points "
            f"{', '.join(f'({q[0]:g}, {q[1]:g})' for q in p.scene.points)} (displacement against contraction; "
            f"0 without friction, `tests/test_friction.py`): the first point has moved {d_in:.2f} mm at grip 12 "
            f"on the way in against {d_back:.2f} mm on the way back, and returns to within {back:.2g} mm "
            "of where it started.")


def accuracy_pick() -> str:
    """What `--accuracy 1` picks for the gripper, and control on it (expensive)."""
    import plush_opt
    from plush_opt.io import load_scene
    from plush_opt.solve.accuracy import choose_mesh
    scene = load_scene(ROOT / "problems" / "gripper.yaml")
    mesh, report = choose_mesh(scene, 1.0)
    p = plush_opt.from_scene(dataclasses.replace(scene, element=mesh.element.name), mesh)
    result = p.control(method="reparam")
    via = report["bound_via"]
    how = "" if via in (None, report["picked"]) else (
        f" (its distance to the {report['levels'][via]['n_nodes']:,}-node {report['levels'][via]['element']} "
        "level plus that level's estimate)")
    date = datetime.date.today().isoformat()
    return (f"For the gripper at 1 mm, `--accuracy 1` picks {report['element']} with {report['nodes']:,} "
            f"nodes, bound {report['estimated_error']:.3f} mm{how}; control (reparam) on it ends at "
            f"O = {result.objective:.4g} ({result.reason}). Made by `python tools/doc_numbers.py --only "
            f"accuracy-pick` on {date}; the table below is dated history of earlier code.")


def obstacle_vertex() -> str:
    """An obstacle vertex's barrier sum against a boundary cut ever finer
    (tools/obstacle_vertex_pairs.py, its default arguments)."""
    import obstacle_vertex_pairs as ovp
    return "\n".join(ovp.arithmetic(ovp.GAP, ovp.SIZES))


def hexapod_friction() -> str:
    """Control of problems/hexapod_stand.yaml with friction at its contacts
    (docs/model.md, "Contact"): at its targets and at 18 mm up, and the
    walk of its body driven straight to a = b = 7 mm."""
    import yaml
    from plush_opt import from_scene, load
    from plush_opt.io.problem_file import scene_from_dict
    path = ROOT / "problems" / "hexapod_stand.yaml"
    up = [{"at": [-40.0, 30.5], "to": [-40.0, 48.5]}, {"at": [40.0, 30.5], "to": [40.0, 48.5]}]

    def with_friction(mu):
        doc = yaml.safe_load(path.read_text())
        doc["contact"]["friction"] = mu
        return from_scene(scene_from_dict(doc, path.name))

    def said(r):
        where = ", ".join(f"{n} = {v:.2f}" for n, v in r.contractions.items())
        how = {"max_iterations": "at its iteration limit", "stationary": "stationary"}.get(r.reason, r.reason)
        # at the iteration limit O's fourth digit is the machine's round-off (9.976 on one, 9.977 on another)
        digits = ".4g" if r.reason == "stationary" else ".3g"
        return f"O = {r.objective:{digits}} mm^2 ({where} mm; {how})"

    plain, p = load(path), with_friction(0.5)
    at_file, high = p.control(), p.with_targets(up).control()
    first, second = at_file.history[2], at_file.history[3]
    others = {mu: with_friction(mu).control() for mu in (0.3, 0.2)}
    walked, still = p.equilibrium({"a": 7.0, "b": 7.0}), plain.equilibrium({"a": 7.0, "b": 7.0})
    x, x0 = p.targets.y(walked.x)[:, 0], plain.targets.y(still.x)[:, 0]
    return (f"With the targets 18 mm up (the file's until 2026-12-06, `tests/test_contact_friction_history.py`) "
            f"the loop ends at {said(high)} (frictionless: O = {plain.with_targets(up).control().objective:.3g}). "
            f"With the file's targets, 8 mm up, it ends at {said(at_file)}: from rest it reaches "
            f"a = {first.contraction[0]:.2f}, b = {first.contraction[1]:.2f} (O = {first.objective:.3g}), and its "
            f"next step, Gauss-Newton on the sensitivities of that friction state, goes asymmetric (a = "
            f"{second.contraction[0]:.2f}, b = {second.contraction[1]:.2f}); mu = 0.3: {said(others[0.3])}; "
            f"mu = 0.2: {said(others[0.2])}; frictionless: O = {plain.control().objective:.3g}. Why: the body "
            f"walks. With both feet sliding outwards their friction forces differ by the mesh's slight asymmetry, "
            f"so in each step one foot sticks and the other slides for both; driven from rest to a = b = 7 mm the "
            f"body ends {np.mean(x - x0):.1f} mm further in x (the targets' points at x = "
            f"{x[0]:.2f} and {x[1]:.2f} instead of {x0[0]:.2f} and {x0[1]:.2f}), and the targets, fixed in space, "
            f"are out of reach of equal contractions.")


BLOCKS = {"api-tour": (api_tour, True), "friction-sweep": (friction_sweep, True),
          "friction-loops": (friction_loops, True), "accuracy-pick": (accuracy_pick, False),
          "obstacle-vertex": (obstacle_vertex, True), "hexapod-friction": (hexapod_friction, True)}


#: Blocks whose numbers round-off moves (a via point within stick_tol of its
#: friction cone sticks with one factoriser and slips with another; both
#: states pass the state check): --check takes their words and whole
#: numbers exactly and their decimals within ROUNDOFF_RTOL (the friction
#: sweep's loop area, printed to two decimals, moved in its fourth digit
#: between QDLDL and CHOLMOD on 2026-12-05; the hexapod's control loop with
#: friction ends at its iteration limit, where its O, printed to three
#: digits, moved in the fourth between two machines).
ROUNDOFF_BLOCKS = ("friction-sweep", "hexapod-friction")
ROUNDOFF_RTOL = 1e-3
_NUMBER = re.compile(r"\d[\d,]*(?:\.\d+)?")


def _same_up_to_roundoff(old: str, new: str) -> bool:
    """Whether block texts ``old`` and ``new`` differ only in numbers that
    round-off moves (ROUNDOFF_RTOL)."""
    if _NUMBER.sub("#", old) != _NUMBER.sub("#", new):
        return False
    for a, b in zip(_NUMBER.finditer(old), _NUMBER.finditer(new)):
        x, y = float(a.group().replace(",", "")), float(b.group().replace(",", ""))
        if "." in a.group() + b.group():
            if abs(x - y) > ROUNDOFF_RTOL * max(abs(x), abs(y)):
                return False
        elif x != y:
            return False
    return True


#: Blocks whose function also draws the picture the text describes (not with --check).
PICTURES = ("friction-loops",)


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- doc-numbers: {name} -->", f"<!-- /doc-numbers: {name} -->"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="exit 1 if a block is stale (cheap blocks only)")
    ap.add_argument("--only", choices=sorted(BLOCKS), action="append", help="these blocks only")
    args = ap.parse_args(argv)
    names = args.only or [n for n, (_, cheap) in BLOCKS.items() if cheap or not args.check]
    docs = {path: path.read_text() for path in sorted(DOCS.glob("*.md"))}
    stale = []
    for name in names:
        begin, end = _markers(name)
        found = [path for path, text in docs.items() if begin in text and end in text]
        if not found:
            print(f"no block {name!r} in docs/", file=sys.stderr)
            return 2
        make = BLOCKS[name][0]
        text = make(pictures=not args.check) if name in PICTURES else make()
        for path in found:
            new = replace_between(docs[path], begin, end, text, str(path))
            if args.check and name in ROUNDOFF_BLOCKS and _same_up_to_roundoff(read_between(docs[path], begin, end), text):
                continue
            if new != docs[path]:
                stale.append(f"{path.relative_to(ROOT)}: {name}")
                docs[path] = new
    if args.check:
        for s in stale:
            print(f"stale: {s} (run tools/doc_numbers.py)")
        return 1 if stale else 0
    for path, text in docs.items():
        if path.read_text() != text:
            write_text_atomic(path, text)
            print(f"wrote {path.relative_to(ROOT)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
