"""The board links behind open_board: dry run, the emulator, a serial port."""

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from board_helpers import fast_calibration_dict, wait_until
from plush_opt.board import DryRunLink, SerialLink, SimulatorLink, calibration_from_dict, open_board
from plush_opt.base.errors import HardwareError


def children() -> set[int]:
    """Process ids of this process's children (Linux)."""
    pids = set()
    for task in Path("/proc/self/task").iterdir():
        pids.update(int(p) for p in (task / "children").read_text().split())
    return pids


def alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except FileNotFoundError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"   # a zombie has exited


def test_dry_run_checks_and_records_and_moves_nothing(calibration):
    with open_board(calibration, bounds={"grip": (0.0, 20.0)}) as link:
        assert isinstance(link, DryRunLink) and link.winch_names == ("left", "right", "grip")
        link.send({"left": 2.0, "grip": 5.0})
        link.send({"grip": 20.0})
        with pytest.raises(HardwareError, match=r"contraction 20\.5 for winch 'grip' is outside"):
            link.send({"left": 1.0, "grip": 20.5})
        with pytest.raises(HardwareError, match=r"contraction '3' for winch 'left' is not a finite number"):
            link.send({"left": "3"})
        assert link.sent == [({"left": 2.0, "grip": 5.0}, calibration.to_ticks({"left": 2.0, "grip": 5.0})),
                             ({"grip": 20.0}, calibration.to_ticks({"grip": 20.0}))]
        assert link.commanded == {"left": 2.0, "grip": 20.0}
        assert link.positions() is None and not link.moving()
        link.stop()
    assert link.closed and link.stops == 1


def test_open_board_takes_a_calibration_file(tmp_path):
    path = tmp_path / "board.yaml"
    path.write_text(yaml.safe_dump(fast_calibration_dict()))
    link = open_board(path)
    assert isinstance(link, DryRunLink) and link.calibration.source == str(path)


def test_open_board_refuses_unclear_requests(calibration):
    with pytest.raises(HardwareError, match=r"give a serial port or a simulator, not both"):
        open_board(calibration, port="/dev/ttyACM0", simulator="emulator")
    with pytest.raises(HardwareError, match=r"simulator: must be one of 'emulator', 'simavr', got 'qemu'"):
        open_board(calibration, simulator="qemu")
    with pytest.raises(HardwareError, match=r"scene winch 'thumb' is not calibrated"):
        open_board(calibration, bounds={"thumb": (0.0, 1.0)})
    with pytest.raises(HardwareError, match=r"cannot open serial port /nonexistent/tty"):
        open_board(calibration, port="/nonexistent/tty")


def test_emulator_link_moves_the_emulated_winches(calibration, emu_binary):
    before = children()
    link = open_board(calibration, simulator="emulator", bounds={"grip": (0.0, 20.0)})
    try:
        assert isinstance(link, SimulatorLink) and link.kind == "emulator"
        emu = link.simulator_process
        assert emu.running and emu.pid in children() - before
        assert os.getsid(emu.pid) != os.getsid(0)   # its own session: a Ctrl-C reaches only us
        command = {"left": 12.5, "right": 7.25, "grip": 3.0}
        link.send(command)
        assert emu.read_state()["target"] == [calibration.to_ticks(command)[n] for n in link.winch_names]
        assert wait_until(lambda: not link.moving())
        for name, measured in link.positions().items():
            assert measured == pytest.approx(command[name], abs=1.5 / calibration.winch(name).ticks_per_mm)
        lines = emu.read_state()["lines"]
        with pytest.raises(HardwareError, match=r"refused, nothing sent: contraction 20\.5 for winch 'grip'"):
            link.send({"grip": 20.5})
        assert emu.read_state()["lines"] == lines   # nothing reached the board
        link.stop()
        assert emu.read_state()["enabled"] == [False] * 3
    finally:
        link.close()
    assert not emu.running and not (children() - before)   # no child process left behind


def test_link_on_a_serial_port_stops_on_close(emulator, calibration):
    with open_board(calibration, port=emulator.port) as link:
        assert isinstance(link, SerialLink) and link.port == emulator.port
        link.send({"left": 5.0})
        assert emulator.read_state()["enabled"][0]
    state = emulator.read_state()
    assert state["enabled"] == [False] * 3 and state["connected"] is False


def test_a_watchdog_trip_is_an_error_not_a_silent_stop(make_emulator):
    emu = make_emulator(3, speed=100.0)   # slow: still moving when the watchdog bites
    calibration = calibration_from_dict(fast_calibration_dict(watchdog_ms=100), source="fast.yaml")
    with open_board(calibration, port=emu.port) as link:
        link.send({"left": 20.0})
        assert link.moving()
        time.sleep(0.4)                   # the host "stalls"
        with pytest.raises(HardwareError, match=r"the board's watchdog stopped the motors \(no command for "
                                                r"100 ms while moving\)"):
            link.positions()


CHILD = """
import json, sys, time
from plush_opt.board import calibration_from_dict, open_board
link = open_board(calibration_from_dict(json.loads(sys.argv[1])), simulator="emulator")
print(link.simulator_process.pid, flush=True)
time.sleep(60)
"""


def test_the_simulator_dies_with_its_host(emu_binary):
    host = subprocess.Popen([sys.executable, "-c", CHILD, json.dumps(fast_calibration_dict())],
                            stdout=subprocess.PIPE, text=True)
    try:
        pid = int(host.stdout.readline())
        assert alive(pid)
    finally:
        host.send_signal(signal.SIGKILL)   # no chance to close the link
        host.wait()
    assert wait_until(lambda: not alive(pid), timeout=5.0), f"emulator {pid} outlived its host"
