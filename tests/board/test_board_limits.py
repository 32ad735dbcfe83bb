"""plush_opt.board.limits: the one check of contractions against the allowed ranges."""

import math

import numpy as np
import pytest

from plush_opt.board.limits import allowed_ranges, check_contractions
from plush_opt.base.errors import HardwareError


def test_allowed_ranges_intersect_calibration_limits_with_scene_bounds(calibration):
    allowed = allowed_ranges(calibration, {"left": (-5.0, 10.0), "grip": (2.0, 30.0)})
    assert allowed == {"left": (0.0, 10.0), "right": (0.0, 25.0), "grip": (2.0, 25.0)}
    assert allowed_ranges(calibration) == {w.name: w.limits for w in calibration.winches}


@pytest.mark.parametrize("bounds, match", [
    ({"thumb": (0, 1)}, r"fast\.yaml: scene winch 'thumb' is not calibrated; calibrated winches: left, right, grip"),
    ({"grip": (26.0, 30.0)}, r"fast\.yaml: winch 'grip': scene bounds \[26, 30\] and calibration limits "
                             r"\[0, 25\] do not overlap"),
])
def test_allowed_ranges_refuse_bounds_that_do_not_fit(calibration, bounds, match):
    with pytest.raises(HardwareError, match=match):
        allowed_ranges(calibration, bounds)


def test_check_converts_to_ticks_by_the_calibration(calibration):
    allowed = allowed_ranges(calibration, {"grip": (0.0, 20.0)})
    command = {"left": 12.5, "right": 7.25, "grip": np.float64(3.0)}
    assert check_contractions(command, allowed, calibration) == calibration.to_ticks(command)
    assert check_contractions({}, allowed, calibration) == {}
    assert check_contractions({"left": np.int64(2)}, allowed, calibration) == calibration.to_ticks({"left": 2.0})
    # float noise at a bound is clamped onto it, nothing more
    assert check_contractions({"grip": 20.0 + 1e-12}, allowed, calibration) == calibration.to_ticks({"grip": 20.0})


@pytest.mark.parametrize("command, match", [
    ({"thumb": 1.0}, r"no winch 'thumb' in calibration fast\.yaml; calibrated winches: left, right, grip"),
    ({"grip": 20.5}, r"contraction 20\.5 for winch 'grip' is outside its allowed range \[0, 20\]"),
    ({"left": -0.01}, r"contraction -0\.01 for winch 'left' is outside its allowed range \[0, 25\]"),
    ({"left": 1.0, "right": "10"}, r"contraction '10' for winch 'right' is not a finite number"),
    ({"left": True}, r"contraction True for winch 'left' is not a finite number"),
    ({"left": np.bool_(True)}, r"for winch 'left' is not a finite number"),
    ({"left": None}, r"contraction None for winch 'left' is not a finite number"),
    ({"left": math.nan}, r"contraction nan for winch 'left' is not a finite number"),
    ({"left": -math.inf}, r"contraction -inf for winch 'left' is not a finite number"),
    ({"left": [1.0]}, r"contraction \[1\.0\] for winch 'left' is not a finite number"),
])
def test_check_refuses_with_the_winch_and_the_value(calibration, command, match):
    allowed = allowed_ranges(calibration, {"grip": (0.0, 20.0)})
    with pytest.raises(HardwareError, match=match):
        check_contractions(command, allowed, calibration)
