"""Regenerate docs/robustness.md: every hard scene of problems/hard/ run with
each method, outcome, status, iterations and time.

Usage: .venv/bin/python tools/robustness_table.py [--out docs/robustness.md]

For each scene: the model is built (or refused: the row says why); forward
solves with both equilibrium backends at the contractions listed in
CONTRACTIONS (default: every winch at its upper bound); and, if the scene
has targets, method 1 (reparametrised and clipped bounds, Newton
equilibria; reparametrised with IPOPT equilibria) and the bilevel method
when plush_opt.control.bilevel exists. Every claim of convergence is
re-checked here, independently of the solver's flags: admissible pose,
relative residual within gtol, Hessian positive definite beyond round-off
(dense Cholesky of H - 10 eps |H|_inf I). A claim that fails the re-check
is reported as WRONG. The text about each scene is the header comment of
its file.
"""

from __future__ import annotations

import argparse
import ast
import datetime
import platform
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from plush_opt.control.gradient import ControlOptions, solve_control
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium
from plush_opt.base.errors import PlushError, SceneError
from plush_opt.io import load_scene
from plush_opt.fem.mesh import build_mesh
from plush_opt.fem.model import build_model
from plush_opt.fem.objective import Targets

try:
    from plush_opt.control.bilevel import BilevelOptions, solve_bilevel
except ImportError:                                   # not in this tree yet
    solve_bilevel = None

ROOT = Path(__file__).resolve().parent.parent
HARD = ROOT / "problems" / "hard"

# the hard tests' own re-check of a convergence claim: one definition
sys.path.insert(0, str(ROOT / "tests" / "hard"))
from hardlib import header, recheck  # noqa: E402
GTOL = EquilibriumOptions().gtol
CONTROL_BUDGET_S = 60.0

#: forward contractions worth a row, per scene (default: the upper bounds)
CONTRACTIONS = {
    "near_inversion": [[3.0], [6.0]],
    "buckling": [[0.5], [6.0]],
    "stiff_tendons": [[3.0, 0.0], [12.0, 0.0], [6.0, 6.0]],
    "slack_taut": [[12.0, -2.0], [6.0, 6.0]],
    "inverted_explicit": [[3.0]],
    "sliver_explicit": [[1.0]],
}


def outcome(model, eq, converged: bool) -> str:
    if converged:
        wrong = recheck(model, eq)
        return "certified" if not wrong else f"WRONG ({'; '.join(wrong)})"
    if model.admissible(eq.x):
        return "not converged"
    return "not converged (inadmissible start)"


def fmt_c(c) -> str:
    return "(" + ", ".join(f"{v:g}" for v in np.asarray(c, dtype=float)) + ")"


def rows_for(path: Path) -> list[dict]:
    name = path.stem
    rows = []

    def add(method, setting, result, status, iterations, seconds):
        rows.append({"scene": name, "method": method, "setting": setting, "outcome": result,
                     "status": status, "iterations": iterations, "seconds": seconds})

    t0 = time.perf_counter()
    try:
        scene = load_scene(path)
        mesh = build_mesh(scene)
        model = build_model(scene, mesh)
    except SceneError as exc:
        msg = str(exc)
        add("model", "", "refused before solving", msg.split(": ", 1)[1], 0, time.perf_counter() - t0)
        return rows
    targets = Targets.from_mesh(mesh, scene)

    for c in CONTRACTIONS.get(name, [model.upper.tolist()]):
        for backend in ("newton", "ipopt"):
            eq = solve_equilibrium(model, c, options=EquilibriumOptions(backend=backend))
            add(f"forward, {backend}", f"c = {fmt_c(c)}", outcome(model, eq, eq.converged),
                eq.status, eq.iterations, eq.t_wall)

    if targets.n_targets:
        runs = [("method 1 reparam, newton", ControlOptions()),
                ("method 1 clip, newton", ControlOptions(bounds="clip")),
                ("method 1 reparam, ipopt",
                 ControlOptions(equilibrium=EquilibriumOptions(backend="ipopt", eigenvalue=False)))]
        for method, options in runs:
            options = replace(options, max_time=CONTROL_BUDGET_S)
            t = time.perf_counter()
            try:
                res = solve_control(model, targets, options=options)
            except PlushError as exc:
                add(method, "targets", "refused", str(exc), 0, time.perf_counter() - t)
                continue
            wrong = ["; ".join(w) for w in (recheck(model, it.equilibrium) for it in res.history) if w]
            result = ("WRONG (an iterate: " + wrong[0] + ")") if wrong else (
                "stopped" if res.converged else "not converged")
            add(method, f"targets, c = {fmt_c(res.contraction)}", result,
                f"{res.status}; O = {res.objective:.4g}", len(res.history) - 1,
                time.perf_counter() - t)
        if solve_bilevel is not None:
            t = time.perf_counter()
            try:
                res = solve_bilevel(model, targets, scene.contraction, scene.frozen,
                                    options=BilevelOptions(max_time=CONTROL_BUDGET_S))
                add("bilevel (IPOPT)", f"targets, c = {fmt_c(res.contraction)}",
                    outcome(model, res.equilibrium, res.converged),
                    f"{res.status}; O = {res.objective:.4g}", res.stats.iterations,
                    time.perf_counter() - t)
            except PlushError as exc:
                add("bilevel (IPOPT)", "targets", "refused", str(exc), 0, time.perf_counter() - t)
    return rows


def _xfail_reason(call: ast.Call, constants: dict) -> str | None:
    for kw in call.keywords:
        if kw.arg == "reason":
            if isinstance(kw.value, ast.Constant) and isinstance(kw.value.value, str):
                return kw.value.value
            if isinstance(kw.value, ast.Name):
                return constants.get(kw.value.id)
    return None


def _is_xfail(node) -> bool:
    return (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)
            and node.func.attr == "xfail")


def test_index(folder: Path):
    """From the test sources: which tests mention each scene, and the
    strict-xfail reasons (the known defects) with their tests."""
    mentions, defects = {}, []
    for path in sorted(folder.glob("test_*.py")):
        if path.name == "test_hard_docs.py":          # tests this page, not the scenes
            continue
        src = path.read_text()
        tree = ast.parse(src)
        constants = {t.id: n.value.value for n in tree.body if isinstance(n, ast.Assign)
                     for t in n.targets if isinstance(t, ast.Name)
                     and isinstance(n.value, ast.Constant) and isinstance(n.value.value, str)}
        functions = [n for n in tree.body if isinstance(n, ast.FunctionDef)]
        for fn in functions:
            text = "\n".join(ast.get_source_segment(src, d) or "" for d in fn.decorator_list)
            text += "\n" + (ast.get_source_segment(src, fn) or "")
            if fn.name.startswith("test_"):
                mentions[fn.name] = (path.name, text)
            for node in ast.walk(fn):
                if _is_xfail(node):
                    reason = _xfail_reason(node, constants)
                    if reason is None:
                        continue
                    users = [fn.name] if fn.name.startswith("test_") else [
                        g.name for g in functions if g.name.startswith("test_")
                        and any(fn.name in (ast.get_source_segment(src, d) or "")
                                for d in g.decorator_list)]
                    for user in users:
                        defects.append((path.name, user, reason))
            for d in fn.decorator_list:
                if _is_xfail(d):
                    reason = _xfail_reason(d, constants)
                    if reason is not None:
                        defects.append((path.name, fn.name, reason))
    seen, unique = set(), []
    for item in defects:
        if item not in seen:
            seen.add(item)
            unique.append(item)
    return mentions, unique


INTRO = """\
# Robustness: hard cases and what the solvers do with them

A controller that drives motors must either give a certified answer or
say clearly why it cannot. `problems/hard/` holds small scenes, each
built around one numerical difficulty; the header comment of each file
says what makes it hard and what the right outcome is, and `tests/hard/`
checks that outcome for both equilibrium backends and the control
methods. Defects found this way are tests marked `xfail(strict=True)`
whose reason describes them; they turn into failures (XPASS) once fixed.

This page is generated by `tools/robustness_table.py`, which runs every
scene with every method and re-checks every claim of convergence
independently of the solver (admissible pose, relative residual within
`gtol`, Hessian positive definite beyond round-off). Outcomes:

- **certified**: converged, and the re-check agrees;
- **stopped** (control): the loop ended on its own criterion (targets
  reached, stationary, objective stopped decreasing), every iterate
  certified; **not converged**: it ended on a budget or a failed line
  search, every iterate certified;
- **not converged**: an equilibrium solve that says it did not converge;
  the pose it returns is admissible;
- **refused before solving**: a SceneError before any solve;
- **WRONG**: a claim the re-check does not confirm (a bug).

Iterations are Newton or IPOPT iterations for forward solves, accepted
iterates for method 1, IPOPT iterations for the bilevel method. Times are
wall-clock seconds on the machine that generated the page ({machine}, {date}) and
vary between runs; control runs are capped at {budget:g} s.
"""


def render(rows: list[dict], scenes: list[Path], seconds: float) -> str:
    """The page: ``rows`` of ``scenes``, made in ``seconds`` (wall)."""
    mentions, defects = test_index(ROOT / "tests" / "hard")
    date = datetime.datetime.now(datetime.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    out = [INTRO.format(machine=f"{platform.machine()}, Python {platform.python_version()}", date=date,
                        budget=CONTROL_BUDGET_S)]
    out.append("## Summary\n")
    out.append("| scene | method | setting | outcome | status | iterations | time (s) |")
    out.append("|---|---|---|---|---|---:|---:|")
    for r in rows:
        status = r["status"].replace("|", "/")
        out.append(f"| {r['scene']} | {r['method']} | {r['setting']} | {r['outcome']} | "
                   f"{status} | {r['iterations']} | {r['seconds']:.2f} |")
    out.append("")
    out.append("## Known defects (strict xfail tests)\n")
    if defects:
        out.append("Each of these is a test that asserts the right outcome and currently fails; "
                   "the reason is the test's own. When a defect is fixed the test passes, "
                   "pytest reports it as XPASS (a failure) and the marker is removed.\n")
        for file, test, reason in defects:
            out.append(f"- `{file}::{test}`: {reason}")
        out.append("")
    else:
        out.append("None at the time of this run.\n")
    out.append("## The scenes\n")
    for path in scenes:
        out.append(f"### {path.stem}\n")
        out.append(f"`problems/hard/{path.name}`\n")
        out.append(header(path).strip() + "\n")
        mine = [r for r in rows if r["scene"] == path.stem]
        counts = {}
        for r in mine:
            key = r["outcome"].split(" (")[0]
            counts[key] = counts.get(key, 0) + 1
        out.append("Observed in this run: " + ", ".join(f"{v} {k}" for k, v in counts.items())
                   + ".\n")
        tests = [f"`{file}::{name}`" for name, (file, text) in mentions.items()
                 if f'"{path.stem}"' in text]
        if tests:
            out.append("Tested by " + ", ".join(tests) + ".\n")
    invalid = sorted((HARD / "invalid").glob("*.yaml"))
    out.append("### invalid/\n")
    out.append(f"`problems/hard/invalid/` holds {len(invalid)} files that are wrong on purpose "
               "(zero-area triangle, node index out of range, via point or target outside the "
               "body, duplicate names, non-numeric, infinite, huge and negative values, empty "
               "lists, unknown keys, a wrong `format`, an anchor/alias pair, a pin box that "
               "misses the mesh, a contraction outside its bounds, bounds beyond the length "
               "limit, outline or hole vertices closer than the point tolerance, a mesh over "
               "the triangle cap). Each has an `# expect:` "
               "line; `tests/hard/test_hard_files.py` runs each through `plush-opt solve` "
               "and requires exit status 2, that one line on stderr (file, key, index), no "
               "traceback and no result file. The same test runs a 5 MB file, a nested alias "
               "bomb, random bytes, an empty file, a truncated file, a missing file and a "
               "directory, and a selection of the loader's own bad files in `tests/bad/`. "
               "`tests/hard/test_hard_fuzz.py` mutates the text of the shipped and hard "
               "problem files at random (hypothesis, bounded example counts): whatever does "
               "not load raises SceneError naming the file, whatever loads meshes and builds "
               "a model, and value-preserving rewrites load to the same scene.\n")
    out.append("## Regenerating\n")
    out.append(f"```sh\n.venv/bin/python tools/robustness_table.py      # this page took {seconds:.0f} s\n```\n")
    out.append("On a small machine that is busy with other work, `OPENBLAS_NUM_THREADS=1` "
               "makes both this script and `pytest tests/hard` several times faster (the dense "
               "eigen-solves and Cholesky re-checks otherwise fight over the cores).\n")
    return "\n".join(out)


PROMISES = "## Promises of the command line and the runs\n"


def keep_promises(text: str, old_path: Path) -> str:
    """The hand-written promises section of the existing page, kept before
    "## Regenerating" (it is not generated)."""
    old = old_path.read_text() if old_path.exists() else ""
    if PROMISES not in old:
        return text
    section = old[old.index(PROMISES):old.index("## Regenerating\n")]
    return text.replace("## Regenerating\n", section + "## Regenerating\n")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "robustness.md")
    parser.add_argument("--scene", action="append", default=[],
                        help="only these scenes (stems); default all")
    args = parser.parse_args(argv)
    scenes = sorted(HARD.glob("*.yaml"))
    if args.scene:
        scenes = [p for p in scenes if p.stem in args.scene]
    rows, start = [], time.perf_counter()
    for path in scenes:
        t = time.perf_counter()
        mine = rows_for(path)
        rows += mine
        print(f"{path.stem}: {len(mine)} rows, {time.perf_counter() - t:.1f} s", flush=True)
    text = keep_promises(render(rows, scenes, time.perf_counter() - start), args.out)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".tmp")
    tmp.write_text(text)
    tmp.replace(args.out)
    print(f"wrote {args.out.relative_to(ROOT) if args.out.is_relative_to(ROOT) else args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
