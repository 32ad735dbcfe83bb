"""The real firmware binary on simavr: its build, its motor loop, and a
whole run's contractions played through the host driver.

These are real time (simavr keeps the simulated clock at the wall clock).
"""

import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from board_helpers import wait_until
from plush_opt.board import Driver, load_calibration
from plush_opt.board import protocol as P
from plush_opt.board.simavr import DEADBAND, SimavrBoard
from plush_opt.errors import HardwareError

ROOT = Path(__file__).resolve().parents[2]
HW = ROOT / "hw"


def _get(port, seq, axes=4):
    reply = P.parse_reply(port.ask(f"{seq} GET"))
    assert reply.ok, reply
    return P.parse_state(reply.payload, axes)


def test_firmware_builds_for_the_mega_and_reports_its_size():
    if shutil.which("avr-gcc") is None:
        pytest.fail("avr-gcc not found: the firmware needs gcc-avr avr-libc binutils-avr arduino-core-avr "
                    "(make firmware-deps)", pytrace=False)
    r = subprocess.run(["make", "-s", "-C", str(HW), "firmware"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Device: atmega2560" in r.stdout and "Program:" in r.stdout and "Data:" in r.stdout
    assert (HW / "firmware" / "build" / "plush_winch.hex").read_text().startswith(":")


def test_missing_avr_toolchain_is_named_with_the_fix(tmp_path):
    r = subprocess.run(["make", "-s", "-C", str(HW), "firmware", "AVR_CXX=no-such-avr-g++",
                        f"FW_BUILD={tmp_path}/fw"], capture_output=True, text=True, timeout=60)
    assert r.returncode != 0
    assert "no-such-avr-g++" in r.stderr and "make firmware-deps" in r.stderr
    assert not (tmp_path / "fw").exists()


def test_simavr_board_refuses_what_the_firmware_fixes(sim_binaries, tmp_path):
    with pytest.raises(HardwareError, match="winches must be 1..4"):
        SimavrBoard(5, binary=sim_binaries[0], firmware=sim_binaries[1])
    with pytest.raises(HardwareError, match="built in"):
        SimavrBoard(2, watchdog_ms=500, binary=sim_binaries[0], firmware=sim_binaries[1])
    with pytest.raises(HardwareError, match=r"board firmware not built: .*make -C hw firmware simavr"):
        SimavrBoard(2, binary=sim_binaries[0], firmware=tmp_path / "none.elf")


def test_exits_cleanly_on_sigterm(make_simavr, raw_port):
    sim = make_simavr(1)
    assert raw_port(sim.port).ask("1 PING") == "1 OK"
    assert sim.stop() == 0


def test_stalled_motor_at_the_deadband_is_not_driven(make_simavr, raw_port):
    """A target exactly DEADBAND ticks away counts as arrived for the watchdog
    (the core: moving means |error| > deadband), so the firmware must hold
    there too, not drive a motor it can no longer stop by the watchdog."""
    sim = make_simavr(1, extra_args=["--deadzone", "0.5"])  # a load the PID's full output cannot turn
    port = raw_port(sim.port)
    assert port.ask(f"1 LIMIT 0 0 {DEADBAND}") == f"1 OK lo=0 hi={DEADBAND}"
    assert port.ask(f"2 SET 0 {DEADBAND}") == "2 OK"
    time.sleep(1.0)  # long enough for a driving PID's integral to wind up
    state = _get(port, 3)
    assert state.position[0] == 0 and not state.moving[0] and state.enabled[0]
    true = sim.read_state()
    assert abs(true["drive"][0]) < 0.05, true  # holding, not pushing against the stall


def test_reference_moves_at_large_tick_counts(make_simavr, raw_port):
    """Above 2^24 ticks a float reference cannot advance ~1 tick per control cycle."""
    start = 100_000_000
    sim = make_simavr(1, extra_args=["--encoder-start", str(start)])
    port = raw_port(sim.port)
    assert wait_until(lambda: _get(port, 1).position[0] == start, timeout=2.0)
    assert port.ask(f"2 LIMIT 0 0 {2 * start}") == f"2 OK lo=0 hi={2 * start}"
    assert port.ask(f"3 SET 0 {start + 300}") == "3 OK"
    assert wait_until(lambda: abs(_get(port, 4).position[0] - start - 300) <= DEADBAND, timeout=3.0)
    assert sim.read_state()["ticks"][0] > start + 250


def _run_contractions(tmp_path):
    """The contractions the gripper run commands, from a dry run of it."""
    log = tmp_path / "run.jsonl"
    r = subprocess.run([sys.executable, "-m", "plush_opt", "run", str(ROOT / "examples" / "gripper_run.yaml"),
                        "--dry-run", "--log", str(log)], capture_output=True, text=True, timeout=300, cwd=ROOT)
    assert r.returncode == 0, r.stdout + r.stderr
    events = [json.loads(line) for line in log.read_text().splitlines()]
    return [e["commanded"] for e in events if e["event"] == "command"]


def _settled(driver, reads=4, interval=0.1):
    """Not moving, and standing still, over a few reads (a motor can pass its deadband and coast on)."""
    states = []
    for _ in range(reads):
        states.append(driver.read_state())
        time.sleep(interval)
    return not any(s.any_moving for s in states) and len({s.position for s in states}) == 1


def test_gripper_run_contractions_are_reached_on_the_firmware(make_simavr, tmp_path):
    calibration = load_calibration(HW / "boards" / "gripper.yaml")
    # mm: the arrival deadband plus the half tick of rounding a contraction to ticks
    tolerance = {w.name: (DEADBAND + 0.5) / w.ticks_per_mm for w in calibration.winches}
    top = 2 * max(w.speed_ticks for w in calibration.winches)  # as plush-opt run starts its boards
    sim = make_simavr(calibration.n_axes_required, speed=top)
    played, last_ticks = 0, None
    with Driver(sim.start(), calibration) as board:
        for commanded in _run_contractions(tmp_path):
            ticks = calibration.to_ticks(commanded)   # set_contractions checks the limits
            if last_ticks is not None and all(abs(ticks[n] - last_ticks[n]) <= DEADBAND for n in ticks):
                continue  # the same pose to within the deadband: nothing to see
            last_ticks = ticks
            board.set_contractions(commanded)
            assert wait_until(lambda: _settled(board), timeout=10.0), commanded
            measured = board.read_positions()
            for name, c in commanded.items():
                assert abs(measured[name] - c) <= tolerance[name] + 1e-9, (name, c, measured)
            played += 1
    assert played >= 8
    state = sim.read_state()
    assert state["enabled"] == [False] * 3  # the driver stopped the board on closing
