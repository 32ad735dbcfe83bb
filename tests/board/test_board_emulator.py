"""Both boards spoken to by hand over their pty: the emulator (protocol_core.cpp
compiled for the host) and the firmware binary on simavr (``board`` fixture),
then what only the emulator has (state file, fuzzing, flags)."""

import random
import signal
import subprocess
import threading
import time

import pytest

from board_helpers import wait_until
from plush_opt.board import protocol as P
from plush_opt.board.emulator import Emulator
from plush_opt.base.errors import HardwareError

def _get(port, seq):
    """The board's GET, decoded (4 axes)."""
    reply = P.parse_reply(port.ask(f"{seq} GET"))
    assert reply.ok and reply.seq == seq, reply
    return P.parse_state(reply.payload, 4)


def _settled(port, axis, seq=100):
    """Wait until ``axis`` reads not moving (the board says so only once it is
    within its deadband and at rest); True once it does."""
    return wait_until(lambda: not _get(port, seq).moving[axis], timeout=6.0)


def test_identify_and_initial_state(board, raw_port):
    port = raw_port(board.port)
    assert port.ask("1 ID") == f"1 OK board={board.name} fw=1.1.0 proto=1 winches=4"
    assert port.ask("2 GET") == "2 OK pos=0,0,0,0 tgt=0,0,0,0 mov=0,0,0,0 en=0,0,0,0 wd=0"
    assert port.ask("007 ping") == "7 OK"
    assert port.ask("3 LIMIT 1") == "3 OK lo=0 hi=0"      # nothing moves before limits are set
    assert port.ask("4 SET 1 1") == "4 ERR 6 target outside limits"


@pytest.mark.parametrize("line, reply", [
    ("hello", "* ERR 1 bad sequence number"),
    ("65536 ID", "* ERR 1 bad sequence number"),
    ("-1 ID", "* ERR 1 bad sequence number"),
    ("5\x00 ID", "* ERR 1 malformed line"),
    ("5 ID\x7f", "* ERR 1 malformed line"),
    ("5 \xe9", "* ERR 1 malformed line"),
    ("5", "5 ERR 1 missing command"),
    ("5 MOVE 0 1", "5 ERR 3 unknown command"),
    ("5 ID 1", "5 ERR 4 expected no arguments"),
    ("5 SET 0", "5 ERR 4 expected axis and target"),
    ("5 SET 0 1.5", "5 ERR 4 bad target"),
    ("5 SET 0 1000000001", "5 ERR 4 bad target"),
    ("5 SET 0 99999999999", "5 ERR 4 bad target"),
    ("5 SET x 1", "5 ERR 4 bad axis"),
    ("5 SET -1 1", "5 ERR 4 bad axis"),
    ("5 SET 4 1", "5 ERR 5 no such axis"),
    ("5 SETALL 1 2", "5 ERR 4 expected one target per axis"),
    ("5 SETALL 1 2 3 4 5 6 7 8 9", "5 ERR 4 too many arguments"),
    ("5 LIMIT 0 9 1", "5 ERR 4 bad limits"),
    ("5 LIMIT 0 1", "5 ERR 4 expected axis [lo hi]"),
    ("5 SPEED 0 0", "5 ERR 4 bad speed"),
    ("5 WDOG 19", "5 ERR 4 bad timeout"),
    ("5 WDOG 60001", "5 ERR 4 bad timeout"),
    ("5 ZERO 7", "5 ERR 5 no such axis"),
    ("5 " + "X" * 200, "5 ERR 2 line too long"),
    ("Y" * 121, "* ERR 2 line too long"),
])
def test_refusals(board, raw_port, line, reply):
    port = raw_port(board.port)
    assert port.ask(line) == reply
    assert port.ask("6 GET").startswith("6 OK pos=0,0,0,0 ")  # still answering, nothing moved


def test_blank_lines_and_crlf(board, raw_port):
    port = raw_port(board.port)
    port.ser.write(b"\r\n   \n\t\n1 ID\r\n")
    assert port.ser.readline().startswith(b"1 OK board=")
    port.ser.write(b"2 PING\n")
    assert port.ser.readline() == b"2 OK\n"  # nothing was answered to the blank lines


def test_sequence_numbers_are_echoed_in_decimal(board, raw_port):
    port = raw_port(board.port)
    for seq, echo in (("0", "0"), ("00042", "42"), ("65535", "65535"), ("1", "1")):
        assert port.ask(f"{seq} PING") == f"{echo} OK"
    port.ser.write(b"10 PING\n11 ID\n12 PING\n")  # in order, one reply each
    assert [port.ser.readline().split()[0] for _ in range(3)] == [b"10", b"11", b"12"]


@pytest.mark.slow
def test_out_of_limit_targets_are_refused_not_clamped(board, raw_port):
    port = raw_port(board.port)
    assert port.ask("1 LIMIT 0 -100 500") == "1 OK lo=-100 hi=500"
    assert port.ask("2 SET 0 501") == "2 ERR 6 target outside limits"
    assert port.ask("3 SET 0 -101") == "3 ERR 6 target outside limits"
    assert port.ask("4 SETALL 100 - 5 -") == "4 ERR 6 target outside limits"  # axis 2 limits are [0, 0]
    state = _get(port, 5)
    assert state.target == (0, 0, 0, 0) and not any(state.enabled)  # the refused SETALL moved nothing
    assert port.ask("6 SPEED 0 500") == "6 OK speed=500"
    assert port.ask("7 SETALL 500 - - -") == "7 OK"
    assert _settled(port, 0)
    state = _get(port, 9)
    assert abs(state.position[0] - 500) <= board.deadband and state.enabled == (True, False, False, False)
    # The limit bounds targets; a real motor coasts past its target by up to speed x time constant.
    assert board.read_state()["max_ticks"][0] <= 500 + board.coast(500)


def test_zero_limit_speed_and_busy(board, raw_port):
    port = raw_port(board.port)
    assert port.ask("1 LIMIT 0 0 1000") == "1 OK lo=0 hi=1000"
    assert port.ask("2 SPEED 0 100") == "2 OK speed=100"
    assert port.ask("3 SET 0 1000") == "3 OK"
    time.sleep(0.2)
    assert port.ask("4 ZERO") == "4 ERR 7 axis is moving"
    assert port.ask("5 LIMIT 0 0 2000") == "5 ERR 7 axis is moving"
    assert port.ask("6 ZERO 1") == "6 OK"          # axis 1 is not moving
    assert port.ask("7 STOP") == "7 OK"
    pos = _get(port, 8).position[0]
    assert 0 < pos < 500
    assert port.ask("9 LIMIT 0 0 5") == "9 OK lo=0 hi=5"   # stopped: new limits accepted
    assert port.ask("10 ZERO 0") == "10 OK"
    assert port.ask("11 GET") == "11 OK pos=0,0,0,0 tgt=0,0,0,0 mov=0,0,0,0 en=0,0,0,0 wd=0"
    assert port.ask("12 SET 0 5") == "12 OK"
    assert _settled(port, 0)
    assert port.ask("14 LIMIT 0 10 20") == "14 ERR 8 target outside new limits"


REST_CREEP = 1   # ticks: "at rest" is slower than 20 ticks/s, so the last edge of a coast may still come


@pytest.mark.slow
def test_arrival_is_settled_not_passing_through(board, raw_port):
    """Not moving means within the deadband AND at rest: once the firmware says
    so, the motor has stopped and stays within the deadband (board time)."""
    port = raw_port(board.port)
    assert port.ask("1 LIMIT 0 -2000 2000") == "1 OK lo=-2000 hi=2000"
    seq = 2
    for speed, target in ((700, 600), (500, -200)):
        assert port.ask(f"{seq} SPEED 0 {speed}") == f"{seq} OK speed={speed}"
        assert port.ask(f"{seq + 1} SET 0 {target}") == f"{seq + 1} OK"
        seq += 2
        start = board.read_state()["time"]
        while _get(port, seq).moving[0]:
            seq += 1
            assert board.read_state(fresh=False)["time"] - start < 6.0, "never arrived"
        arrived = board.read_state()
        assert abs(arrived["ticks"][0] - target) <= board.deadband, arrived
        later = arrived["time"] + 0.3
        assert wait_until(lambda: board.read_state(fresh=False)["time"] > later, timeout=5.0)
        state = _get(port, seq + 1)
        assert not state.moving[0] and abs(state.position[0] - target) <= board.deadband, state
        assert abs(state.position[0] - arrived["ticks"][0]) <= REST_CREEP, (arrived, state)   # it had stopped
        seq += 2
    extremes = board.read_state()   # and it did not overshoot on the way
    assert extremes["max_ticks"][0] <= 600 + board.deadband and extremes["min_ticks"][0] >= -200 - board.deadband


def _stopped(board, axis):
    """The board's true state once ``axis`` is no longer driven, else None."""
    state = board.read_state(fresh=False)
    return None if state["enabled"][axis] else state


WATCHDOG_MS = 200
CONTROL_PERIOD_S = 0.002     # the firmware's control cycle: the watchdog acts within one


def test_watchdog_stops_motors_after_host_silence(board, raw_port):
    port = raw_port(board.port)
    assert port.ask(f"1 WDOG {WATCHDOG_MS}") == f"1 OK ms={WATCHDOG_MS}"
    assert port.ask("2 LIMIT 0 0 100000") == "2 OK lo=0 hi=100000"
    assert port.ask("3 SPEED 0 1000") == "3 OK speed=1000"
    assert port.ask("4 SET 0 100000") == "4 OK"
    # Talking keeps it alive ...
    for seq in range(5, 17):
        time.sleep(0.03)
        assert port.ask(f"{seq} PING") == f"{seq} OK"
    assert board.read_state()["enabled"][0]
    assert _get(port, 17).moving[0]
    # ... silence stops it.
    state = wait_until(lambda: _stopped(board, 0), timeout=2.0)
    assert state and not state["enabled"][0]
    if board.kind == "simavr":
        # In the board's own time: braked after the promised silence, within a control cycle of it
        # (the moment the brake engaged, not when the simulator next wrote its state: that
        # lags by a loaded machine's scheduling)
        silent = state["braked_time"][0] - state["last_rx_time"]
        assert WATCHDOG_MS / 1000 <= silent <= WATCHDOG_MS / 1000 + CONTROL_PERIOD_S + 0.005, state
        assert state["speed"][0] == 0.0 and state["drive"][0] == 0.0
    else:
        assert state["stops"]["watchdog"] == 1
    stopped_at = state["ticks"][0]
    assert 100 < stopped_at < 5000  # moved while pinged, stopped long before the target
    time.sleep(0.1)
    assert board.read_state()["ticks"][0] == stopped_at
    assert port.ask("20 GET").endswith("en=0,0,0,0 wd=1")


def test_holding_is_not_moving_so_no_watchdog(board, raw_port):
    port = raw_port(board.port)
    assert port.ask("2 LIMIT 0 0 100") == "2 OK lo=0 hi=100"
    assert port.ask("3 SET 0 100") == "3 OK"
    assert _settled(port, 0)
    assert port.ask("1 WDOG 50") == "1 OK ms=50"
    time.sleep(0.3)
    state = _get(port, 5)
    assert state.enabled[0] and state.watchdog_trips == 0


def test_host_closing_port_mid_move_stops_motors(board, raw_port):
    """The emulator sees the hang-up at once; the firmware cannot (a closed USB
    port does not always reach the board), so its watchdog stops the motors."""
    port = raw_port(board.port)
    wd = 10000 if board.stops_on_hangup else 300   # the hang-up, not the watchdog, must stop the emulator
    assert port.ask(f"1 WDOG {wd}") == f"1 OK ms={wd}"
    assert port.ask("2 LIMIT 1 -100000 0") == "2 OK lo=-100000 hi=0"
    assert port.ask("3 SPEED 1 1000") == "3 OK speed=1000"
    assert port.ask("4 SET 1 -100000") == "4 OK"
    time.sleep(0.05)
    port.close()
    state = wait_until(lambda: _stopped(board, 1), timeout=2.0)
    assert state and not state["enabled"][1]
    if board.stops_on_hangup:
        assert state["stops"]["hangup"] >= 1 and state["stops"]["watchdog"] == 0
        assert not state["connected"]
    stopped_at = state["ticks"][1]
    assert -3000 < stopped_at < 0
    time.sleep(0.1)
    assert board.read_state()["ticks"][1] == stopped_at
    # The port can be opened again and the board answers.
    again = raw_port(board.port)
    state = _get(again, 5)
    assert state.position == (0, stopped_at, 0, 0)
    assert not any(state.moving) and not any(state.enabled)
    assert state.watchdog_trips == (0 if board.stops_on_hangup else 1)
    # The stop takes the position as the target; a real motor may still turn
    # by an encoder edge between that reading and the brake.
    assert abs(state.target[1] - stopped_at) <= (0 if board.kind == "emulator" else 1), state


def _fuzz_lines(rng: random.Random, n: int):
    words = ["ID", "PING", "GET", "SET", "SETALL", "STOP", "SPEED", "WDOG", "set", "Get", "LIMIT", "ZERO"]

    def number():
        return rng.choice([str(rng.randint(-1000, 2000)), str(rng.randint(-2**40, 2**40)), "-", "+", "",
                           "1.5", "0x10", "+" + str(rng.randint(0, 900)), "9" * rng.randint(1, 14),
                           "".join(rng.choice("0123456789-+ ") for _ in range(rng.randint(1, 6)))])

    for _ in range(n):
        kind = rng.random()
        if kind < 0.2:    # plain moves, half of them outside the limits
            line = f"{rng.randint(0, 65535)} SET {rng.randrange(3)} {rng.randint(-1000, 1000)}".encode()
        elif kind < 0.35:   # random bytes, including NUL, high bytes, CR and LF
            line = bytes(rng.randrange(256) for _ in range(rng.randint(0, 60)))
        elif kind < 0.4:  # over-long lines
            line = bytes(rng.randrange(32, 127) for _ in range(rng.randint(100, 400)))
        else:             # command-like lines with mutated arguments
            seq = rng.choice([str(rng.randint(0, 70000)), "", "x", "-1", str(rng.randint(0, 65535))])
            word = rng.choice(words)
            if word.upper() == "LIMIT":     # only forms that do not change the limits
                args = rng.choice([["0"], ["9", "1", "2"], ["0", "5"], ["0", "10", "5"], ["x", "1", "2"]])
            elif word.upper() == "ZERO":    # only forms that are refused
                args = rng.choice([["9"], ["x"], ["0", "1"], ["-1"]])
            else:
                args = [number() for _ in range(rng.choice([0, 1, 2, 2, 3, 3, 4, 9]))]
            sep = rng.choice([" ", "  ", "\t", " \t "])
            line = sep.join([seq, word, *args]).encode()
        upper = line.upper()
        if (b"ZERO" in upper or b"LIMIT" in upper) and not line.decode("latin-1").split()[1:2] in (["LIMIT"], ["ZERO"]):
            continue  # random bytes that happen to spell a frame-changing command
        yield line + rng.choice([b"\n", b"\r\n", b"\r"])


def test_fuzzing_never_crashes_nor_leaves_the_limits(make_emulator, raw_port):
    emu = make_emulator(3, speed=50000.0)
    port = raw_port(emu.port)
    limits = [(-300, 400), (0, 800), (-800, 0)]
    for axis, (lo, hi) in enumerate(limits):
        assert port.ask(f"{axis} LIMIT {axis} {lo} {hi}") == f"{axis} OK lo={lo} hi={hi}"
    assert port.ask("9 WDOG 60000") == "9 OK ms=60000"

    stop = threading.Event()

    def drain():  # read replies so that the pty never fills up
        while not stop.is_set():
            port.ser.read(4096)

    reader = threading.Thread(target=drain, daemon=True)
    port.ser.timeout = 0.01
    reader.start()
    rng = random.Random(20240611)
    lines = list(_fuzz_lines(rng, 4000))
    try:
        for i in range(0, len(lines), 20):
            port.ser.write(b"".join(lines[i:i + 20]))
            if i % 400 == 0:
                state = emu.read_state(fresh=False)
                for axis, (lo, hi) in enumerate(limits):
                    assert lo <= state["ticks"][axis] <= hi
    finally:
        stop.set()
        reader.join(2)
    assert emu.running, "emulator died while fuzzed"
    port.ser.write(b"\n")  # end whatever half line the fuzzer left
    port.ser.timeout = 0.2
    while port.ser.read(4096):  # replies still queued in the emulator: read until it is quiet
        pass
    port.ser.timeout = 1.0
    assert port.ask("54321 ID") == "54321 OK board=plush-winch-emu fw=1.1.0 proto=1 winches=3"
    state = emu.read_state()
    assert state["lines"] > 3000 and state["errors"] > 1000
    for axis, (lo, hi) in enumerate(limits):
        assert lo <= state["min_ticks"][axis] <= state["max_ticks"][axis] <= hi, (axis, state)
        assert state["limit_lo"][axis] == lo and state["limit_hi"][axis] == hi
    assert any(state["max_ticks"][a] - state["min_ticks"][a] > 100 for a in range(3)), "fuzzing moved nothing"
    assert emu.stop() == 0


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_exits_cleanly_on_signals(make_emulator, raw_port, sig):
    emu = make_emulator(1)
    raw_port(emu.port).ask("1 ID")
    emu._proc.send_signal(sig)
    assert emu._proc.wait(2) == 0


def test_bad_flags_exit_2(emu_binary):
    for args in (["--winches", "9"], ["--speed", "fast"], ["--bogus"], ["--tau"]):
        r = subprocess.run([str(emu_binary), *args], capture_output=True, text=True, timeout=5)
        assert r.returncode == 2 and "plush-board-emu:" in r.stderr, (args, r)
    r = subprocess.run([str(emu_binary), "--help"], capture_output=True, text=True, timeout=5)
    assert r.returncode == 0 and "--state-file" in r.stdout


def test_missing_binary_says_how_to_build(tmp_path):
    with pytest.raises(HardwareError, match=r"board emulator not built: .*make -C hw"):
        Emulator(1, binary=tmp_path / "plush-board-emu")


def test_unread_replies_are_dropped_whole_never_cut(make_emulator, raw_port):
    """A host that stops reading loses whole replies, never the tail of one."""
    emu = make_emulator(3)
    port = raw_port(emu.port)
    n = 3000  # ~150 kB of GET replies: far more than the terminal holds
    for start in range(1, n + 1, 100):
        port.ser.write(b"".join(b"%d GET\n" % seq for seq in range(start, min(start + 100, n + 1))))
    assert wait_until(lambda: emu.read_state(fresh=False)["lines"] == n, timeout=10.0)
    assert emu.read_state()["dropped_replies"] > 0
    port.ser.timeout = 0.3
    seqs = []
    while line := port.ser.readline():
        reply = P.parse_reply(line)  # a cut reply glued to the next one does not parse
        assert reply.ok and line.endswith(b"\n"), line
        P.parse_state(reply.payload, 3)
        seqs.append(reply.seq)
    assert seqs == sorted(seqs) and len(seqs) + emu.read_state()["dropped_replies"] == n
