"""Protocol lines (plush_opt.board.protocol) and the three copies of the error table."""

import re
from pathlib import Path

import pytest
from hypothesis import given
from hypothesis import strategies as st

from plush_opt.board import protocol as P
from plush_opt.base.errors import HardwareError

HW = Path(__file__).resolve().parents[2] / "hw"


def test_format_command():
    assert P.format_command(7, "SET", 1, -500) == b"7 SET 1 -500\n"
    assert P.format_command(65535, "SETALL", 1, P.KEEP, 3) == b"65535 SETALL 1 - 3\n"
    assert P.format_command(0, "ID") == b"0 ID\n"


@pytest.mark.parametrize("args, match", [
    ((70000, "ID"), "sequence number"),
    ((1, "MOVE"), "unknown command"),
    ((1, "SET", 0, 1.5), "not an integer"),
    ((1, "SET", 0, True), "not an integer"),
    ((1, "SETALL", *([123456789] * 12)), "exceeds 120"),
])
def test_format_command_refuses_what_the_board_would(args, match):
    with pytest.raises(ValueError, match=match):
        P.format_command(*args)


def test_parse_reply():
    r = P.parse_reply(b"12 OK pos=1,-2 tgt=0,0\n")
    assert (r.seq, r.ok, r.payload) == (12, True, "pos=1,-2 tgt=0,0")
    assert r.fields() == {"pos": "1,-2", "tgt": "0,0"}
    assert P.parse_reply("3 OK") == P.Reply(seq=3, ok=True, payload="")
    e = P.parse_reply(b"4 ERR 6 target outside limits\r\n")
    assert (e.seq, e.ok, e.code, e.message, e.error_name) == (4, False, 6, "target outside limits", "OUT_OF_LIMITS")
    star = P.parse_reply(b"* ERR 1 bad sequence number\n")
    assert star.seq is None and star.code == P.E_MALFORMED


@pytest.mark.parametrize("line", [b"", b"OK", b"12 ok", b"12 OK  x=1", b"x OK", b"1 ERR x y", b"1 ERR 4",
                                  b"99999 OK", b"1 OK\xff", b"1 OK novalue"])
def test_parse_reply_rejects_garbage(line):
    with pytest.raises(HardwareError):
        P.parse_reply(line).fields()


def test_parse_info_and_state():
    info = P.parse_info("board=plush-winch fw=1.0.0 proto=1 winches=4 extra=ignored")
    assert info == P.BoardInfo("plush-winch", "1.0.0", 1, 4)
    state = P.parse_state("pos=1,-2 tgt=3,4 mov=0,1 en=1,1 wd=2", 2)
    assert state.position == (1, -2) and state.target == (3, 4)
    assert state.moving == (False, True) and state.any_moving and state.watchdog_trips == 2
    with pytest.raises(HardwareError, match="3 values, board has 2"):
        P.parse_state("pos=1,2,3 tgt=3,4 mov=0,1 en=1,1 wd=2", 2)
    with pytest.raises(HardwareError, match="lacks field 'wd'"):
        P.parse_state("pos=1,2 tgt=3,4 mov=0,1 en=1,1", 2)


@pytest.mark.slow
@given(st.integers(0, P.MAX_SEQ),
       st.dictionaries(st.from_regex(r"[a-z][a-z0-9]{0,5}", fullmatch=True),
                       st.from_regex(r"[!-~]{1,12}", fullmatch=True).filter(lambda v: "=" not in v), max_size=5))
def test_ok_reply_round_trip(seq, fields):
    line = " ".join([str(seq), "OK", *(f"{k}={v}" for k, v in fields.items())]) + "\n"
    reply = P.parse_reply(line)
    assert reply.seq == seq and reply.ok and reply.fields() == fields


def test_error_codes_agree_with_protocol_md_and_core_header():
    doc = (HW / "PROTOCOL.md").read_text()
    table = dict((int(code), name) for code, name in re.findall(r"^\|\s*(\d+)\s*\|\s*([A-Z_]+)\s*\|", doc, re.M))
    header = (HW / "firmware" / "plush_winch" / "protocol_core.h").read_text()
    enum = {int(code): name for name, code in re.findall(r"\bE_([A-Z_]+)\s*=\s*(\d+)", header)}
    consts = {getattr(P, f"E_{name}"): name for name in P.ERROR_NAMES.values()}
    assert table == P.ERROR_NAMES == enum == consts
    assert len(table) == 8


def test_limits_agree_with_core_header():
    header = (HW / "firmware" / "plush_winch" / "protocol_core.h").read_text()

    def const(name):
        m = re.search(rf"{name}\s*=\s*(\d+)", header)
        return int(m.group(1))
    assert const("kMaxLine") == P.MAX_LINE
    assert const("kMaxSeq") == P.MAX_SEQ
    assert const("kMaxTicks") == P.MAX_TICKS
    assert const("kMaxSpeed") == P.MAX_SPEED
    assert const("kMinWatchdogMs") == P.MIN_WATCHDOG_MS
    assert const("kMaxWatchdogMs") == P.MAX_WATCHDOG_MS
    assert const("kMaxAxes") == P.MAX_AXES
    assert const("kProtocolVersion") == P.PROTOCOL_VERSION
