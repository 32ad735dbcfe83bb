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
import sys
from pathlib import Path

import pytest

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
