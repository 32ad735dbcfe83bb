"""``plush-opt export``: a run log or a problem's pose for ParaView. The
writers are :mod:`plush_opt.apps.export`."""

from __future__ import annotations

from pathlib import Path

from ..base.errors import SceneError
from .arguments import contraction_arg
from .console import EXIT_OK, EXIT_SOLVER, say
from .solve_command import solve_problem


def add_export_parser(sub) -> None:
    p = sub.add_parser("export", help="write a run log or a problem's pose for ParaView (meshio)",
                       description="A run log (JSON lines of plush-opt run) becomes DIR/run.pvd, the "
                       "pose at every command; a problem file becomes DIR/pose.vtu, the equilibrium at "
                       "its contractions (and -c) or the pose --result recorded. With friction at via points "
                       "a run is replayed command by command, a result keeps its segment rest lengths, "
                       "a problem alone is driven from the start state (see docs/model.md).")
    p.add_argument("source", type=Path, help="a run log (.jsonl) or a problem file (.yaml)")
    p.add_argument("--out", "-o", type=Path, required=True, metavar="DIR", help="output folder")
    p.add_argument("--contraction", "-c", action="append", type=contraction_arg, default=[],
                   metavar="NAME=VALUE", help="contraction of a winch (problem files); repeatable")
    p.add_argument("--result", "-r", type=Path, metavar="FILE", help="a result file of this problem: its pose")
    p.set_defaults(func=cmd_export)


def cmd_export(args) -> int:
    from .export import export_result, export_run, write_pose
    if args.source.suffix == ".json":
        raise SceneError(f"{args.source}: a result file: export PROBLEM.yaml --result {args.source} --out DIR")
    if (args.contraction or args.result) and (args.source.suffix == ".jsonl" or args.contraction and args.result):
        raise SceneError("--contraction, --result: one of them, with a problem file (a run log has its own poses)")
    if args.source.suffix == ".jsonl":
        say(str(export_run(args.out, args.source)))
        return EXIT_OK
    if args.result is not None:
        path, note, converged = export_result(args.out, args.source, args.result)
        say(f"export: {note}", err=True)
    else:
        p, eq, doc, _ = solve_problem(args.source, args.contraction, method="forward")
        if p.plant.history_note:       # the pose depends on the path: which history it assumed
            say(f"export: {p.source}: {p.plant.history_note}; --result FILE exports a state a solve recorded",
                err=True)
        path, converged = write_pose(args.out / "pose.vtu", p.model, eq.x, eq.contraction, eq), doc["converged"]
    say(str(path))
    return EXIT_OK if converged else EXIT_SOLVER
