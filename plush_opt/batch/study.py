"""A design study: one problem file solved at every combination of varied
parameters (``plush-opt study``, docs/study.md).

Each variant is the file with some numbers changed (``--vary
material.youngs_modulus=0.01:0.08:8``), checked like any problem file
before anything runs. Per variant, :func:`solve_variant` solves the file's
control problem and measures what a designer trades off: the target error
reached, the largest tendon tension and winch contraction it needs, the
friction hysteresis of one winch (the work a load-unload cycle loses) and
the pose left when every winch is released. Every pose is certified
(converged, Hessian positive definite); a variant where one is not says so
in ``certified`` and ``status``.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import itertools
import math
import re
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..base.errors import SceneError
from ..io.problem_file import scene_from_dict
from ..io.yaml_reader import read_yaml
from ..problem import from_scene
from .runner import BatchResult, run_batch

#: values of one --vary range, at most (a study is a grid: 1000 per key is already a night)
MAX_VALUES = 1000
#: variants of one study, at most
MAX_VARIANTS = 100_000
#: steps of each leg (pull, release) of the hysteresis sweep: enough for the loop's area to a few percent
SWEEP_STEPS = 12
#: the swept winch's pull ends here at least (length units): a solution that barely pulls
#: any winch still gets a loop worth measuring
MIN_SWEEP = 1e-6

_PART = re.compile(r"^([A-Za-z_][A-Za-z0-9_]*)(?:\[(\d+)\])?$")
_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


@dataclass(frozen=True)
class Vary:
    """One varied key of the problem file and its values.

    key : dotted key of the problem file (``material.youngs_modulus``;
        a list entry as ``tendons.list[2].friction``).
    values : the values, in the order given.
    """

    key: str
    values: tuple[float, ...]


def parse_vary(text: str) -> Vary:
    """``KEY=A:B:N`` (N values from A to B, evenly spaced, both included)
    or ``KEY=V1,V2,...``. A :class:`SceneError` names what is wrong."""
    where = f"--vary {text}"
    key, sep, spec = text.partition("=")
    key, spec = key.strip(), spec.strip()
    if not sep or not key or not spec:
        raise SceneError(f"{where}: expected KEY=A:B:N or KEY=V1,V2,... "
                         "(e.g. material.youngs_modulus=0.01:0.08:8)")
    for part in key.split("."):
        if not _PART.match(part):
            raise SceneError(f"{where}: {key!r} is not a key of the problem file "
                             "(dotted names, a list entry as list[2])")
    if re.fullmatch(rf"{_NUMBER}:{_NUMBER}:\d+", spec):
        a, b, n = spec.split(":")
        n = int(n)
        if not 1 <= n <= MAX_VALUES:
            raise SceneError(f"{where}: the number of values must be 1..{MAX_VALUES}, got {n}")
        if n == 1 and float(a) != float(b):
            raise SceneError(f"{where}: one value from {a} to {b}: give 2 or more, or A:A:1")
        values = tuple(float(v) for v in np.linspace(float(a), float(b), n))
    elif re.fullmatch(rf"{_NUMBER}(?:,{_NUMBER})*", spec):
        values = tuple(float(v) for v in spec.split(","))
        if len(values) > MAX_VALUES:
            raise SceneError(f"{where}: at most {MAX_VALUES} values, got {len(values)}")
    else:
        raise SceneError(f"{where}: {spec!r} is neither A:B:N (numbers, N an integer) "
                         "nor a list of numbers V1,V2,...")
    if not all(math.isfinite(v) for v in values):
        raise SceneError(f"{where}: values must be finite numbers")
    return Vary(key, values)


def set_key(document: dict, key: str, value: float, where: str) -> None:
    """Set ``key`` (dotted) of the problem document to ``value``. The key's
    section must exist; an existing value must be a number. Whether a new
    key is allowed is the problem-file reader's call (see :func:`variants`)."""
    node, parts = document, key.split(".")
    for depth, part in enumerate(parts):
        name, index = _PART.match(part).groups()
        last = depth == len(parts) - 1
        here = ".".join(parts[:depth + 1])
        if not isinstance(node, dict):
            raise SceneError(f"{where}: {'.'.join(parts[:depth])} is not a section with keys")
        if last and index is None:
            old = node.get(name)
            if old is not None and (isinstance(old, bool) or not isinstance(old, (int, float))):
                raise SceneError(f"{where}: {here} is {old!r} in the file, not a number")
            node[name] = value
            return
        if name not in node:
            raise SceneError(f"{where}: the problem file has no {here!r}")
        node = node[name]
        if index is not None:
            if not isinstance(node, list) or int(index) >= len(node):
                size = len(node) if isinstance(node, list) else 0
                raise SceneError(f"{where}: {here}: the file's {name} has {size} entries")
            if last:
                raise SceneError(f"{where}: {here} is a list entry, not a number")
            node = node[int(index)]


@dataclass(frozen=True)
class Variant:
    """One combination of values: ``index`` in the study, ``values``
    ((key, value) pairs), the problem ``document`` with them set, and its
    ``source`` (the file's name with the values, for messages)."""

    index: int
    values: tuple[tuple[str, float], ...]
    document: dict
    source: str

    @property
    def label(self) -> str:
        return ", ".join(f"{k.rsplit('.', 1)[-1]}={v:g}" for k, v in self.values)


def variants(path, varies: list[Vary]) -> list[Variant]:
    """Every combination of the varied values (the first --vary slowest),
    each checked by the problem-file reader before anything is solved: a
    key or value the file cannot take is a :class:`SceneError` naming the
    file, the --vary and the key."""
    path = Path(path)
    if not varies:
        raise SceneError("study: give at least one --vary KEY=A:B:N")
    keys = [v.key for v in varies]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        raise SceneError(f"--vary {twice[0]}: given twice (one --vary per key)")
    n = math.prod(len(v.values) for v in varies)
    if n > MAX_VARIANTS:
        raise SceneError(f"--vary: {n} variants; at most {MAX_VARIANTS}")
    base = read_yaml(path, what="problem file", source=path.name)
    out = []
    for i, combo in enumerate(itertools.product(*(v.values for v in varies))):
        doc = copy.deepcopy(base)
        pairs = tuple(zip(keys, combo))
        for key, value in pairs:
            set_key(doc, key, value, f"{path.name}: --vary {key}")
        source = f"{path.name} [{', '.join(f'{k}={v:g}' for k, v in pairs)}]"
        try:
            scene_from_dict(copy.deepcopy(doc), source)
        except SceneError as exc:
            raise SceneError(f"--vary: {exc}") from None
        out.append(Variant(i, pairs, doc, source))
    return out


@dataclass(frozen=True)
class StudyOptions:
    """What each variant runs.

    method : control method (``reparam``, ``clip``, ``bilevel``).
    max_area : mesh every variant with triangles up to this area instead
        of the file's (None: the file's mesh).
    sweep_steps : equilibria per leg of the hysteresis sweep (pull, release).
    sweep_winch : the winch swept (None: the one the solution pulls most).
    """

    method: str = "reparam"
    max_area: float | None = None
    sweep_steps: int = SWEEP_STEPS
    sweep_winch: str | None = None

    def __post_init__(self):
        if self.method not in ("reparam", "clip", "bilevel"):
            raise SceneError(f"--method: expected reparam, clip or bilevel, got {self.method!r}")
        if self.max_area is not None and not (math.isfinite(self.max_area) and self.max_area > 0):
            raise SceneError(f"--max-area: expected an area > 0, got {self.max_area:g}")
        if not 1 <= self.sweep_steps <= 10_000:
            raise SceneError(f"--sweep-steps: expected 1..10000, got {self.sweep_steps}")


#: the columns of a study's table, after the varied keys (units in docs/study.md)
COLUMNS = ("status", "certified", "converged", "control_reason", "target_error", "max_tension",
           "max_contraction", "sweep_winch", "hysteresis_work", "release_error", "n_nodes",
           "equilibrium_solves", "t_wall")


def solve_variant(variant: Variant, options: StudyOptions) -> dict:
    """Solve one variant; the study's row for it (see :data:`COLUMNS`).

    ``target_error`` RMS distance of the targets (length), ``max_tension``
    the largest tendon (segment) tension at the solution (force),
    ``max_contraction`` the largest winch contraction (length),
    ``hysteresis_work`` the work one pull-and-release cycle of
    ``sweep_winch`` (0 to its contraction in the solution and back, the
    others slack) loses to friction, the loop's area in tension against
    contraction (force x length; 0 without friction), ``release_error``
    the largest distance of a node from where it sits at zero contraction
    reached from the start state, after every winch is released from the
    solution (length; what friction holds).
    ``certified``: every pose above converged with a positive definite Hessian.
    """
    t0 = time.perf_counter()
    scene = scene_from_dict(copy.deepcopy(variant.document), variant.source)
    problem = from_scene(scene, max_area=options.max_area)
    if not problem.targets.n_targets:
        raise SceneError(f"{variant.source}: targets: a study solves the file's control problem; "
                         "the file has none")
    result = problem.control(options.method)
    eq = result.equilibrium
    poses = [eq]
    tensions = [t for row in problem.plant.segment_table(eq) for t in row["segment_tensions"]]
    c = np.asarray(eq.contraction, dtype=np.float64)
    # released: every winch back to zero from the solution's state (friction holds the body)
    plant = problem.plant.fork(problem.plant.state_of(eq))
    released = plant.drive(np.zeros_like(c), origin="the study's control solution")
    poses.append(released)
    # against the pose at zero contraction reached without history (gravity sags it too)
    start = problem.plant.fork().drive(np.zeros_like(c), origin="the scene's start state")
    poses.append(start)
    release_error = float(np.max(np.linalg.norm(released.nodes - start.nodes, axis=1)))
    winch, work, swept_ok = _hysteresis(problem, c, options)
    certified = swept_ok and all(p.converged and p.positive_definite for p in poses)
    status = "ok" if certified else "not certified"
    if certified and not result.converged:
        status = f"ok ({result.reason})"
    return {**{k: v for k, v in variant.values}, "status": status, "certified": certified,
            "converged": bool(result.converged), "control_reason": result.reason,
            "target_error": float(problem.targets.rms_error(eq.x)),
            "max_tension": float(max(tensions, default=0.0)),
            "max_contraction": float(np.max(c, initial=0.0)), "sweep_winch": winch,
            "hysteresis_work": work, "release_error": release_error,
            "n_nodes": int(problem.mesh.n_nodes), "equilibrium_solves": int(result.stats.equilibrium_solves),
            "t_wall": time.perf_counter() - t0}


def _hysteresis(problem, c: np.ndarray, options: StudyOptions) -> tuple[str, float, bool]:
    """(winch, loop area, every state converged) of a pull-and-release
    sweep of one winch from the start state, on the segmented plant (the
    same poses without friction, both end tensions of every tendon); a
    scene without friction loses nothing: 0, not swept (its sweep measured
    the solver's tolerance, 1e-10 to 1e-5 N mm)."""
    from ..solve.plant import make_plant, path_dependent
    names = problem.winch_names
    if options.sweep_winch is not None:
        if options.sweep_winch not in names:
            raise SceneError(f"--sweep-winch {options.sweep_winch}: no winch named "
                             f"{options.sweep_winch!r} (winches: {', '.join(names)})")
        w = names.index(options.sweep_winch)
    else:
        w = int(np.argmax(c))
    if not path_dependent(problem.scene):     # no friction: the same poses both ways, nothing lost
        return names[w], 0.0, True
    top = max(float(c[w]), MIN_SWEEP)
    leg = np.linspace(0.0, top, options.sweep_steps + 1)
    values = np.concatenate([leg[1:], leg[::-1][1:]])
    path = np.zeros((len(values), len(names)))
    path[:, w] = values
    plant = make_plant(problem.model, segmented=True)
    states = plant.follow(path)
    ok = len(states) == len(path) + 1 and all(s.converged for s in states)
    if not ok:
        return names[w], float("nan"), False
    on = [t for t, tendon in enumerate(problem.scene.tendons) if tendon.winch == names[w]]
    pull = np.array([sum(plant.end_tensions(s)[t][0] for t in on) for s in states])
    cw = np.array([s.contraction[w] for s in states])
    # the closed loop 0 -> top -> 0: the shoelace integral of tension over contraction
    work = float(abs(np.sum((cw[1:] - cw[:-1]) * (pull[1:] + pull[:-1]) / 2.0)))
    return names[w], work, True


@dataclass(frozen=True)
class StudyResult:
    """A study's rows (one dict per variant, in variant order; a failed
    variant has its values, ``status`` ``failed: ...`` and NaN elsewhere),
    the varied keys and the :class:`~plush_opt.batch.runner.BatchResult`."""

    rows: tuple[dict, ...]
    keys: tuple[str, ...]
    batch: BatchResult


def run_study(path, varies: list[Vary], options: StudyOptions | None = None, *, jobs=None,
              scheduler=None, progress=None) -> StudyResult:
    """Solve every variant of ``path`` (see :func:`variants`) with
    :func:`~plush_opt.batch.runner.run_batch`; the rows in variant order.
    An interrupted study returns the variants that finished (the others
    ``status`` ``interrupted``); ``result.batch.raise_if_interrupted()``
    after writing them."""
    options = options or StudyOptions()
    todo = variants(path, varies)
    names = [w.name for w in scene_from_dict(copy.deepcopy(todo[0].document), todo[0].source).winches]
    if options.sweep_winch is not None and options.sweep_winch not in names:
        raise SceneError(f"--sweep-winch {options.sweep_winch}: no winch named {options.sweep_winch!r} "
                         f"(winches: {', '.join(names)})")
    if progress is not None and getattr(progress, "describe", None) is not None:
        progress.describe = lambda i: todo[i].label
    batch = run_batch(functools.partial(solve_variant, options=options), todo, jobs=jobs,
                      scheduler=scheduler, progress=progress)
    rows = []
    for variant, item in zip(todo, batch.items):
        if item.ok:
            rows.append(item.value)
            continue
        row = {**{k: v for k, v in variant.values}, **{c: math.nan for c in COLUMNS}}
        row.update(status=item.status + (f": {item.error}" if item.error else ""), certified=False,
                   converged=False, control_reason="", sweep_winch="")
        rows.append(row)
    return StudyResult(tuple(rows), tuple(v.key for v in varies), batch)
