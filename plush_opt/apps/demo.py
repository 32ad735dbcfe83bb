"""``plush-opt demo`` and ``plush-opt examples``: the main job on the
shipped gripper (what ``make demo`` runs), with the hexapod standing up on
the floor for contact, and a copy of the shipped problems, run scripts and
board files to play with."""

from __future__ import annotations

import json
from pathlib import Path
from types import SimpleNamespace

from .arguments import check_tension_max
from .console import EXIT_OK, EXIT_SOLVER, say, target_summary, use_agg
from ..io.units import units_of
from .run_command import cmd_run
from .solve_command import solve_problem, write_interrupted, write_trace


def add_demo_parser(sub) -> None:
    p = sub.add_parser("demo", help="the main job on the default problem (what `make demo` runs)",
                       description="Solve the gripper's pose problem, stand the hexapod up on the "
                       "floor (contact; with the default problem), then play the gripper run "
                       "script on the board emulator. Works from any folder: the shipped files "
                       "come with the package.")
    p.add_argument("--problem", type=Path, default=None, help="default: the shipped problems/gripper.yaml")
    p.add_argument("--script", type=Path, default=None, help="default: the shipped examples/gripper_run.yaml")
    p.add_argument("--out", type=Path, default=Path("out/demo"), help="output folder")
    p.add_argument("--no-board", action="store_true", help="skip playing the run on the emulator")
    p.add_argument("--tension-max", type=float, default=None, metavar="N",
                   help="top of the tension colour scale of the pose picture (N)")
    p.set_defaults(func=cmd_demo)


def add_examples_parser(sub) -> None:
    p = sub.add_parser("examples", help="copy the shipped problems, run scripts and board files into a folder",
                       description="Copy problems/, examples/ and hw/boards/ into DIR, laid out as in the "
                       "source tree, so that the run scripts find their problem and board files.")
    p.add_argument("dir", type=Path, metavar="DIR", help="destination folder (created; must not hold them yet)")
    p.set_defaults(func=cmd_examples)


def cmd_examples(args) -> int:
    from ..base.data_files import copy_examples
    for folder in copy_examples(args.dir):
        say(f"examples: wrote {folder}")
    say(f"examples: try `plush-opt solve {args.dir / 'problems' / 'gripper.yaml'}` or "
        f"`plush-opt run {args.dir / 'examples' / 'gripper_run.yaml'} --emulator`")
    return EXIT_OK


def default_problem() -> Path:
    """The shipped problems/gripper.yaml."""
    from ..base.data_files import data_file
    return data_file("problems", "gripper.yaml")


def cmd_demo(args) -> int:
    from .plot import plot_pose, plot_trace
    from ..base.data_files import data_file
    from ..base.files import check_output_folder, write_json_atomic
    check_tension_max(args.tension_max)
    use_agg()
    problem = args.problem or default_problem()
    out = check_output_folder(args.out, "--out")
    out.mkdir(parents=True, exist_ok=True)
    say(f"demo: solving {problem.name} (control to its targets)")
    try:
        p, eq, doc, history = solve_problem(problem, method="reparam")
    except KeyboardInterrupt as exc:
        # a signal mid-control: result.json is the run so far, marked
        # interrupted (as `solve --out` writes it); the signal ends the demo
        write_interrupted(out / "result.json", exc)
        raise
    write_json_atomic(out / "result.json", doc)
    plot_pose(out / "pose.png", p.model, eq.x, eq.contraction, p.targets, tension_max=args.tension_max,
              converged=doc["converged"], status=doc["status"])
    plot_trace(out / "trace.png", history, title=f"{p.scene.name}: control iterates", units=p.scene.units)
    write_trace(out / "trace.csv", p.model, p.targets, history)
    say(f"demo: {doc['status']}; {len(history) - 1} iterates, "
        f"{doc['control']['equilibrium_solves']} equilibrium solves, {doc['timing']['total_s']:.2f} s")
    mm = units_of(doc).length
    say("demo: contractions " + ", ".join(f"{n} = {v:.3f} {mm}" for n, v in doc["contractions"].items()))
    say(f"demo: {target_summary(doc['target_error'], mm)}; "
        f"min Hessian eigenvalue {doc['min_hessian_eigenvalue']:.3g}")
    say(f"demo: wrote {out / 'result.json'}, {out / 'pose.png'}, {out / 'trace.png'}, {out / 'trace.csv'}")
    if args.problem is None:
        _demo_contact(data_file("problems", "hexapod_stand.yaml"), out / "hexapod_stand", args.tension_max)
    if not args.no_board:
        code = _demo_run(args.script or data_file("examples", "gripper_run.yaml"), out)
        if code != EXIT_OK:
            return code
    return EXIT_OK if doc["converged"] else EXIT_SOLVER


def _demo_contact(problem: Path, out: Path, tension_max) -> None:
    """Contact: the hexapod lying on the floor stands up to its targets;
    its result and picture go to ``out``."""
    from .plot import plot_pose
    from ..base.files import write_json_atomic
    say(f"demo: contact: {problem.name}, the hexapod lying on the floor, stands up")
    p, eq, doc, _ = solve_problem(problem, method="reparam")
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / "result.json", doc)
    plot_pose(out / "pose.png", p.model, eq.x, eq.contraction, p.targets, tension_max=tension_max,
              converged=doc["converged"], status=doc["status"])
    contact, units = doc["contact"], units_of(doc)
    say(f"demo: contact: {doc['status']}; {target_summary(doc['target_error'], units.length)}; the floor carries "
        f"{contact['total_force'][1]:.4g} {units.force} (its weight), smallest gap {contact['min_gap']:.3g} "
        f"{units.length}, free: {', '.join(contact['free_motions']) or 'nothing'}")
    feet = [f"{patch['force'][1]:.4g} {units.force} at x = {patch['at'][0]:.3g}" for patch in contact["patches"]
            if patch["with"] == "ground"]
    say(f"demo: contact: {len(feet)} patch(es) on the floor: {'; '.join(feet)}")
    say(f"demo: contact: wrote {out / 'result.json'}, {out / 'pose.png'}")


def _demo_run(script: Path, out: Path) -> int:
    """Play a run script on the board emulator; write its log and a plot.
    Returns the run's exit status: 0, or 128 + the signal that interrupted
    it (the board stopped, the log ended), which the demo exits with."""
    from .plot import plot_run_log
    say(f"demo: playing {script.name} on the board emulator")
    log_path = out / "run.jsonl"
    # (quiet: the demo's own line below says how the run ended, on the same stream as its others)
    args = SimpleNamespace(script=script, port=None, emulator=True, dry_run=False, log=log_path,
                           quiet=True, plot=None, vtk=None, progress=False)
    code = cmd_run(args)
    if code != EXIT_OK:
        return code
    rows = [json.loads(line) for line in log_path.read_text().splitlines()]
    from ..io.problem_file import file_units
    from ..io.run_script import load_run_script
    plot_run_log(out / "run.png", rows, title=f"{script.stem}: commanded and measured contractions",
                 length=file_units(load_run_script(script).problem).length)
    end = rows[-1]
    say(f"demo: run {end['status']}: {end['steps_done']} steps, {end['commands']} commands; "
        f"wrote {log_path}, {out / 'run.png'}")
    return EXIT_OK
