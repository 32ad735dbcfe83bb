"""What a scripted run sends during a pose step: only certified poses, the
same commands every time for the same script, whatever the planner's speed;
a dry run's log and picture are a plan (planned time, nothing measured)."""

import json
import random
import time

import pytest

from board_helpers import fast_calibration_dict
from fake_planner import FakePlanner
from plush_opt.apps.runs import run_script
from plush_opt.base.errors import SceneError, SolverError
from plush_opt.io.run_script import load_run_script
from test_board_runs import read_log, write_script

def pose(**kw):
    """A pose step's body (a fresh one each time: the YAML writer would alias a shared one)."""
    return {"targets": [{"at": [0, 150], "to": [-30, 140]}], "freeze": ["grip"], "max_time": 5, **kw}
GOAL = {"left": 12.0, "right": 6.0}


class JitteryPlanner(FakePlanner):
    """FakePlanner whose iterates take an irregular time each (seeded), some
    faster than the script's rate and some slower: compute timing that
    differs from one run to the next."""

    def __init__(self, seed, **kw):
        super().__init__(**kw)
        self.rng = random.Random(seed)

    def pose(self, targets, freeze, max_time):
        for it in super().pose(targets, freeze, max_time):
            time.sleep(self.rng.choice((0.0, 0.0, 0.002, 0.03)))
            yield it


def _commands(log):
    return [(r["step"], r["kind"], r["commanded"], r["ticks"], r.get("iteration")) for r in log
            if r["event"] == "command"]


def _play(tmp_path, name, steps, planner, **kw):
    folder = tmp_path / name
    folder.mkdir()
    log_path = folder / "log.jsonl"
    run_script(write_script(folder, steps, **kw), dry_run=True, planner=planner, log_path=log_path)
    return read_log(log_path)


@pytest.mark.parametrize("stream", [False, True])
def test_the_same_script_sends_the_same_commands_whatever_the_planner_speed(tmp_path, stream):
    steps = [{"set": {"grip": 5.0}}, {"pose": pose(stream=stream)}, {"hold": 0.1}, {"set": {"left": 2.0}},
             {"pose": pose(targets=[{"at": [0, 150], "to": [30, 140]}], stream=stream)}, "release"]
    runs = [_commands(_play(tmp_path, f"run{seed}", steps, JitteryPlanner(seed, steps=30, goal=GOAL), rate=50))
            for seed in (1, 2)]
    assert runs[0] == runs[1]
    poses = [c for c in runs[0] if c[1] == "pose"]
    if stream:
        # every iterate that moves a winch, in order, each once: 30 per pose step
        assert [c[4] for c in poses] == list(range(1, 31)) * 2
    else:
        # one command per pose step: its final pose
        assert [c[4] for c in poses] == [30, 30]
        assert poses[0][2] == {"left": 12.0, "right": 6.0, "grip": 5.0}


def test_the_same_script_sends_the_same_commands_on_the_emulator(tmp_path, make_emulator):
    steps = [{"pose": pose(stream=True)}, {"set": {"grip": 3.0}}, {"pose": pose()}]
    runs = []
    for seed in (1, 2):
        folder = tmp_path / f"run{seed}"
        folder.mkdir()
        run_script(write_script(folder, steps, rate=100), port=make_emulator(3).port,
                   planner=JitteryPlanner(seed, steps=12, goal=GOAL), log_path=folder / "log.jsonl")
        runs.append(_commands(read_log(folder / "log.jsonl")))
    assert runs[0] == runs[1]
    assert [c[4] for c in runs[0] if c[1] == "pose"] == [*range(1, 13), 12]


class HalfCertifiedPlanner(FakePlanner):
    """Every other iterate is an in-progress step, not a certified pose: its
    contraction is far off (19 mm) and must never reach the board."""

    def __init__(self, final_certified=True, time_limited=False, **kw):
        super().__init__(**kw)
        self.final_certified, self.time_limited = final_certified, time_limited

    def pose(self, targets, freeze, max_time):
        iterates = list(super().pose(targets, freeze, max_time))
        for k, it in enumerate(iterates[:-1]):
            yield it
            yield {**it, "contraction": {**it["contraction"], "right": 19.0}, "certified": False,
                   "status": f"in progress {k}"}
        yield {**iterates[-1], "certified": self.final_certified, "time_limited": self.time_limited}


@pytest.mark.parametrize("stream", [False, True])
def test_an_uncertified_iterate_is_never_sent(tmp_path, stream):
    log = _play(tmp_path, "run", [{"pose": pose(stream=stream)}],
                HalfCertifiedPlanner(steps=6, goal=GOAL), stream=False)
    poses = [r for r in log if r["event"] == "command"]
    assert poses and all(r["commanded"]["right"] != 19.0 for r in poses)
    assert poses[-1]["commanded"] == {"left": 12.0, "right": 6.0, "grip": 0.0} and poses[-1]["converged"]
    # streamed: the certified iterates 1, 3, ..., 9 and the final pose (11); else the final alone
    assert [r["iteration"] for r in poses] == ([1, 3, 5, 7, 9, 11] if stream else [11])


def test_an_uncertified_final_pose_stops_the_run_before_it_is_sent(tmp_path):
    path = write_script(tmp_path, [{"set": {"left": 2.0}}, {"pose": pose()}, "release"])
    with pytest.raises(SolverError, match=r"run\.yaml: steps\[1\]\.pose: the planner's final pose is not a "
                                          r"certified equilibrium \(converged\); nothing of this step was sent"):
        run_script(path, dry_run=True, planner=HalfCertifiedPlanner(final_certified=False, steps=4, goal=GOAL),
                   log_path=tmp_path / "log.jsonl")
    log = read_log(tmp_path / "log.jsonl")
    assert [r["kind"] for r in log if r["event"] == "command"] == ["set"]
    assert log[-1]["status"].startswith("error: ") and log[-1]["commands"] == 1


def test_a_pose_cut_by_max_time_stops_the_run(tmp_path):
    path = write_script(tmp_path, [{"pose": pose()}])
    with pytest.raises(SolverError, match=r"steps\[0\]\.pose: the planner stopped at max_time \(5 s\) before "
                                          r"its own stop rules.*raise max_time"):
        run_script(path, dry_run=True, planner=HalfCertifiedPlanner(time_limited=True, steps=4, goal=GOAL),
                   log_path=tmp_path / "log.jsonl")
    assert not [r for r in read_log(tmp_path / "log.jsonl") if r["event"] == "command"]


def test_stream_is_a_script_key_and_a_pose_key(tmp_path):
    steps = [{"pose": pose()}, {"pose": pose(stream=False)}]
    script = load_run_script(write_script(tmp_path, steps, stream=True))
    assert [s.stream for s in script.steps] == [True, False]
    assert not load_run_script(write_script(tmp_path, steps)).steps[0].stream
    with pytest.raises(SceneError, match=r"run\.yaml: steps\[0\]\.pose\.stream: expected true or false, "
                                         r"got string 'yes please'"):
        load_run_script(write_script(tmp_path, [{"pose": pose(stream="yes please")}]))
    with pytest.raises(SceneError, match=r"run\.yaml: stream: expected true or false"):
        load_run_script(write_script(tmp_path, steps, stream=2))


# ------------------------------------------------------------ a dry run's time --

def test_a_dry_run_logs_planned_time(tmp_path):
    """Moves at the calibration's top speed (200 mm/s here), holds, and a
    stream one period apart: the same times every run, solver time excluded."""
    assert {w["max_speed"] for w in fast_calibration_dict()["winches"]} == {200.0}
    steps = [{"set": {"left": 10.0}}, {"hold": 1.0}, {"pose": pose(stream=True)}, {"set": {"left": 0.0}}]
    logs = [_play(tmp_path, f"run{seed}", steps, JitteryPlanner(seed, steps=4, goal={"left": 14.0}), rate=10)
            for seed in (1, 2)]
    assert [r["t"] for r in logs[0]] == [r["t"] for r in logs[1]]
    log = logs[0]
    assert log[0]["t"] == 0.0 and log[0]["clock"] == "planned"
    at = {(r["step"], r["event"], r.get("iteration")): r["t"] for r in log}
    assert at[(0, "command", None)] == 0.0                       # 10 mm at 200 mm/s: 0.05 s
    assert at[(1, "hold", None)] == pytest.approx(0.05)
    # the stream starts after the hold; its commands are 0.1 s apart (rate 10)
    assert [at[(2, "command", k)] for k in (1, 2, 3, 4)] == pytest.approx([1.05, 1.15, 1.25, 1.35])
    # then the last streamed command (14 mm) is reached: the winch follows the
    # stream at 200 mm/s, so it is there 0.005 s after the last command
    assert at[(3, "command", None)] == pytest.approx(1.355)
    assert log[-1]["kind"] == "end" and log[-1]["t"] == pytest.approx(1.355 + 0.07)


def test_a_dry_run_picture_says_it_is_a_plan(tmp_path, monkeypatch):
    from plush_opt.apps import plot, run_command
    figures = []
    monkeypatch.setattr(plot, "save_figure", lambda fig, path: figures.append(fig))
    log = _play(tmp_path, "run", [{"set": {"left": 10.0}}, {"pose": pose()}], FakePlanner(steps=3, goal=GOAL))
    log_path = tmp_path / "run" / "log.jsonl"
    run_command._run_plot(tmp_path / "run.png", log_path, tmp_path / "run" / "run.yaml")
    fig, = figures
    texts = [t.get_text() for t in fig.findobj(lambda a: hasattr(a, "get_text"))]
    assert fig.axes[-1].get_xlabel() == "planned time [s]"
    assert fig._suptitle.get_text() == "run: planned contractions (dry run: a plan, nothing measured)"
    legend = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert legend == ["planned command"]
    assert not any("measured" in t and "nothing measured" not in t for t in texts)
    assert all(r["measured"] is None for r in log)


def test_a_board_run_picture_keeps_measured_time(tmp_path, monkeypatch):
    from plush_opt.apps import plot
    figures = []
    monkeypatch.setattr(plot, "save_figure", lambda fig, path: figures.append(fig))
    rows = [{"t": 0.0, "kind": "start", "step": None, "commanded": {"a": 0.0}, "measured": {"a": 0.0},
             "dry_run": False},
            {"t": 0.5, "kind": "set", "step": 0, "commanded": {"a": 1.0}, "measured": {"a": 0.9}}]
    plot.plot_run_log(tmp_path / "x.png", rows, title="t")
    fig, = figures
    assert fig.axes[-1].get_xlabel() == "time [s]"
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["commanded", "measured"]


def test_log_lines_of_a_pose_step_say_which_iterate_they_sent(tmp_path):
    log = _play(tmp_path, "run", [{"pose": pose(stream=True)}], FakePlanner(steps=3, goal=GOAL))
    lines = [json.dumps(r) for r in log if r["event"] == "command"]
    assert len(lines) == 3 and all('"iteration"' in line and '"converged"' in line for line in lines)

