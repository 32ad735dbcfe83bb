"""Overshoot of the board's motion control: a sweep of speeds and move
patterns on the emulator and on the firmware under simavr.

Usage: python tools/board_overshoot.py [--board emulator|simavr|both]

For each simulated motor of MOTORS, the four axes of one board get four
speed limits (SPEED, ticks/s, from 1, the slowest a board file can ask,
to 1,000,000, the protocol's fastest) and the same move pattern, scaled
to each axis (PATTERN: moves, a move back, moves to both soft limits, a
hold, two reversals mid-move, a return to 0). Every command opens a
window of position extremes in the simulator (``Emulator.new_window``);
the overshoot of a command is how far the encoder count went past its
target, away from where the axis stood when it was sent. Prints one row
per board, motor and speed: the worst overshoot and the worst excursion
past a soft limit. ``tests/board/test_board_overshoot.py`` runs the same
sweep and asserts: never past a target by more than the deadband, never
past a soft limit. docs/hardware.md records this table.
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from plush_opt.board import protocol as P  # noqa: E402
from plush_opt.board.emulator import Emulator  # noqa: E402
from plush_opt.board.simavr import SimavrBoard  # noqa: E402

import serial  # noqa: E402

AXES = 4
DEADBAND = 3            # ticks: the firmware's, and the emulator is started with it
TAU = 0.02              # s: motor time constant on both boards
MOVE_TIME = 0.6         # s: each axis' amplitude is what its speed covers in this time ...
AMPLITUDE = (4, 300)    # ticks: ... within these bounds (4: more than the deadband)
ARRIVE_TIMEOUT = 30.0   # s: a segment's wait for every axis to arrive

# motor speed at full PWM (ticks/s), the four axes' SPEED, and how long a
# reversal lets the axes run before turning them (about half the fastest travel)
MOTORS = {
    "slow": (96.0, (1, 10, 48, 1_000_000), 0.6),
    "fast": (10_000.0, (300, 3000, 10_000, 1_000_000), 0.04),
}
# (fraction of the amplitude, then wait: "arrive" or seconds); the soft limits are [-A, A]
PATTERN = (
    (0.42, "arrive"), (0.13, "arrive"), (-1.0, "arrive"), (-1.0, 0.3),
    (1.0, "reversal"), (-1.0, "reversal"), (1.0, "arrive"), (0.0, "arrive"),
)


@dataclass
class Segment:
    """One command on one axis and what the axis did until the next."""
    target: int
    start: int
    low: int = 0
    high: int = 0

    def overshoot(self) -> int:
        """Ticks past the target, away from the start (both ways for a hold)."""
        up = self.high - self.target
        down = self.target - self.low
        if self.target > self.start:
            return up
        if self.target < self.start:
            return down
        return max(up, down)


@dataclass
class AxisResult:
    speed: int
    amplitude: int
    segments: list = field(default_factory=list)
    low: int = 0
    high: int = 0

    def worst(self) -> int:
        return max(s.overshoot() for s in self.segments)

    def past_limit(self) -> int:
        return max(0, self.high - self.amplitude, -self.amplitude - self.low)


def amplitude(speed: int, motor: float) -> int:
    lo, hi = AMPLITUDE
    return int(min(hi, max(lo, round(min(speed, motor) * MOVE_TIME))))


class _Port:
    def __init__(self, path):
        self.ser = serial.Serial(path, 115200, timeout=1.0)
        self.seq = 0

    def ask(self, command: str) -> str:
        self.seq = self.seq % 65535 + 1
        self.ser.write(f"{self.seq} {command}\n".encode())
        reply = P.parse_reply(self.ser.readline())
        if not reply.ok or reply.seq != self.seq:
            raise RuntimeError(f"board refused {command!r}: {reply}")
        return reply.payload

    def moving(self) -> bool:
        return any(P.parse_state(self.ask("GET"), AXES).moving)


def _wait(port, how, reversal):
    if how == "arrive":
        deadline = time.monotonic() + ARRIVE_TIMEOUT
        while port.moving():
            if time.monotonic() > deadline:
                raise RuntimeError(f"axes did not arrive within {ARRIVE_TIMEOUT} s")
            time.sleep(0.01)
        return
    end = time.monotonic() + (reversal if how == "reversal" else how)
    while time.monotonic() < end:
        port.ask("PING")
        time.sleep(0.005)


def run_motor(sim, motor: str) -> list[AxisResult]:
    """The pattern on the four axes of a started board ``sim`` with motor ``motor``."""
    top, speeds, reversal = MOTORS[motor]
    results = [AxisResult(s, amplitude(s, top)) for s in speeds]
    port = _Port(sim.port)
    try:
        for a, r in enumerate(results):
            port.ask(f"LIMIT {a} {-r.amplitude} {r.amplitude}")
            port.ask(f"SPEED {a} {r.speed}")
        open_segments = None
        for fraction, how in PATTERN:
            closed = sim.new_window()
            if open_segments is not None:
                _close(open_segments, closed)
            now = sim.read_state()["ticks"]
            targets = [round(fraction * r.amplitude) for r in results]
            open_segments = [Segment(t, now[a]) for a, t in enumerate(targets)]
            for r, s in zip(results, open_segments):
                r.segments.append(s)
            port.ask("SETALL " + " ".join(map(str, targets)))
            _wait(port, how, reversal)
        _close(open_segments, sim.new_window())
        state = sim.read_state()
        for a, r in enumerate(results):
            r.low, r.high = state["min_ticks"][a], state["max_ticks"][a]
        port.ask("STOP")
    finally:
        port.ser.close()
    return results


def _close(segments, closed):
    for a, s in enumerate(segments):
        s.low, s.high = closed["min"][a], closed["max"][a]


def start_board(kind: str, motor: str, **kw):
    """A started 4-axis board of ``kind`` with the motor ``motor`` of MOTORS."""
    top = MOTORS[motor][0]
    if kind == "emulator":
        sim = Emulator(AXES, speed=top, tau=TAU, deadband=DEADBAND, **kw)
    else:
        sim = SimavrBoard(AXES, speed=top, tau=TAU, **kw)
    sim.start()
    return sim


def sweep(kind: str) -> list[tuple[str, AxisResult]]:
    rows = []
    for motor in MOTORS:
        sim = start_board(kind, motor)
        try:
            rows += [(motor, r) for r in run_motor(sim, motor)]
        finally:
            sim.close()
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--board", choices=("emulator", "simavr", "both"), default="both")
    args = ap.parse_args(argv)
    kinds = ("emulator", "simavr") if args.board == "both" else (args.board,)
    print(f"| board | motor (ticks/s) | SPEED (ticks/s) | amplitude (ticks) | worst overshoot (ticks; < 0: short of every target) "
          f"| past a soft limit (ticks) |")
    print("|---|---:|---:|---:|---:|---:|")
    for kind in kinds:
        for motor, r in sweep(kind):
            print(f"| {kind} | {MOTORS[motor][0]:.0f} | {r.speed} | {r.amplitude} | {r.worst()} "
                  f"| {r.past_limit()} |")
    print(f"\ndeadband {DEADBAND} ticks, motor time constant {TAU} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
