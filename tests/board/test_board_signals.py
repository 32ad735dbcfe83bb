"""Signals at several points of a run, through the CLI's signal policy.

SIGTERM, SIGHUP and SIGINT, each at the start (the board open, no command
yet), mid-move (a pose step streaming) and during a hold: the process exits
128 + signum, the driver has sent STOP and the board is stopped, no
simulator process outlives the run, and every line of the log parses, the
last saying how the run ended.
"""

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
from plush_opt.io.run_script import FORMAT

pytestmark = pytest.mark.slow  # each runs and interrupts a command-line run

CHILD = Path(__file__).with_name("cli_child.py")
SIGNALS = ("SIGTERM", "SIGHUP", "SIGINT")
# streamed, so that the run is still sending commands when the signal comes
POSE = {"pose": {"targets": [{"at": [0, 0], "to": [1, 1]}], "max_time": 30, "stream": True}}
#: point of the run -> (steps, predicate on the log lines so far)
POINTS = {
    "start": ([POSE], lambda lines: lines is not None and len(lines) == 0),
    "mid-move": ([POSE], lambda lines: lines is not None and sum(r["event"] == "command" for r in lines) >= 5),
    "hold": ([{"set": {"grip": 1.0}}, {"hold": 30}],
             lambda lines: lines is not None and any(r["kind"] == "hold" for r in lines)),
}


def _script(folder: Path, steps) -> Path:
    cal = fast_calibration_dict()
    for w in cal["winches"]:
        w["max_speed"] = 2.0       # mm/s: still moving when the signal comes
    (folder / "problem.yaml").write_text("format: plush-opt/1\n")
    (folder / "board.yaml").write_text(yaml.safe_dump(cal))
    path = folder / "run.yaml"
    path.write_text(yaml.safe_dump({"format": FORMAT, "problem": "problem.yaml", "board": "board.yaml",
                                    "rate": 20, "steps": steps}, sort_keys=False))
    return path


def _lines(path: Path):
    """Complete lines of the log so far (None before it exists)."""
    if not path.exists():
        return None
    text = path.read_text()
    return [json.loads(line) for line in text[:text.rfind("\n") + 1].splitlines()]


def _children(pid: int) -> list[int]:
    out = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                stat = Path("/proc", entry, "stat").read_text()
            except OSError:
                continue
            if int(stat[stat.rfind(")") + 2:].split()[1]) == pid:
                out.append(int(entry))
    return out


def _alive(pid: int) -> bool:
    try:
        stat = Path("/proc", str(pid), "stat").read_text()
    except OSError:
        return False
    return stat[stat.rfind(")") + 2] != "Z"


def _interrupt(tmp_path, point, name, board_args, board_open=None):
    """``board_open()``: true once the board has heard from the run (the
    log is created before the port is opened: without it a signal at the
    start could land before there is a board to stop)."""
    steps, ready = POINTS[point]
    log = tmp_path / "run.jsonl"
    child = subprocess.Popen([sys.executable, str(CHILD), str(_script(tmp_path, steps)), str(log), *board_args],
                             stderr=subprocess.PIPE, text=True, preexec_fn=default_sigint)
    try:
        assert wait_until(lambda: ready(_lines(log)) and (board_open is None or board_open()), timeout=20), \
            child.stderr.read() if child.poll() is not None else f"never reached {point}"
        if board_open is not None:
            time.sleep(0.3)         # the rest of the handshake (the run then sleeps 1.5 s in its first solve)
        children = _children(child.pid)
        child.send_signal(getattr(signal, name))
        code = child.wait(20)
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
    stderr = child.stderr.read()
    return code, stderr, _lines(log), children


@pytest.mark.parametrize("point", sorted(POINTS))
@pytest.mark.parametrize("name", SIGNALS)
def test_a_signal_stops_the_board_and_ends_the_log(tmp_path, make_emulator, name, point):
    emu = make_emulator(3, speed=400.0)
    before = emu.read_state()
    code, stderr, lines, _ = _interrupt(tmp_path, point, name, ["--port", emu.port],
                                        lambda: emu.read_state()["lines"] > before["lines"])
    assert code == 128 + getattr(signal, name), stderr
    assert f"interrupted ({name})" in stderr and "Traceback" not in stderr, stderr
    assert lines[-1]["kind"] == "end" and lines[-1]["status"] == "interrupted", lines[-1]
    assert lines[-1]["signal"] == name
    state = emu.read_state()
    assert state["enabled"] == [False] * 3 and not any(state["moving"]), state
    assert state["stops"]["command"] >= before["stops"]["command"] + 1     # the driver sent STOP
    assert state["stops"]["watchdog"] == 0


@pytest.mark.parametrize("name", SIGNALS)
def test_a_signal_leaves_no_simulator_behind(tmp_path, emu_binary, name):
    code, stderr, lines, children = _interrupt(tmp_path, "mid-move", name, ["--emulator"])
    assert code == 128 + getattr(signal, name), stderr
    assert children, "the run started no simulator"
    assert wait_until(lambda: not any(_alive(pid) for pid in children), timeout=5), children
    assert lines[-1]["kind"] == "end" and lines[-1]["status"] == "interrupted"
