"""Board calibration files: shipped boards, validation messages, length <-> ticks."""

import copy
import math
from pathlib import Path

import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from board_helpers import fast_calibration_dict
from plush_opt.board.board_file import WinchCalibration, calibration_from_dict, load_calibration
from plush_opt.base.errors import SceneError

BOARDS = Path(__file__).resolve().parents[2] / "hw" / "boards"


@pytest.mark.parametrize("name, winches", [("gripper", ("left", "right", "grip")), ("hexapod", ("a", "b")),
                                           ("hexapod_leg", ("leg",))])
def test_shipped_boards(name, winches):
    cal = load_calibration(BOARDS / f"{name}.yaml")
    assert cal.name == name and cal.winch_names == winches
    assert cal.port.baudrate == 115200
    for w in cal.winches:
        lo, hi = w.tick_limits
        assert lo <= w.to_ticks(w.limits[0]) <= hi and lo <= w.to_ticks(w.limits[1]) <= hi
        assert w.speed_ticks >= 1


def test_gripper_numbers():
    left = load_calibration(BOARDS / "gripper.yaml").winch("left")
    # 12 counts/rev x 100:1 = 1200 ticks per spool turn, 2 pi 6 mm of tendon per turn.
    assert left.ticks_per_rev * left.gear_ratio == 1200
    assert left.to_ticks(2 * math.pi * 6.0) == 1200
    assert left.tick_limits == (0, 796)


def test_tolerance_defaults_to_the_deadband_and_may_be_wider():
    cal = load_calibration(BOARDS / "gripper.yaml")
    for w in cal.winches:   # no tolerance in the file: 3 ticks of deadband and half a tick of rounding
        assert w.tolerance == w.min_tolerance == pytest.approx(3.5 / w.ticks_per_mm)
    assert cal.winch("left").tolerance == pytest.approx(0.110, abs=1e-3)
    d = fast_calibration_dict()
    d["winches"][0]["tolerance"] = 0.5
    d["winches"][1]["tolerance"] = None   # null: the default
    wide = calibration_from_dict(d, source="wide.yaml")
    assert wide.winch("left").tolerance == 0.5
    assert wide.winch("right").tolerance == pytest.approx(wide.winch("right").min_tolerance)


def test_direction_flips_ticks():
    right = load_calibration(BOARDS / "gripper.yaml").winch("right")
    assert right.direction == -1
    assert right.to_ticks(10.0) == -318 and right.to_mm(-318) == pytest.approx(9.99, abs=0.01)
    assert right.tick_limits == (-796, 0)
    assert str(right.to_mm(0)) == "0.0"


def _bad(mutate):
    d = fast_calibration_dict()
    mutate(d)
    return d


@pytest.mark.parametrize("mutate, match", [
    (lambda d: d.update(format="plush-board/2"), r"bad\.yaml: format: must be 'plush-board/1'"),
    (lambda d: d.pop("winches"), r"bad\.yaml: winches: missing required key"),
    (lambda d: d.update(extra=1), r"bad\.yaml: extra: unknown key"),
    (lambda d: d.update(winches=[]), r"winches: empty list"),
    (lambda d: d["winches"][1].update(spool_radius=-6), r"winches\[1\]\.spool_radius: must be > 0, got -6"),
    (lambda d: d["winches"][2].update(ticks_per_rev="12"), r"winches\[2\]\.ticks_per_rev: expected a number, got string '12'"),
    (lambda d: d["winches"][0].update(gear_ratio=True), r"winches\[0\]\.gear_ratio: expected a number, got boolean true"),
    (lambda d: d["winches"][0].update(gear_ratio=float("nan")), r"winches\[0\]\.gear_ratio: expected a finite number, got nan"),
    (lambda d: d["winches"][1].update(direction=0), r"winches\[1\]\.direction: must be 1 or -1"),
    (lambda d: d["winches"][2].update(limits=[5, 1]), r"winches\[2\]\.limits: lower must be < upper"),
    (lambda d: d["winches"][2].update(limits=[0, 1, 2]), r"winches\[2\]\.limits: must be \[lower, upper\]"),
    (lambda d: d["winches"][2].update(limits=[0, "x"]), r"winches\[2\]\.limits\[1\]: expected a number, got string 'x'"),
    (lambda d: d["winches"][2].update(limits=[0, 1e9]), r"winches\[2\]\.limits: .* beyond the board"),
    (lambda d: d["winches"][1].update(name="left"), r"winches\[1\]\.name: duplicate winch name 'left'"),
    (lambda d: d["winches"][1].update(name="a b"), r"winches\[1\]\.name: must be a name"),
    (lambda d: d["winches"][1].update(axis=0), r"winches\[1\]\.axis: axis 0 is already used"),
    (lambda d: d["winches"][1].update(axis=8), r"winches\[1\]\.axis: must be in 0\.\.7"),
    (lambda d: d["winches"][0].pop("max_speed"), r"winches\[0\]\.max_speed: missing required key"),
    (lambda d: d["winches"][0].update(speed=3), r"winches\[0\]\.speed: unknown key"),
    (lambda d: d["winches"][0].update(tolerance=0), r"winches\[0\]\.tolerance: must be > 0, got 0"),
    (lambda d: d["winches"][1].update(tolerance="0.2"), r"winches\[1\]\.tolerance: expected a number, got string"),
    (lambda d: d["winches"][2].update(tolerance=0.01),
     r"winches\[2\]\.tolerance: must be >= 0\.0488[67] mm \(the board's 3-tick deadband plus half a tick"),
    (lambda d: d["port"].update(watchdog_ms=5), r"port\.watchdog_ms: must be in 20\.\.60000"),
    (lambda d: d["port"].update(retries=-1), r"port\.retries: must be >= 0"),
    (lambda d: d["port"].update(baud=9600), r"port\.baud: unknown key"),
])
def test_bad_calibrations_name_file_key_and_index(mutate, match):
    with pytest.raises(SceneError, match=match):
        calibration_from_dict(_bad(mutate), source="bad.yaml")


def test_load_errors_name_the_file(tmp_path):
    missing = tmp_path / "nope.yaml"
    with pytest.raises(SceneError, match="nope.yaml: no such file"):
        load_calibration(missing)
    broken = tmp_path / "broken.yaml"
    broken.write_text("winches: [\n")
    with pytest.raises(SceneError, match=r"broken.yaml: line 2: invalid YAML"):
        load_calibration(broken)
    scalar = tmp_path / "scalar.yaml"
    scalar.write_text("42\n")
    with pytest.raises(SceneError, match="scalar.yaml: the document must be a mapping of keys, got number 42"):
        load_calibration(scalar)


def test_unknown_winch_lookup_names_the_choices(calibration):
    with pytest.raises(KeyError, match="no winch 'thumb'; calibrated winches: left, right, grip"):
        calibration.winch("thumb")


winches = st.builds(
    WinchCalibration, name=st.just("w"), axis=st.just(0),
    spool_radius=st.floats(1.0, 30.0), ticks_per_rev=st.sampled_from([12, 28, 48, 64, 1024, 4096]),
    gear_ratio=st.floats(5.0, 1000.0), direction=st.sampled_from([1, -1]),
    limits=st.just((0.0, 40.0)), max_speed=st.just(10.0))


@given(winches, st.floats(-50.0, 50.0))
def test_length_ticks_length_within_one_tick(w, c):
    back = w.to_mm(w.to_ticks(c))
    tick = 1.0 / w.ticks_per_mm
    assert abs(back - c) <= 0.5 * tick * (1 + 1e-9), (c, back, tick)


@given(winches, st.integers(-1_000_000, 1_000_000))
def test_ticks_length_ticks_exact(w, t):
    assume(abs(w.to_mm(t)) < 1e6)
    assert w.to_ticks(w.to_mm(t)) == t


@given(winches, st.floats(0.0, 1.0))
def test_contractions_within_limits_map_into_tick_limits(w, s):
    lo, hi = w.limits
    c = lo + s * (hi - lo)
    t_lo, t_hi = w.tick_limits
    assert t_lo <= w.to_ticks(c) <= t_hi


def test_mapping_helpers(calibration):
    ticks = calibration.to_ticks({"left": 10.0, "right": 10.0})
    assert ticks == {"left": 318, "right": -318}
    back = calibration.to_mm(ticks)
    assert back["left"] == pytest.approx(10.0, abs=1 / calibration.winch("left").ticks_per_mm)
    assert calibration.n_axes_required == 3
    d = copy.deepcopy(fast_calibration_dict())
    d["winches"][2]["axis"] = 5
    assert calibration_from_dict(d).n_axes_required == 6
