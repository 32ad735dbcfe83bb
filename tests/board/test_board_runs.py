"""Scripted runs (plush_opt.apps.runs) with FakePlanner: dry, on the emulator, interrupted."""

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from board_helpers import default_sigint, fast_calibration_dict, wait_until
from fake_planner import FakePlanner
from plush_opt.io.run_script import FORMAT, RunScript, load_run_script
from plush_opt.apps.run_command import add_run_arguments, cli_run
from plush_opt.apps.runs import check_run_script, run_script
from plush_opt.board import SerialLink, calibration_from_dict, load_calibration
from plush_opt.base.errors import HardwareError, SceneError, SolverError

ROOT = Path(__file__).resolve().parents[2]
LOG_KEYS = {"t", "step", "kind", "event", "commanded", "ticks", "acknowledged", "measured", "objective", "status"}


def write_script(folder: Path, steps, *, rate=50, calibration=None, **top) -> Path:
    """A run script in ``folder`` with its problem (a stand-in: FakePlanner
    does not read it) and the fast board calibration."""
    (folder / "problem.yaml").write_text("format: plush-opt/1\n")
    (folder / "board.yaml").write_text(yaml.safe_dump(calibration or fast_calibration_dict()))
    doc = {"format": FORMAT, "problem": "problem.yaml", "board": "board.yaml", "rate": rate, "steps": steps, **top}
    path = folder / "run.yaml"
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def read_log(path):
    lines = Path(path).read_text().splitlines()
    records = [json.loads(line) for line in lines]  # every line parses
    for r in records:
        assert LOG_KEYS <= r.keys(), r
    return records


STEPS = [{"set": {"grip": 5.0}},
         {"pose": {"targets": [{"at": [0, 150], "to": [-30, 140]}], "freeze": ["grip"], "max_time": 2}},
         {"hold": 0.1},
         "release"]


# ------------------------------------------------------------ the script --

def test_load_run_script(tmp_path):
    script = load_run_script(write_script(tmp_path, STEPS + [{"release": None}], description="demo"))
    assert isinstance(script, RunScript)
    assert script.problem == tmp_path / "problem.yaml" and script.board == tmp_path / "board.yaml"
    assert [s.kind for s in script.steps] == ["set", "pose", "hold", "release", "release"]
    pose = script.steps[1]
    assert pose.targets == ({"at": [0.0, 150.0], "to": [-30.0, 140.0], "weight": 1.0},)
    assert pose.freeze == ("grip",) and pose.max_time == 2.0
    assert script.steps[2].seconds == 0.1 and script.rate == 50.0


@pytest.mark.parametrize("change, match", [
    ({"format": "plush-opt-run/2"}, r"run\.yaml: format: must be 'plush-opt-run/1'"),
    ({"rate": 0}, r"run\.yaml: rate: must be > 0"),
    ({"rate": "fast"}, r"run\.yaml: rate: expected a number, got string 'fast'"),
    ({"problem": "missing.yaml"}, r"run\.yaml: problem: 'missing\.yaml' \(relative to the script\) does not exist"),
    ({"speed": 3}, r"run\.yaml: speed: unknown key"),
    ({"steps": []}, r"run\.yaml: steps: empty list"),
    ({"steps": ["relax"]}, r"run\.yaml: steps\[0\]: must be one of"),
    ({"steps": [{"jump": 1}]}, r"steps\[0\]: unknown step 'jump'"),
    ({"steps": [{"set": {"grip": 1}, "hold": 1}]}, r"steps\[0\]: must be one of"),
    ({"steps": ["release", {"set": {"grip": "lots"}}]}, r"steps\[1\]\.set\.grip: expected a number, got string 'lots'"),
    ({"steps": [{"hold": -1}]}, r"steps\[0\]\.hold: must be >= 0"),
    ({"steps": [{"pose": {"targets": []}}]}, r"steps\[0\]\.pose\.targets: empty list"),
    ({"steps": [{"pose": {"targets": [{"at": [0, 1]}]}}]}, r"steps\[0\]\.pose\.targets\[0\]\.to: missing required key"),
    ({"steps": [{"pose": {"targets": [{"at": [0], "to": [1, 2]}]}}]}, r"targets\[0\]\.at: expected a point \[x, y\], got a list of 1"),
    ({"steps": [{"pose": {"targets": [{"at": [0, 1], "to": [1, 2], "weight": 0}]}}]},
     r"targets\[0\]\.weight: must be > 0"),
    ({"steps": [{"pose": {"targets": [{"at": [0, 1], "to": [1, 2]}], "freeze": "grip"}}]},
     r"steps\[0\]\.pose\.freeze: expected a list of winch names"),
    ({"steps": [{"pose": {"targets": [{"at": [0, 1], "to": [1, 2]}], "max_time": 0}}]},
     r"steps\[0\]\.pose\.max_time: must be > 0"),
    ({"steps": [{"release": 3}]}, r"steps\[0\]\.release: takes no value"),
])
def test_bad_run_scripts(tmp_path, change, match):
    path = write_script(tmp_path, STEPS)
    doc = yaml.safe_load(path.read_text())
    doc.update(change)
    path.write_text(yaml.safe_dump(doc))
    with pytest.raises(SceneError, match=match):
        load_run_script(path)


@pytest.mark.parametrize("steps, match", [
    ([{"set": {"thumb": 1.0}}], r"steps\[0\]\.set: unknown winch 'thumb'"),
    ([{"set": {"grip": 21.0}}], r"steps\[0\]\.set\.grip: contraction 21 for winch 'grip' is outside .*\[0, 20\]"),
    ([{"set": {"left": 26.0}}], r"steps\[0\]\.set\.left: contraction 26 .* is outside .*\[0, 25\]"),  # scene: 30
    (["release", {"pose": {"targets": [{"at": [0, 1], "to": [1, 2]}], "freeze": ["x"]}}],
     r"steps\[1\]\.pose: unknown winch 'x'"),
])
def test_names_and_bounds_checked_before_any_port_is_opened(tmp_path, steps, match):
    planner = FakePlanner(upper=[30.0, 20.0, 20.0])
    with pytest.raises(SceneError, match=match):
        run_script(write_script(tmp_path, steps), port="/nonexistent/tty", planner=planner,
                   log_path=tmp_path / "log.jsonl")
    assert not (tmp_path / "log.jsonl").exists()


def test_problem_winch_missing_from_board(tmp_path):
    planner = FakePlanner(winch_names=("left", "thumb"))
    script = load_run_script(write_script(tmp_path, STEPS[:1]))
    with pytest.raises(SceneError, match=r"has no winch 'thumb' of problem"):
        check_run_script(script, planner, calibration_from_dict(fast_calibration_dict()))


def test_needs_a_planner_and_a_board(tmp_path):
    path = write_script(tmp_path, STEPS)
    with pytest.raises(TypeError, match="needs a planner"):
        run_script(path)
    with pytest.raises(HardwareError, match=r"no board to run on: give a serial port \(--port\)"):
        run_script(path, planner=FakePlanner())


# -------------------------------------------------------------- dry runs --

def test_dry_run_plans_logs_and_opens_nothing(tmp_path):
    planner = FakePlanner(steps=20)
    result = run_script(write_script(tmp_path, STEPS), port="/nonexistent/tty", dry_run=True, planner=planner,
                        log_path=tmp_path / "log.jsonl")
    assert result.dry_run and result.steps == 4 and result.contraction == {"left": 0.0, "right": 0.0, "grip": 0.0}
    log = read_log(tmp_path / "log.jsonl")
    assert log[0]["kind"] == "start" and log[0]["dry_run"] is True
    assert log[-1]["kind"] == "end" and log[-1]["status"] == "completed"
    commands = [r for r in log if r["event"] == "command"]
    assert len(commands) == result.commands >= 3
    assert all(r["measured"] is None and r["acknowledged"] is None for r in log)
    assert {r["kind"] for r in commands} == {"set", "pose", "release"}
    # The final pose iterate was sent, grip stayed frozen, ticks follow the calibration.
    last_pose = [r for r in commands if r["kind"] == "pose"][-1]
    assert last_pose["converged"] and last_pose["commanded"]["grip"] == 5.0
    assert last_pose["ticks"]["right"] == -round(last_pose["commanded"]["right"] * 1200 / (2 * 3.141592653589793 * 6))
    kinds = [c[0] for c in planner.calls]
    assert kinds[:3] == ["forward", "forward", "pose"]
    assert planner.calls[2][2] == ["grip"]


def test_a_stream_sends_every_certified_iterate_at_the_rate(tmp_path, make_emulator):
    # 60 iterates computed in ~0.3 s, streamed at 50 Hz: all 60 sent, in order,
    # at least a period apart (the board's own log times), the last the final pose.
    planner = FakePlanner(steps=60, delay=0.005, goal={"left": 12.0, "right": 6.0})
    steps = [{"pose": {"targets": [{"at": [0, 0], "to": [1, 1]}], "stream": True}}]
    run_script(write_script(tmp_path, steps, rate=50), port=make_emulator(3).port, planner=planner,
               log_path=tmp_path / "l.jsonl")
    log = read_log(tmp_path / "l.jsonl")
    sends = [r for r in log if r["event"] == "command"]
    assert [r["iteration"] for r in sends] == list(range(1, 61))
    assert sends[-1]["converged"] and sends[-1]["commanded"]["left"] == pytest.approx(12.0)
    assert all(b["t"] - a["t"] >= 0.0195 for a, b in zip(sends, sends[1:]))
    assert all(r["commanded"]["left"] == pytest.approx(12.0 * r["iteration"] / 60) for r in sends)


def test_examples_dry_run():
    for name in ("gripper", "hexapod"):
        problem = yaml.safe_load((ROOT / "problems" / f"{name}.yaml").read_text())
        names = [w["name"] for w in problem["winches"]]
        planner = FakePlanner(winch_names=names, lower=[w["bounds"][0] for w in problem["winches"]],
                              upper=[w["bounds"][1] for w in problem["winches"]])
        script = load_run_script(ROOT / "examples" / f"{name}_run.yaml")
        assert script.problem == ROOT / "problems" / f"{name}.yaml"
        result = run_script(script, dry_run=True, planner=planner, log_path=os.devnull)
        assert result.steps == len(script.steps)


# ---------------------------------------------------------- on the board --

def test_run_on_the_emulator(tmp_path, emulator):
    planner = FakePlanner(steps=15, delay=0.005, goal={"left": 8.0, "right": 4.0})
    result = run_script(write_script(tmp_path, STEPS), port=emulator.port, planner=planner,
                        log_path=tmp_path / "log.jsonl")
    assert not result.dry_run and result.steps == 4
    log = read_log(tmp_path / "log.jsonl")
    # Each command's line is written before it is sent; the board's OK follows.
    replies = [(a, b) for a, b in zip(log, log[1:]) if a["event"] == "command"]
    assert len(replies) == result.commands >= 3
    for command, reply in replies:
        assert command["acknowledged"] is None
        assert reply["event"] == "acknowledged" and reply["acknowledged"] is True
        assert reply["commanded"] == command["commanded"] and reply["ticks"] == command["ticks"]
    arrived = {r["kind"]: r for r in log if r["event"] == "arrived"}
    assert arrived.keys() == {"set", "pose", "release"}
    assert arrived["pose"]["measured"]["left"] == pytest.approx(8.0, abs=0.05)
    assert arrived["pose"]["measured"]["right"] == pytest.approx(4.0, abs=0.05)
    assert arrived["pose"]["measured"]["grip"] == pytest.approx(5.0, abs=0.05)
    assert arrived["release"]["measured"]["left"] == pytest.approx(0.0, abs=0.05)
    assert [r["kind"] for r in log if r["kind"] == "hold"] and log[-1]["status"] == "completed"
    state = emulator.read_state()
    assert state["enabled"] == [False] * 3 and not any(state["moving"])


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["emulator", "simavr"])
def test_gripper_run_arrives_within_tolerance(tmp_path, request, kind):
    """The shipped run, as a user starts it: every arrival in its log has
    every winch within the calibration's tolerance of its command."""
    request.getfixturevalue("emu_binary" if kind == "emulator" else "sim_binaries")  # built, or fail saying how
    log_path = tmp_path / "run.jsonl"
    r = subprocess.run([sys.executable, "-m", "plush_opt", "run", "examples/gripper_run.yaml", f"--{kind}",
                        "--log", str(log_path)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    log = read_log(log_path)
    calibration = load_calibration(ROOT / "hw" / "boards" / "gripper.yaml")
    arrived = [e for e in log if e["event"] == "arrived"]
    script = load_run_script(ROOT / "examples" / "gripper_run.yaml")
    assert len(arrived) == sum(step.kind in ("set", "pose", "release") for step in script.steps)
    for e in arrived:
        for name, commanded in e["commanded"].items():
            tolerance = calibration.winch(name).tolerance
            assert e["tolerance"][name] == pytest.approx(tolerance)
            assert abs(e["measured"][name] - commanded) <= tolerance + 1e-9, (name, e)
            assert e["error"][name] == pytest.approx(e["measured"][name] - commanded)
    assert log[-1]["status"] == "completed"


class OffsetLink(SerialLink):
    """A board that says it has arrived but reads ``offset`` mm off every command."""

    def __init__(self, port, calibration, offset):
        super().__init__(port, calibration)
        self.offset, self.now = offset, 0.0

    def positions(self):
        return {n: v + self.offset for n, v in super().positions().items()}

    def clock(self):
        self.now += 0.1  # each look at the clock 0.1 s later: the wait ends within a few dozen polls
        return self.now


def test_an_arrival_outside_the_tolerance_is_an_error(tmp_path, emulator, calibration):
    tolerance = calibration.winch("left").tolerance
    with OffsetLink(emulator.port, calibration, offset=3 * tolerance) as board:
        with pytest.raises(HardwareError, match=r"steps\[0\]\.set: winch '\w+' did not reach .* tolerance "
                                                r".*the board holds it there"):
            run_script(write_script(tmp_path, [{"set": {"left": 3.0}}]), board=board, planner=FakePlanner(),
                       log_path=tmp_path / "log.jsonl")
    log = read_log(tmp_path / "log.jsonl")
    assert not [e for e in log if e["event"] == "arrived"] and log[-1]["status"].startswith("error:")


def test_run_with_an_open_link_keeps_it_open(tmp_path, emulator, calibration):
    with SerialLink(emulator.port, calibration) as board:
        run_script(write_script(tmp_path, [{"set": {"left": 3.0}}]), board=board, planner=FakePlanner(),
                   log_path=tmp_path / "log.jsonl")
        assert board.driver.is_open and emulator.read_state()["enabled"] == [False] * 3   # stopped, not closed
        assert board.positions()["left"] == pytest.approx(3.0, abs=0.05)


class ExplodingPlanner(FakePlanner):
    def pose(self, targets, freeze, max_time):
        it = super().pose(targets, freeze, max_time)
        yield next(it)
        yield next(it)
        raise RuntimeError("solver blew up")


def test_planner_failure_stops_the_board_and_ends_the_log(tmp_path, make_emulator):
    emu = make_emulator(3, speed=300.0)
    planner = ExplodingPlanner(steps=4, goal={"left": 20.0})
    with pytest.raises(RuntimeError, match="solver blew up"):
        run_script(write_script(tmp_path, STEPS[1:2]), port=emu.port, planner=planner,
                   log_path=tmp_path / "log.jsonl")
    log = read_log(tmp_path / "log.jsonl")
    assert log[-1]["kind"] == "end" and log[-1]["status"] == "error: solver blew up"
    assert emu.read_state()["enabled"] == [False] * 3


class SilentPlanner(FakePlanner):
    def pose(self, targets, freeze, max_time):
        time.sleep(30)
        yield from ()


def test_a_planner_that_never_finishes_is_an_error(tmp_path, monkeypatch):
    monkeypatch.setattr("plush_opt.apps.runs.PLANNER_GRACE", 0.1)
    steps = [{"pose": {"targets": [{"at": [0, 0], "to": [1, 1]}], "max_time": 0.1}}]
    with pytest.raises(SolverError, match=r"steps\[0\]\.pose: the planner did not finish within 0\.3 s"):
        run_script(write_script(tmp_path, steps), dry_run=True, planner=SilentPlanner(), log_path=os.devnull)


@pytest.mark.slow
def test_sigint_mid_move_stops_the_board_and_leaves_a_parseable_log(tmp_path, make_emulator):
    emu = make_emulator(3, speed=400.0)    # slow: the winches are mid-move when interrupted
    cal = fast_calibration_dict()
    for w in cal["winches"]:
        w["max_speed"] = 2.0   # mm/s: slower than the planner moves the targets
    script = write_script(tmp_path, [{"pose": {"targets": [{"at": [0, 0], "to": [1, 1]}], "max_time": 30,
                                               "stream": True}}], rate=20, calibration=cal)
    log_path = tmp_path / "log.jsonl"
    child = subprocess.Popen([sys.executable, str(Path(__file__).with_name("sigint_child.py")), str(script),
                              emu.port, str(log_path)], stderr=subprocess.PIPE, text=True,
                             preexec_fn=default_sigint)
    try:
        def sending():
            if not log_path.exists():
                return False
            return sum('"event":"command"' in line for line in log_path.read_text().splitlines()) >= 5
        assert wait_until(sending, timeout=10), child.stderr.read() if child.poll() is not None else "no commands"
        before = emu.read_state()
        assert any(before["moving"]), before
        child.send_signal(signal.SIGINT)
        assert child.wait(10) == 130, child.stderr.read()
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    state = emu.read_state()
    assert state["enabled"] == [False] * 3 and not any(state["moving"])
    assert state["stops"]["command"] >= before["stops"]["command"] + 1   # the driver sent STOP
    assert state["stops"]["watchdog"] == 0
    time.sleep(0.1)
    assert emu.read_state()["ticks"] == state["ticks"]
    log = read_log(log_path)
    assert log[-1]["kind"] == "end" and log[-1]["status"] == "interrupted"


# ------------------------------------------------------------------- CLI --

def test_cli_arguments():
    parser = add_run_arguments(argparse.ArgumentParser(prog="plush-opt run"))
    args = parser.parse_args(["x.yaml", "--emulator", "--log", "l.jsonl"])
    assert args.script == Path("x.yaml") and args.emulator and not args.dry_run and args.port is None
    for clash in (["--emulator", "--port", "/dev/ttyACM0"], ["--simavr", "--emulator"], ["--simavr", "--port", "p"]):
        with pytest.raises(SystemExit):
            parser.parse_args(["x.yaml", *clash])
    assert parser.parse_args(["x.yaml", "--simavr"]).simavr
    assert parser.parse_args(["x.yaml", "--port", "/dev/ttyACM0", "--dry-run"]).dry_run


def test_cli_run_on_the_emulator_and_dry(tmp_path, emu_binary, capsys):
    parser = add_run_arguments(argparse.ArgumentParser())
    script = write_script(tmp_path, [{"set": {"left": 2.0}}, "release"])
    seen = []

    def factory(problem):
        seen.append(problem)
        return FakePlanner()
    for i, flags in enumerate((["--emulator"], ["--dry-run"], ["--emulator", "--dry-run"])):
        log = tmp_path / f"log{i}.jsonl"
        assert cli_run(parser.parse_args([str(script), *flags, "--log", str(log)]), factory) == 0
        assert read_log(log)[-1]["status"] == "completed"
        assert read_log(log)[0]["dry_run"] is ("--dry-run" in flags)
    assert seen == [tmp_path / "problem.yaml"] * 3
    err = capsys.readouterr().err
    assert "completed on emulator" in err and "completed on dry run" in err


# ------------------------------------------------ a board that goes silent --

def _answers_all_but_moves(line):
    """A fake three-axis board that answers everything except SET/SETALL."""
    seq, command = line.split()[:2]
    if command in ("SET", "SETALL"):
        return None
    if command == "ID":
        return [f"{seq} OK board=fake fw=0 proto=1 winches=3\n".encode()]
    if command == "GET":
        return [f"{seq} OK pos=0,0,0 tgt=0,0,0 mov=0,0,0 en=0,0,0 wd=0\n".encode()]
    return [f"{seq} OK\n".encode()]


def test_the_command_line_is_logged_before_the_board_answers(tmp_path, fake_board):
    board = fake_board(_answers_all_but_moves)
    with pytest.raises(HardwareError, match=r"no reply from the board to SETALL after 2 attempt\(s\)"):
        run_script(write_script(tmp_path, [{"set": {"left": 2.0}}]), port=board.port, planner=FakePlanner(),
                   log_path=tmp_path / "log.jsonl")
    log = read_log(tmp_path / "log.jsonl")
    assert [r["event"] for r in log] == ["start", "command", "end"]
    assert log[1]["commanded"]["left"] == 2.0 and log[1]["acknowledged"] is None
    assert log[-1]["status"].startswith("error: ") and log[-1]["commands"] == 0
    assert any(line.split()[1] == "STOP" for line in board.received[-2:])   # stopped after all
