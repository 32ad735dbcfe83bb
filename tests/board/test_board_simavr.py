"""The real firmware binary on simavr: its build and its motor loop (the
shared protocol cases are in test_board_emulator.py, whole runs in
test_board_runs.py).

These are real time (simavr keeps the simulated clock at the wall clock).
"""

import re
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from board_helpers import wait_until
from plush_opt.board import protocol as P
from plush_opt.board.simavr import DEADBAND, SimavrBoard
from plush_opt.base.errors import HardwareError

ROOT = Path(__file__).resolve().parents[2]
HW = ROOT / "hw"


def _get(port, seq, axes=4):
    reply = P.parse_reply(port.ask(f"{seq} GET"))
    assert reply.ok, reply
    return P.parse_state(reply.payload, axes)


@pytest.mark.slow
def test_firmware_builds_for_the_mega_and_reports_its_size():
    if shutil.which("avr-gcc") is None:
        pytest.fail("avr-gcc not found: the firmware needs gcc-avr avr-libc binutils-avr arduino-core-avr "
                    "(make firmware-deps)", pytrace=False)
    r = subprocess.run(["make", "-s", "-C", str(HW), "firmware"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "Device: atmega2560" in r.stdout and "Program:" in r.stdout and "Data:" in r.stdout
    assert (HW / "firmware" / "build" / "plush_winch.hex").read_text().startswith(":")
    # docs/hardware.md's size table is this report's
    doc = (ROOT / "docs" / "hardware.md").read_text()
    for memory, label in (("flash", "Program"), ("RAM", "Data")):
        used, share = re.search(rf"{label}:\s+(\d+) bytes \(([\d.]+)% Full\)", r.stdout).groups()
        assert f"| {memory} (" in doc and re.search(rf"\| {memory} \(.*\| {int(used):,} bytes \({share} %\)", doc), \
            f"docs/hardware.md: the {memory} row should say {int(used):,} bytes ({share} %)"


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


@pytest.mark.slow
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
