"""The motion control never passes its target by more than the deadband nor a
soft limit at all: a sweep of speeds (SPEED 1, the slowest a board file can
ask, to 1,000,000) and move patterns (moves, a move back, moves to both soft
limits, a hold, reversals mid-move) against a slow and a fast motor, on the
firmware under simavr and on the emulator, which runs the firmware's own
control law against the same motor model. The sweep is
tools/board_overshoot.py's (it prints the table docs/hardware.md records).

Real time: about 20 s per board.
"""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

from plush_opt.board import load_calibration

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location("board_overshoot", ROOT / "tools" / "board_overshoot.py")
overshoot = importlib.util.module_from_spec(_spec)
sys.modules.setdefault("board_overshoot", overshoot)   # its dataclasses look their module up
_spec.loader.exec_module(overshoot)


def _violations(motor, results):
    found = []
    for r in results:
        for i, s in enumerate(r.segments):
            if s.overshoot() > overshoot.DEADBAND:
                found.append(f"{motor} motor, SPEED {r.speed}: command {i} ({s.start} -> {s.target}) went "
                             f"{s.overshoot()} ticks past its target (window {s.low}..{s.high})")
        if r.past_limit() > 0:
            found.append(f"{motor} motor, SPEED {r.speed}: reached {r.low}..{r.high}, "
                         f"beyond the soft limits [{-r.amplitude}, {r.amplitude}]")
    return found


@pytest.mark.slow
@pytest.mark.parametrize("motor", list(overshoot.MOTORS))
@pytest.mark.parametrize("kind", ["emulator", "simavr"])
def test_no_overshoot_past_target_or_soft_limit(kind, motor, emu_binary, sim_binaries):
    extra = {"binary": emu_binary} if kind == "emulator" else {"binary": sim_binaries[0],
                                                              "firmware": sim_binaries[1]}
    sim = overshoot.start_board(kind, motor, **extra)
    try:
        results = overshoot.run_motor(sim, motor)
    finally:
        sim.close()
    assert _violations(motor, results) == []


SLOW_RUN = """format: plush-opt-run/1
problem: {root}/problems/gripper.yaml
board: {board}
rate: 20
steps:
  - set: {{left: 4.0, grip: 1.8}}
  - set: {{left: 1.26, grip: 0.56}}
  - set: {{left: 0.0, grip: 0.0}}
"""


@pytest.mark.slow
@pytest.mark.parametrize("kind", ["emulator", "simavr"])
def test_a_slow_run_ends_on_its_targets_and_never_below_the_lower_limit(tmp_path, request, kind):
    """The gripper's board file with max_speed 1.508 mm/s (48 ticks/s on
    `left`): 0 -> 4 -> 1.26 -> 0 mm, the last move to the lower limit. The
    firmware used to end these at 138, 31 and -11 ticks, and the run
    exited 4 at -0.314 mm."""
    request.getfixturevalue("emu_binary" if kind == "emulator" else "sim_binaries")
    text = (ROOT / "hw" / "boards" / "gripper.yaml").read_text()
    board = tmp_path / "slow.yaml"
    board.write_text(text.replace("max_speed: 15.0", "max_speed: 1.508").replace("max_speed: 10.0", "max_speed: 0.67"))
    script = tmp_path / "run.yaml"
    script.write_text(SLOW_RUN.format(root=ROOT, board=board))
    log_path = tmp_path / "run.jsonl"
    r = subprocess.run([sys.executable, "-m", "plush_opt", "run", str(script), f"--{kind}", "--log", str(log_path)],
                       capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    log = [json.loads(line) for line in log_path.read_text().splitlines()]
    calibration = load_calibration(board)
    assert all(e["measured"]["left"] >= 0.0 and e["measured"]["grip"] >= 0.0 for e in log if e["measured"]), log
    arrived = [e for e in log if e["event"] == "arrived"]
    assert len(arrived) == 3 and log[-1]["status"] == "completed"
    for e in arrived:
        for name, commanded in e["commanded"].items():
            # the 3-tick deadband and half a tick of rounding
            assert abs(e["measured"][name] - commanded) <= 3.5 / calibration.winch(name).ticks_per_mm, (name, e)
