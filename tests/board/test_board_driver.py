"""plush_opt.board.Driver against the emulator and against fake boards on bare ptys."""

import logging
import re

import pytest

from board_helpers import fast_calibration_dict, wait_until
from plush_opt.board import Driver, calibration_from_dict
from plush_opt.base.errors import HardwareError


def test_handshake_configures_limits_speeds_and_watchdog(emulator, calibration):
    with Driver(emulator.port, calibration, watchdog_ms=400) as board:
        assert board.info.board == "plush-winch-emu" and board.info.winches == 3 and board.info.protocol == 1
        state = emulator.read_state()
        assert state["watchdog_ms"] == 400
        for w in calibration.winches:
            assert (state["limit_lo"][w.axis], state["limit_hi"][w.axis]) == w.tick_limits
            assert state["speed"][w.axis] == w.speed_ticks
        assert state["limit_lo"][1] < 0 == state["limit_hi"][1]  # right runs backwards


def test_set_and_read_back_in_mm(emulator, calibration):
    command = {"left": 12.5, "right": 7.25, "grip": 3.0}
    with Driver(emulator.port, calibration) as board:
        ticks = board.set_contractions(command)
        assert ticks == calibration.to_ticks(command) and ticks["right"] < 0
        assert wait_until(lambda: not board.read_state().any_moving)
        measured = board.read_positions()
        for name, c in command.items():
            tick = 1.0 / calibration.winch(name).ticks_per_mm
            assert abs(measured[name] - c) <= 1.5 * tick, (name, measured[name], c)  # rounding + 1-tick deadband
        state = emulator.read_state()
        assert state["target"] == [ticks["left"], ticks["right"], ticks["grip"]]
        # One winch: the others keep their targets.
        board.set_contractions({"grip": 10.0})
        assert emulator.read_state()["target"][:2] == [ticks["left"], ticks["right"]]


def test_refuses_out_of_bounds_before_sending(emulator, calibration):
    with Driver(emulator.port, calibration, bounds={"grip": (0.0, 20.0)}) as board:
        lines = emulator.read_state()["lines"]
        refused = r"refused, nothing sent: contraction 20\.5 for winch 'grip' is outside .*\[0, 20\]"
        with pytest.raises(HardwareError, match=refused):
            board.set_contractions({"left": 1.0, "grip": 20.5})      # scene bound
        with pytest.raises(HardwareError, match=r"winch 'left' is outside .*\[0, 25\]"):
            board.set_contractions({"left": 25.5})                   # calibration limit
        with pytest.raises(HardwareError, match=r"winch 'left'"):
            board.set_contractions({"left": -0.01})
        with pytest.raises(HardwareError, match=r"winch 'left'"):
            board.set_contractions({"left": float("nan")})
        with pytest.raises(HardwareError, match=r"no winch 'thumb'"):
            board.set_contractions({"thumb": 1.0})
        for value in ("10", True, None):
            with pytest.raises(HardwareError, match=rf"contraction {value!r} for winch 'left' is not a finite number"):
                board.set_contractions({"left": value})
        assert emulator.read_state()["lines"] == lines  # nothing reached the board
        board.set_contractions({"grip": 20.0 + 1e-12})   # float noise at a bound is not a violation


def test_scene_winch_missing_from_calibration(calibration):
    with pytest.raises(HardwareError, match="scene winch 'thumb' is not calibrated"):
        Driver("/dev/null", calibration, bounds={"thumb": (0, 1)})


def test_board_with_too_few_axes(make_emulator, calibration):
    emu = make_emulator(2)
    with pytest.raises(HardwareError, match=r"has 2 winch axes, calibration fast.yaml needs 3"):
        Driver(emu.port, calibration).open()


def test_board_refusal_reports_code_and_message(emulator, calibration):
    with Driver(emulator.port, calibration) as board:
        with pytest.raises(HardwareError, match=r"refused '\d+ ZERO 9': ERR 5 BAD_AXIS \(no such axis\)"):
            board._transact("ZERO", 9)


def test_missing_port():
    cal = calibration_from_dict(fast_calibration_dict())
    with pytest.raises(HardwareError, match="cannot open serial port /nonexistent/tty"):
        Driver("/nonexistent/tty", cal).open()


def test_board_that_never_answers_times_out(fake_board, calibration):
    silent = fake_board(lambda line: None)      # reads every line, answers none
    board = Driver(silent.port, calibration, timeout=0.2, retries=2)
    with pytest.raises(HardwareError, match=r"no reply from the board to ID after 3 attempt\(s\) of 0\.20 s"):
        board.open()
    assert not board.is_open
    # three attempts, each with its own sequence number, then it gave up
    assert wait_until(lambda: len(silent.received) >= 3)
    assert [line.split()[1] for line in silent.received] == ["ID"] * 3
    assert len({line.split()[0] for line in silent.received}) == 3


def _id_reply(seq, winches=3):
    return f"{seq} OK board=fake fw=0 proto=1 winches={winches}\n".encode()


def test_sequence_mismatch_is_detected(fake_board, calibration):
    def wrong_seq(line):
        seq = int(line.split()[0])
        return [_id_reply(seq + 7)]
    board = fake_board(wrong_seq)
    with pytest.raises(HardwareError, match=r"reply sequence mismatch: sent ID with sequence number (\d+), got a "
                                            r"reply for (\d+)"):
        Driver(board.port, calibration, timeout=0.3).open()


def _answer(line, state):
    seq, cmd, *args = line.split()
    if cmd == "ID":
        return [_id_reply(seq)]
    if cmd == "GET":
        return [f"{seq} OK pos=0,0,0 tgt=0,0,0 mov=0,0,0 en=0,0,0 wd=0\n".encode()]
    if cmd == "LIMIT":
        return [f"{seq} OK lo={args[1]} hi={args[2]}\n".encode()]
    return [f"{seq} OK\n".encode()]


def test_late_reply_to_an_abandoned_command_is_dropped(fake_board, calibration):
    held = []

    def slow_first(line):
        if not held:                       # first ID: answer only later, with the retry
            held.append(line)
            return []
        if len(held) == 1:
            held.append(line)
            return [*_answer(held[0], None), b"garbage from the line\n", *_answer(line, None)]
        return _answer(line, None)
    board = fake_board(slow_first)
    with Driver(board.port, calibration, timeout=0.2, retries=1) as d:
        assert d.info.board == "fake"
    first, second = (int(l.split()[0]) for l in held)
    assert second == first + 1


def test_star_reply_is_not_ours(fake_board, calibration):
    def noisy(line):
        return [b"* ERR 1 malformed line\n", *_answer(line, None)]
    with Driver(fake_board(noisy).port, calibration) as d:
        assert d.read_state().position == (0, 0, 0)


def test_context_manager_stops_on_exception(emulator, calibration):
    with pytest.raises(RuntimeError, match="boom"):
        with Driver(emulator.port, calibration) as board:
            board.set_contractions({"left": 20.0})
            raise RuntimeError("boom")
    state = emulator.read_state()
    assert state["enabled"] == [False] * 3 and not any(state["moving"])
    assert state["stops"]["command"] == 2    # one on open, one on exit


def test_context_manager_stops_on_keyboard_interrupt(emulator, calibration):
    with pytest.raises(KeyboardInterrupt):
        with Driver(emulator.port, calibration) as board:
            board.set_contractions({"left": 20.0, "right": 20.0})
            raise KeyboardInterrupt
    state = emulator.read_state()
    assert state["enabled"] == [False] * 3 and state["stops"]["command"] == 2


def test_stop_on_exit_keeps_the_port_open(emulator, calibration):
    board = Driver(emulator.port, calibration).open()
    try:
        with pytest.raises(ValueError):
            with board.stop_on_exit():
                board.set_contractions({"grip": 5.0})
                raise ValueError
        assert board.is_open and emulator.read_state()["enabled"] == [False] * 3
        board.set_contractions({"grip": 5.0})
    finally:
        board.close()
    assert not board.is_open and emulator.read_state()["enabled"] == [False] * 3


def test_board_gone_mid_session(make_emulator, calibration, caplog):
    emu = make_emulator(3)
    board = Driver(emu.port, calibration, timeout=0.2, retries=0).open()
    emu.stop()
    with caplog.at_level(logging.DEBUG, logger="plush_opt.board.driver"):
        with pytest.raises(HardwareError, match=re.escape(emu.port)):
            board.read_state()
    # one attempt (retries=0), then the error: nothing waits on a board that is gone
    assert len([r for r in caplog.records if " > " in r.getMessage()]) == 1
    board.close()  # logs, does not raise
    assert not board.is_open


def test_board_that_boots_slowly_is_waited_for(fake_board, calibration):
    ignored = []

    def booting(line):       # an Arduino in its bootloader: the first lines are lost
        if line.split()[1] == "ID" and len(ignored) < 3:
            ignored.append(line)
            return []
        return _answer(line, None)
    impatient = fake_board(booting)
    with pytest.raises(HardwareError, match="no reply from the board to ID after 2 attempt"):
        Driver(impatient.port, calibration, timeout=0.1, retries=1).open()
    ignored.clear()
    patient = fake_board(booting)
    with Driver(patient.port, calibration, timeout=0.1, retries=1, boot_time=0.5) as board:
        assert board.info.board == "fake" and len(ignored) == 3
    # without boot_time the driver gave up after its 2 attempts; with it, it
    # tried again (boot_time / timeout + 1 = 6 at most) until the 4th was answered
    assert wait_until(lambda: len(impatient.received) >= 2)
    assert [line.split()[1] for line in impatient.received] == ["ID"] * 2
    assert [line.split()[1] for line in patient.received].count("ID") == 4
