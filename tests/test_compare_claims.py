"""What compare's report claims about its times and its reference (issue 35):
a time is the median of its repeats, or said to be one sample; the
reference's check is not presented as a bound of the reference's error."""

import math

import pytest

from plush_opt.apps.compare import runner
from plush_opt.apps.compare.report import timing_note
from plush_opt.apps.compare.settings import CompareSettings, Run


def _run(t):
    return Run("p", "reparam", "main", "default", "P1", 1.0, 1.0, 10, 10, t_solve=t, t_setup=0.0)


@pytest.mark.parametrize("times, median", [((3.0, 1.0, 2.0), 2.0), ((5.0, 0.1, 0.2, 4.0), 0.2),
                                           ((0.7,), 0.7), ((math.nan, 1.0, 2.0), 2.0)])
def test_a_case_keeps_the_run_of_median_time(monkeypatch, times, median):
    it = iter(times)
    monkeypatch.setattr(runner, "_run_once", lambda *args: _run(next(it)))
    settings = CompareSettings(repeat=len(times), resolve_bilevel_iterates=False)
    assert runner._run(None, "reparam", "default", ("P1", 1.0), "main", settings).t_solve == median


def test_the_report_says_what_its_times_are():
    assert "one sample per run" in timing_note(1) and "not speeds" in timing_note(1)
    assert timing_note(3) == "Times are the median of 3 runs of each case (wall seconds)."
    assert CompareSettings.coarse().repeat == 1 and CompareSettings.full().repeat >= 3
