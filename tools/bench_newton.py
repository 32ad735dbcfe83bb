"""What the factorisation savings buy: the forward solve from rest and the
control loop with and without them, interleaved in one run (CPU times, one
BLAS thread).

    OPENBLAS_NUM_THREADS=1 python tools/bench_newton.py --nodes 1000 10000 --repeats 3
    OPENBLAS_NUM_THREADS=1 python tools/bench_newton.py --nodes 30000 --no-control --variants refresh now

Variants (module constants switched between runs, nothing else changes):

- ``reference``: the Woodbury set-up with k full solves
  (``linalg.WOODBURY_HALVES = False``), no kept-factor steps
  (``kept_factor.CHORD_STEPS = 0``) and no tentative steps
  (``newton.TENTATIVE_FAILURES = 0``);
- ``halves``: the set-up by forward substitution alone;
- ``chord``: that, and Newton's kept-factor (chord) steps, in the forward
  solve and from the committed equilibrium's factor in each control trial;
- ``tentative``: that, and Newton's tentative full steps;
- ``kernels``: that, and the elastic kernels compiled with their loop
  (``mapped.COMPILE_MAPPED_MIN``; the variants above call them once per
  element, on a second model of the same mesh);
- ``refresh``: that, and the kept factor's low-rank term set up afresh
  where its steps stall, and a control trial's factor with its predictor's
  tendon terms (``kept_factor.FRESH_LOW_RANK``);
- ``krylov``: that, and an inexact Newton step (conjugate gradients
  preconditioned by the kept factor) where they stall even so
  (``kept_factor.KRYLOV_STEPS``);
- ``now``: that, and the same where they cut the residual slowly in the
  local phase (``kept_factor.KRYLOV_AFTER_RATE``): the shipped code.

For each: the forward solve (CPU s, Newton iterations, factorisations), and
a reparam control run: the median CPU time of an iterate after the first
(the starting solve left out), the factorisations per iterate, the
iterates and the objective (the variants must agree on it). Prints a
Markdown table.

    python tools/bench_newton.py --peak-memory 30000

instead builds the model and solves once from rest in this process (the
shipped code, nothing switched) and prints the process's peak resident
memory.

    python tools/bench_newton.py --parts --nodes 10000 30000 [--variant refresh]

instead profiles the shipped code, or a variant's switches (cProfile on
CPU time), and prints where the time goes: of a forward solve from rest,
and of a reparam control run's iterates after the starting solve (the
control run only up to ``--inverse-max-nodes`` nodes).

    python tools/bench_newton.py --breakdown --nodes 10000

instead times, per iterate of a reparam control run of the shipped code
(its starting solve left out), where its CPU time goes: the CHOLMOD
numeric factorisations, the low-rank set-ups, the solves, the model's
evaluations by order, the products with a low-rank Hessian, d2E/dx dc and
the rest (each part's own time, the parts it calls left out; plain timers,
no profiler); a Markdown table.

    python tools/bench_newton.py --counts --nodes 1000 10000

instead counts, per iterate of a reparam control run of the shipped code
(its starting solve left out), the model evaluations by order, the solves
with a factor (right-hand sides) and the factorisations, by the function
that asked for them; a Markdown table.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from plush_opt.apps.timing import counting_factorisations
from plush_opt.base import linalg, low_rank
from plush_opt.control.gradient import Controller
from plush_opt.fem import mapped
from plush_opt.fem.mesh import mesh_for_nodes
from plush_opt.io import load_scene
from plush_opt.problem import from_scene
from plush_opt.solve import kept_factor, newton
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium

ROOT = Path(__file__).resolve().parent.parent
# (linalg.WOODBURY_HALVES, kept_factor.CHORD_STEPS, newton.TENTATIVE_FAILURES, kept_factor.FRESH_LOW_RANK,
#  kept_factor.KRYLOV_STEPS, kept_factor.KRYLOV_AFTER_RATE, elastic kernels compiled with their loop)
SWITCHES = ("WOODBURY_HALVES", "CHORD_STEPS", "TENTATIVE_FAILURES", "FRESH_LOW_RANK", "KRYLOV_STEPS",
            "KRYLOV_AFTER_RATE")
#: the module each of the solver's switches lives in
_HOME = {"CHORD_STEPS": kept_factor, "TENTATIVE_FAILURES": newton, "FRESH_LOW_RANK": kept_factor,
         "KRYLOV_STEPS": kept_factor, "KRYLOV_AFTER_RATE": kept_factor}
_CHORD, _TENTATIVE, _FRESH, _KRYLOV, _SLOW = (kept_factor.CHORD_STEPS, newton.TENTATIVE_FAILURES,
                                              kept_factor.FRESH_LOW_RANK, kept_factor.KRYLOV_STEPS,
                                              kept_factor.KRYLOV_AFTER_RATE)
VARIANTS = {"reference": (False, 0, 0, 0, 0, 1.0, False), "halves": (True, 0, 0, 0, 0, 1.0, False),
            "chord": (True, _CHORD, 0, 0, 0, 1.0, False),
            "tentative": (True, _CHORD, _TENTATIVE, 0, 0, 1.0, False),
            "kernels": (True, _CHORD, _TENTATIVE, 0, 0, 1.0, True),
            "refresh": (True, _CHORD, _TENTATIVE, _FRESH, 0, 1.0, True),
            "krylov": (True, _CHORD, _TENTATIVE, _FRESH, _KRYLOV, 1.0, True),
            "now": (True, _CHORD, _TENTATIVE, _FRESH, _KRYLOV, _SLOW, True)}


def _switch(values) -> None:
    """Set the variant's module constants (:data:`SWITCHES`)."""
    linalg.WOODBURY_HALVES = values[0]
    for name, value in zip(SWITCHES[1:], values[1:]):
        setattr(_HOME[name], name, value)


def _forward(model, c) -> dict:
    count = counting_factorisations(model)
    try:
        t = time.process_time()
        eq = solve_equilibrium(model, c, options=EquilibriumOptions(eigenvalue=False))
        cpu = time.process_time() - t
    finally:
        del model.factorizer.factor
    assert eq.converged, eq.status
    return {"cpu": cpu, "iterations": eq.iterations, "factorisations": count["n"]}


def _control(model, targets) -> dict:
    ctl = Controller(model, targets)
    steps = ctl.iterates()
    next(steps)                                   # the starting solve
    count = counting_factorisations(model)
    times, inside = [], 0
    try:
        t = time.process_time()
        for _ in steps:
            times.append(time.process_time() - t)
            inside = count["n"]       # (the search that finds no next iterate is no iterate's)
            t = time.process_time()
    finally:
        del model.factorizer.factor
    res = ctl.result(eigenvalue=False)
    return {"iterate_cpu": float(np.median(times)) if times else None, "iterates": len(times),
            "factorisations_per_iterate": inside / max(len(times), 1), "objective": res.objective}


_NO_CONTROL: dict = {}


def _peak_memory(name: str, nodes: int) -> None:
    import resource
    scene = load_scene(ROOT / "problems" / f"{name}.yaml").replace(element="P1")
    model = from_scene(scene, mesh_for_nodes(scene, nodes)).model
    c = model.scene.contraction if name != "gripper" else np.full(model.n_winches, 10.0)
    out = _forward(model, c)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024      # Linux: kB
    print(f"{name} @ {model.n_nodes} nodes: forward from rest {out['cpu']:.2f} s CPU, "
          f"{out['iterations']} iterations, {out['factorisations']} factorisations; peak memory {peak:.0f} MB")


def _part_functions() -> list[tuple[str, object, str]]:
    """(label, function, which time) of the parts :func:`_parts_of` reports."""
    from plush_opt.fem.model import Model
    from plush_opt.solve import branch, sensitivity
    return [("CHOLMOD numeric factorisation", linalg.Factorizer._factor_cholmod, "own"),
            ("low-rank set-up (Woodbury)", linalg._WoodburySolve.__init__, "all"),
            ("model evaluations", Model.evaluate, "all"),
            ("solves with a factor", linalg.Factor.solve, "all"),
            ("inexact Newton steps (their solves too)", kept_factor.krylov_step, "all"),
            ("end-of-branch check (its solves too)", branch._at_the_end, "all"),
            ("sensitivities (their solves too)", sensitivity.state_sensitivity, "all")]


def _parts_of(run) -> tuple[list[tuple[str, float]], object]:
    """CPU seconds of ``run()`` whole and by part (cProfile on CPU time;
    each part a function with what it calls, or a function's own time),
    and what ``run`` returned."""
    import cProfile
    import pstats
    prof = cProfile.Profile(time.process_time)
    t = time.process_time()
    out = prof.runcall(run)
    whole = time.process_time() - t
    stats = pstats.Stats(prof).stats
    parts = [("whole (profiled)", whole)]
    for label, fn, which in _part_functions():
        code = fn.__code__
        key = (code.co_filename, code.co_firstlineno, code.co_name)
        _, _, own, cumulative, _ = stats.get(key, (0, 0, 0.0, 0.0, {}))
        parts.append((label, own if which == "own" else cumulative))
    return parts, out


def _parts(problem: str, nodes_list, inverse_max_nodes: int, variant: str = "now") -> None:
    """Where the time goes (:func:`_parts_of`): a forward solve from rest
    and, up to ``inverse_max_nodes`` nodes, a reparam control run's iterates
    after its starting solve, with the solver switches of ``variant`` (one
    with the elastic kernels compiled with their loop); a Markdown table."""
    *switches, loop = VARIANTS[variant]
    if not loop:
        raise SystemExit(f"--variant {variant}: --parts profiles the variants with the compiled kernel loop")
    saved = (linalg.WOODBURY_HALVES,) + tuple(getattr(_HOME[name], name) for name in SWITCHES[1:])
    _switch(switches)
    try:
        _profile_parts(problem, nodes_list, inverse_max_nodes)
    finally:
        _switch(saved)


def _profile_parts(problem: str, nodes_list, inverse_max_nodes: int) -> None:
    print("| nodes | run | part | CPU [s] | share |")
    print("|---|---|---|---|---|")
    options = EquilibriumOptions(eigenvalue=False)
    for nodes in nodes_list:
        scene = load_scene(ROOT / "problems" / f"{problem}.yaml").replace(element="P1")
        prob = from_scene(scene, mesh_for_nodes(scene, nodes))
        model = prob.model
        c = model.scene.contraction if problem != "gripper" else np.full(model.n_winches, 10.0)
        solve_equilibrium(model, c, options=options)            # the symbolic analysis, once
        runs = [("forward from rest", lambda: solve_equilibrium(model, c, options=options).iterations)]
        if model.n_nodes <= inverse_max_nodes:
            steps = Controller(model, prob.targets).iterates()
            next(steps)                                         # the starting solve, not profiled
            runs.append(("control iterates", lambda: sum(1 for _ in steps)))
        for name, run in runs:
            parts, count = _parts_of(run)
            name += f" ({count} {'Newton iterations' if name.startswith('forward') else 'iterates'})"
            for label, t in parts:
                print(f"| {model.n_nodes} | {name} | {label} | {t:.3f} | {t / parts[0][1]:.0%} |", flush=True)


def _unit_costs(model, c) -> str:
    """The median CPU time of one evaluation of each order, one solve and one
    factorisation (with its low-rank set-up) at the equilibrium from rest
    at contractions ``c``, in words."""
    eq = solve_equilibrium(model, c, options=EquilibriumOptions(eigenvalue=False))
    b = np.random.default_rng(0).standard_normal(model.n_dofs)
    ev = model.evaluate(eq.x, c, order=2)
    runs = {f"evaluation order {o}": (lambda o=o: model.evaluate(eq.x, c, order=o)) for o in (0, 1, 2)}
    runs["solve"] = lambda: eq.factor.solve(b)
    runs["factorisation"] = lambda: model.factorizer.factor(ev.hessian_form)
    out = []
    for name, run in runs.items():
        times = []
        for _ in range(UNIT_REPEATS):
            t = time.process_time()
            run()
            times.append(time.process_time() - t)
        out.append(f"{name} {1e3 * float(np.median(times)):.2f}")
    return ", ".join(out)


# each unit cost of --counts: the median of this many
UNIT_REPEATS = 9


def _counts(problem: str, nodes_list) -> None:
    """:func:`main`'s ``--counts``: per iterate of a control run, what each
    caller asked for (evaluations of order 0/1/2, right-hand sides solved,
    factorisations)."""
    import collections
    import sys
    from plush_opt.fem.model import Model
    print("| nodes | caller | evaluations order 0 / 1 / 2 | right-hand sides solved | factorisations |")
    print("|---|---|---|---|---|")
    plain_evaluate, plain_solve = Model.evaluate, linalg.Factor.solve
    for nodes in nodes_list:
        scene = load_scene(ROOT / "problems" / f"{problem}.yaml").replace(element="P1")
        prob = from_scene(scene, mesh_for_nodes(scene, nodes))
        model = prob.model
        steps = Controller(model, prob.targets).iterates()
        next(steps)                                          # the starting solve, not counted
        count = collections.defaultdict(lambda: [0, 0, 0, 0, 0])     # caller: orders 0-2, rhs, factorisations

        def caller() -> str:
            code = sys._getframe(2).f_code
            return f"{Path(code.co_filename).stem}.{code.co_name}"

        def evaluate(self, x, c, order=2):
            count[caller()][order] += 1
            return plain_evaluate(self, x, c, order)

        def solve(self, b, *args, **kwargs):
            count[caller()][3] += 1 if np.ndim(b) == 1 else np.shape(b)[1]
            return plain_solve(self, b, *args, **kwargs)
        factor = model.factorizer.factor

        def counted_factor(H, shift=0.0):
            count[caller()][4] += 1
            return factor(H, shift)
        woodbury = linalg._WoodburySolve
        plain_call, plain_once = woodbury.__call__, woodbury._once
        low_rank = [0, 0]        # low-rank solves, substitutions (a refined solve takes two)

        def call(self, b):
            low_rank[0] += 1
            return plain_call(self, b)

        def once(self, b):
            low_rank[1] += 1
            return plain_once(self, b)
        Model.evaluate, linalg.Factor.solve, model.factorizer.factor = evaluate, solve, counted_factor
        woodbury.__call__, woodbury._once = call, once
        iterates, inside = 0, {}
        try:
            for _ in steps:           # (the search that finds no next iterate is no iterate's: left out)
                iterates, inside = iterates + 1, {name: list(row) for name, row in count.items()}
        finally:
            Model.evaluate, linalg.Factor.solve = plain_evaluate, plain_solve
            woodbury.__call__, woodbury._once = plain_call, plain_once
            del model.factorizer.factor
        total = np.sum(list(inside.values()), axis=0)
        for name, row in sorted(inside.items(), key=lambda item: -sum(item[1])) + [("all", total)]:
            per = [v / max(iterates, 1) for v in row]
            print(f"| {model.n_nodes} | {name} | {per[0]:.2f} / {per[1]:.2f} / {per[2]:.2f} | {per[3]:.2f} "
                  f"| {per[4]:.2f} |", flush=True)
        print(f"| {model.n_nodes} | low-rank solves refined by their residual: {low_rank[1] - low_rank[0]} "
              f"of {low_rank[0]} in {iterates} iterates | | | |")
        c = model.scene.contraction if problem != "gripper" else np.full(model.n_winches, 10.0)
        print(f"| {model.n_nodes} | unit CPU [ms]: {_unit_costs(model, c)} | | | |", flush=True)


def _timed_parts() -> list[tuple[object, str, str]]:
    """(owner, attribute, part) of the functions :func:`_breakdown` times."""
    from plush_opt.fem.model import Model
    return [(Model, "evaluate", "evaluation"), (Model, "mixed", "d2E/dx dc"),
            (linalg.Factorizer, "_factor_cholmod", "numeric factorisation"),
            (linalg._WoodburySolve, "__init__", "low-rank set-up"), (linalg.Factor, "solve", "solve"),
            (low_rank.LowRankHessian, "__matmul__", "product with H")]


def _own_timers(parts: dict) -> list[tuple[object, str, object]]:
    """Wrap :func:`_timed_parts` so that each adds its own CPU time (what it
    calls among them left out) and calls to ``parts`` {part: [s, calls]};
    returns what to restore."""
    stack, saved = [], []
    for owner, name, part in _timed_parts():
        plain = owner.__dict__[name]

        def timed(*args, _plain=plain, _part=part, **kwargs):
            if _part == "evaluation":
                order = kwargs.get("order", args[3] if len(args) > 3 else 2)
                _part = f"evaluation order {order}"
            stack.append(0.0)
            t = time.process_time()
            try:
                return _plain(*args, **kwargs)
            finally:
                dt = time.process_time() - t
                inner = stack.pop()
                entry = parts.setdefault(_part, [0.0, 0])
                entry[0] += dt - inner
                entry[1] += 1
                if stack:
                    stack[-1] += dt
        setattr(owner, name, timed)
        saved.append((owner, name, plain))
    return saved


def _breakdown(problem: str, nodes_list) -> None:
    """:func:`main`'s ``--breakdown``: per iterate of a reparam control run
    (its starting solve left out), each part's own CPU milliseconds and calls."""
    for nodes in nodes_list:
        scene = load_scene(ROOT / "problems" / f"{problem}.yaml").replace(element="P1")
        prob = from_scene(scene, mesh_for_nodes(scene, nodes))
        steps = Controller(prob.model, prob.targets).iterates()
        next(steps)                                          # the starting solve, not timed
        rows, parts = [], {}
        saved = _own_timers(parts)
        try:
            t = time.process_time()
            for _ in steps:
                rows.append((time.process_time() - t, dict(parts)))
                parts.clear()
                t = time.process_time()
        finally:
            for owner, name, plain in saved:
                setattr(owner, name, plain)
        names = sorted({name for _, p in rows for name in p})
        print(f"| {prob.model.n_nodes} nodes: iterate | CPU [ms] | " + " | ".join(names) + " | the rest |")
        print("|---" * (len(names) + 3) + "|")
        mean = {name: [sum(p.get(name, [0.0, 0])[k] for _, p in rows) / len(rows) for k in (0, 1)] for name in names}
        for label, total, p in [(str(i + 1), s, p) for i, (s, p) in enumerate(rows)] + \
                [("mean", float(np.mean([s for s, _ in rows])), mean)]:
            cells = [f"{1e3 * p[name][0]:.1f} ({p[name][1]:.3g})" if name in p else "—" for name in names]
            rest = total - sum(p[name][0] for name in names if name in p)
            print(f"| {label} | {1e3 * total:.1f} | " + " | ".join(cells) + f" | {1e3 * rest:.1f} |", flush=True)
        print(f"| median | {1e3 * float(np.median([s for s, _ in rows])):.1f} |" + " |" * (len(names) + 1))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--problem", default="gripper")
    ap.add_argument("--nodes", type=int, nargs="+", default=[1000, 10000])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--peak-memory", type=int, metavar="NODES",
                    help="one forward solve at about NODES nodes; print the peak resident memory")
    ap.add_argument("--parts", action="store_true", help="profile the shipped code: where the time goes")
    ap.add_argument("--variants", nargs="+", choices=list(VARIANTS), default=list(VARIANTS),
                    help="the variants to run (default: all)")
    ap.add_argument("--no-control", action="store_true", help="the forward solves alone (no control runs)")
    ap.add_argument("--variant", choices=[name for name, v in VARIANTS.items() if v[-1]], default="now",
                    help="--parts: the solver switches of this variant (default: the shipped code)")
    ap.add_argument("--breakdown", action="store_true",
                    help="where each control iterate's CPU time goes, part by part (plain timers)")
    ap.add_argument("--counts", action="store_true",
                    help="count evaluations, solves and factorisations per control iterate, by caller")
    ap.add_argument("--inverse-max-nodes", type=int, default=12000,
                    help="--parts: the control run only up to this many nodes")
    args = ap.parse_args(argv)
    if args.peak_memory:
        return _peak_memory(args.problem, args.peak_memory)
    if args.breakdown:
        return _breakdown(args.problem, args.nodes)
    if args.counts:
        return _counts(args.problem, args.nodes)
    if args.parts:
        return _parts(args.problem, args.nodes, args.inverse_max_nodes, args.variant)
    print("| nodes | variant | forward CPU [ms] | Newton its | factorisations | control iterate CPU [ms] "
          "median | factorisations per iterate | iterates | objective |")
    print("|---|---|---|---|---|---|---|---|---|")
    saved = (linalg.WOODBURY_HALVES,) + tuple(getattr(_HOME[name], name) for name in SWITCHES[1:])
    for nodes in args.nodes:
        scene = load_scene(ROOT / "problems" / f"{args.problem}.yaml").replace(element="P1")
        problems = {True: from_scene(scene, mesh_for_nodes(scene, nodes))}
        if not all(VARIANTS[name][-1] for name in args.variants):
            compile_min, mapped.COMPILE_MAPPED_MIN = mapped.COMPILE_MAPPED_MIN, np.inf
            try:
                problems[False] = from_scene(scene, problems[True].mesh)      # kernels called per element
            finally:
                mapped.COMPILE_MAPPED_MIN = compile_min
        model = problems[True].model
        c = model.scene.contraction if args.problem != "gripper" else np.full(model.n_winches, 10.0)
        runs = {name: [] for name in args.variants}
        try:
            for _ in range(args.repeats):
                for name in args.variants:
                    *switches, loop = VARIANTS[name]
                    _switch(switches)
                    problem = problems[loop]
                    control = _NO_CONTROL if args.no_control else _control(problem.model, problem.targets)
                    runs[name].append({**_forward(problem.model, c), **control})
        finally:
            _switch(saved)
        for name, rs in runs.items():
            med = lambda key: float(np.median([r[key] for r in rs]))  # noqa: E731
            r = rs[-1]
            control = "— | — | — | —" if args.no_control else (
                f"{1e3 * med('iterate_cpu'):.1f} | {r['factorisations_per_iterate']:.2f} | {r['iterates']} | "
                f"{r['objective']:.10g}")
            print(f"| {model.n_nodes} | {name} | {1e3 * med('cpu'):.1f} | {r['iterations']} | {r['factorisations']} | "
                  f"{control} |", flush=True)


if __name__ == "__main__":
    main()
