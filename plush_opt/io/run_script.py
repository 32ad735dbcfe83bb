"""Run scripts (YAML, format ``plush-opt-run/1``, docs/hardware.md) ->
validated :class:`RunScript`.

A run script names a problem file, a board calibration, a streaming rate
and a list of steps::

    format: plush-opt-run/1
    problem: ../problems/gripper.yaml     # relative to the script
    board: ../hw/boards/gripper.yaml
    rate: 20                              # Hz, at most this many commands per second
    stream: false                         # optional: pose steps send their final pose only (default)
    steps:
      - set: {grip: 10.0}                 # contractions, mm; other winches keep theirs
      - pose: {targets: [{at: [-78, 122], to: [-74, 80], weight: 1}], freeze: [grip], max_time: 5}
      - pose: {targets: [{at: [0, 150], to: [0, 140]}], stream: true}   # every certified iterate
      - hold: 1.5                         # seconds
      - release                           # every winch back to its lower bound

Only the structure is checked here; winch names and bounds are checked
against the scene and the calibration by ``check_run_script`` of the runner.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from .checker import MAX_WEIGHT, Checker, at_index, at_key, describe
from .yaml_reader import read_yaml

FORMAT = "plush-opt-run/1"
STEP_KINDS = ("set", "pose", "hold", "release")
MAX_RATE = 1000.0          # Hz
MIN_RATE = 0.1             # Hz: slower, a run would wait minutes between commands (a typo, not a plan)
MAX_STEP_TIME = 3600.0     # s, a pose's max_time or a hold: an hour on the bench is a long run
MAX_STEPS = 10_000         # steps of one script: a day of one-second moves needs fewer
MAX_RUN_TIME = 86400.0     # s, the holds and pose max_times of one script together: a day
DEFAULT_MAX_TIME = 10.0    # s, pose steps

_TOP_KEYS = ("format", "description", "problem", "board", "rate", "stream", "steps")
_POSE_KEYS = ("targets", "freeze", "max_time", "stream")
_TARGET_KEYS = ("at", "to", "weight")


@dataclass(frozen=True)
class Step:
    """One step of a run script.

    ``kind`` is ``set`` (``contraction``), ``pose`` (``targets``, ``freeze``,
    ``max_time``, ``stream``), ``hold`` (``seconds``) or ``release``. A pose
    step sends its final certified pose only, or with ``stream`` every
    certified iterate of its planner in order (docs/hardware.md).
    """

    kind: str
    contraction: dict = field(default_factory=dict)      # set: {name: mm}
    targets: tuple = ()                                   # pose: ({"at", "to", "weight"}, ...)
    freeze: tuple[str, ...] = ()                          # pose
    max_time: float = DEFAULT_MAX_TIME                    # pose, s
    stream: bool = False                                  # pose: send every certified iterate
    seconds: float = 0.0                                  # hold


@dataclass(frozen=True)
class RunScript:
    """A validated run script; paths are resolved against the script's folder."""

    path: Path
    problem: Path
    board: Path
    rate: float
    steps: tuple[Step, ...]
    description: str = ""


def load_run_script(path) -> RunScript:
    """Read and validate a run script (structure only; names and bounds are
    checked against a planner by ``check_run_script``). Raises :class:`SceneError`."""
    path = Path(path)
    ck = Checker(path)
    top = ck.document(read_yaml(path, what="run script", source=str(path)), _TOP_KEYS,
                      required=("format", "problem", "board", "rate", "steps"))
    if top["format"] != FORMAT:
        ck.fail("format", f"must be {FORMAT!r}, got {describe(top['format'])}")
    files = {}
    for key in ("problem", "board"):
        if not isinstance(top[key], str) or not top[key]:
            ck.fail(key, f"must be a file path, got {describe(top[key])}")
        files[key] = (path.parent / top[key]).resolve()
        if not files[key].is_file():
            ck.fail(key, f"{top[key]!r} (relative to the script) does not exist: {files[key]}")
    rate = ck.number(top["rate"], "rate", gt=0)
    if not MIN_RATE <= rate <= MAX_RATE:
        ck.fail("rate", f"must be in {MIN_RATE:g}..{MAX_RATE:g} Hz, got {rate:g}")
    steps = ck.seq(top["steps"], "steps", min_len=1, what="list of steps")
    if len(steps) > MAX_STEPS:
        ck.fail("steps", f"{len(steps)} steps; at most {MAX_STEPS}")
    description = top.get("description")
    description = "" if description is None else ck.string(description, "description")
    stream = top.get("stream")
    stream = False if stream is None else ck.boolean(stream, "stream")
    parsed = tuple(_parse_step(ck, s, i, stream) for i, s in enumerate(steps))
    total = sum(s.seconds + (s.max_time if s.kind == "pose" else 0.0) for s in parsed)
    if total > MAX_RUN_TIME:
        ck.fail("steps", f"holds and pose max_times add up to {total:g} s; at most {MAX_RUN_TIME:g} s (a day)")
    return RunScript(path=path, problem=files["problem"], board=files["board"], rate=rate, steps=parsed,
                     description=description)


def _parse_step(ck: Checker, item, i: int, stream: bool) -> Step:
    """Step ``i``; ``stream`` is the script's default for pose steps."""
    key = at_index("steps", i)
    if item == "release":
        return Step(kind="release")
    if not isinstance(item, dict) or len(item) != 1:
        ck.fail(key, "must be one of 'release', {set: ...}, {pose: ...}, {hold: seconds}, "
                f"{{release: null}}; got {describe(item)}")
    (kind, body), = item.items()
    if kind not in STEP_KINDS:
        ck.fail(key, f"unknown step {kind!r}; steps are: {', '.join(STEP_KINDS)}")
    key = at_key(key, kind)
    if kind == "release":
        if body not in (None, {}, True):
            ck.fail(key, f"takes no value, got {describe(body)}")
        return Step(kind="release")
    if kind == "hold":
        return Step(kind="hold", seconds=_seconds(ck, ck.number(body, key, ge=0), key))
    if kind == "set":
        if not isinstance(body, dict) or not body:
            ck.fail(key, f"must map winch names to contractions, got {describe(body)}")
        return Step(kind="set", contraction={str(name): ck.number(v, at_key(key, name))
                                             for name, v in body.items()})
    return _parse_pose(ck, body, key, stream)


def _weight(ck: Checker, value, key: str) -> float:
    """A target weight in (0, :data:`MAX_WEIGHT`]."""
    w = ck.number(value, key, gt=0)
    if w > MAX_WEIGHT:
        ck.fail(key, f"must be <= {MAX_WEIGHT:g}, got {w:g}")
    return w


def _seconds(ck: Checker, t: float, key: str) -> float:
    """A step's duration, at most :data:`MAX_STEP_TIME`."""
    if t > MAX_STEP_TIME:
        ck.fail(key, f"must be <= {MAX_STEP_TIME:g} s, got {t:g}")
    return t


def _parse_pose(ck: Checker, body, key: str, stream: bool) -> Step:
    body = ck.mapping(body, key, _POSE_KEYS, required=("targets",))
    targets = []
    items = ck.seq(body["targets"], at_key(key, "targets"), min_len=1, what="list of targets")
    for j, t in enumerate(items):
        tkey = at_index(at_key(key, "targets"), j)
        t = ck.mapping(t, tkey, _TARGET_KEYS, required=("at", "to"))
        weight = t.get("weight")
        targets.append({"at": list(ck.point(t["at"], at_key(tkey, "at"))),
                        "to": list(ck.point(t["to"], at_key(tkey, "to"))),
                        "weight": 1.0 if weight is None else _weight(ck, weight, at_key(tkey, "weight"))})
    freeze = body.get("freeze")
    freeze = [] if freeze is None else ck.seq(freeze, at_key(key, "freeze"),
                                              what="list of winch names")
    freeze = [ck.name(n, at_index(at_key(key, "freeze"), k)) for k, n in enumerate(freeze)]
    max_time = body.get("max_time")
    max_time = (DEFAULT_MAX_TIME if max_time is None
                else _seconds(ck, ck.number(max_time, at_key(key, "max_time"), gt=0), at_key(key, "max_time")))
    if body.get("stream") is not None:
        stream = ck.boolean(body["stream"], at_key(key, "stream"))
    return Step(kind="pose", targets=tuple(targets), freeze=tuple(freeze), max_time=max_time, stream=stream)
