"""Batches of solves (plush_opt.batch): parallel results equal the serial
run's bit for bit and in input order, a failing input is reported and the
others finish, an interruption keeps what finished, the Dask backend runs a
study on a LocalCluster, and ``plush-opt study`` refuses bad --vary keys
with one line (exit 2)."""

import io
import math

import pytest

from cli_helpers import cli, one_error_line
from plush_opt.base.errors import SceneError
from plush_opt.batch import run_batch
from plush_opt.batch.progress import Progress
from plush_opt.batch.study import StudyOptions, Vary, parse_vary, run_study, variants
from shipped import ROOT

GRIPPER = ROOT / "problems" / "gripper.yaml"
# a coarse mesh and short sweeps: the test is about the batch, not the physics
COARSE = StudyOptions(max_area=150.0, sweep_steps=2)


def _timeless(rows):
    return [{k: v for k, v in r.items() if k != "t_wall"} for r in rows]


@pytest.mark.slow
def test_parallel_study_equals_serial_bit_for_bit():
    varies = [parse_vary("material.youngs_modulus=0.01:0.04:2"), parse_vary("tendons.friction=0,0.3")]
    serial = run_study(GRIPPER, varies, COARSE, jobs=1)
    parallel = run_study(GRIPPER, varies, COARSE, jobs=2)
    assert serial.batch.backend == "serial" and parallel.batch.backend == "loky"
    assert [r["material.youngs_modulus"] for r in parallel.rows] == [0.01, 0.01, 0.04, 0.04]
    assert [r["tendons.friction"] for r in parallel.rows] == [0.0, 0.3, 0.0, 0.3]
    # == on floats: the same bits, not merely close
    assert _timeless(serial.rows) == _timeless(parallel.rows)
    for row in parallel.rows:
        assert row["certified"], row
        assert math.isfinite(row["target_error"]) and row["max_tension"] > 0
    # friction loses work in a pull-and-release cycle; without it the loop closes (0, not the
    # solver's round-off of a sweep there and back)
    assert parallel.rows[1]["hysteresis_work"] > 0.0 == parallel.rows[0]["hysteresis_work"]


@pytest.mark.parametrize("jobs", [1, 2])
def test_a_failing_input_is_reported_and_the_others_finish(jobs):
    inputs = ["a=1:2:2", "a=bad", "b.c=3,4"]
    out = io.StringIO()
    batch = run_batch(parse_vary, inputs, jobs=jobs, progress=Progress("t", stream=out, bar=False))
    assert [r.status for r in batch.items] == ["ok", "failed", "ok"]
    assert [r.index for r in batch.items] == [0, 1, 2]
    assert batch.items[0].value == Vary("a", (1.0, 2.0))
    assert batch.items[2].value == Vary("b.c", (3.0, 4.0))
    assert "--vary a=bad" in batch.items[1].error and "\n" not in batch.items[1].error
    assert batch.failed == [batch.items[1]] and not batch.interrupted
    lines = out.getvalue().splitlines()
    assert len(lines) == 4 and lines[0].startswith("t: 3 input(s)")
    assert any(line.startswith("t: [") and "failed: --vary a=bad" in line for line in lines)


def test_an_interruption_keeps_what_finished():
    def fn(i):
        if i == 2:
            raise KeyboardInterrupt
        return i * i

    batch = run_batch(fn, range(5), jobs=1)
    assert batch.interrupted
    assert [r.status for r in batch.items] == ["ok", "ok", "interrupted", "interrupted", "interrupted"]
    assert batch.values[:2] == [0, 1]
    with pytest.raises(KeyboardInterrupt):
        batch.raise_if_interrupted()


def test_jobs_are_checked():
    with pytest.raises(ValueError, match="jobs"):
        run_batch(abs, [1], jobs=0)


@pytest.mark.slow
def test_dask_local_cluster_runs_a_study():
    distributed = pytest.importorskip("distributed")
    varies = [parse_vary("material.youngs_modulus=0.01:0.05:2"), parse_vary("tendons.friction=0,0.2")]
    options = StudyOptions(max_area=300.0, sweep_steps=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster, distributed.Client(cluster) as client:
        result = run_study(GRIPPER, varies, options, scheduler=client)
    assert result.batch.backend == "dask" and result.batch.jobs == 2
    assert len(result.rows) == 4 and all(r["certified"] for r in result.rows), result.rows
    # the same answers as this process gives, in the same order
    serial = run_study(GRIPPER, varies[:1], options, jobs=1)
    assert _timeless(serial.rows) == [
        {k: v for k, v in r.items() if k not in ("t_wall", "tendons.friction")}
        for r in _timeless(result.rows) if r["tendons.friction"] == 0.0]


def test_variants_are_checked_before_anything_runs(tmp_path):
    with pytest.raises(SceneError, match=r"--vary: gripper.yaml \[material.youngs_modulus=-1\]: "
                       r"material.youngs_modulus"):
        variants(GRIPPER, [parse_vary("material.youngs_modulus=-1,0.02")])
    with pytest.raises(SceneError, match="given twice"):
        variants(GRIPPER, [parse_vary("tendons.friction=0,1"), parse_vary("tendons.friction=2")])
    vs = variants(GRIPPER, [parse_vary("material.youngs_modulus=0.01:0.02:2"),
                            parse_vary("tendons.list[0].friction=0.1")])
    assert [v.values for v in vs] == [(("material.youngs_modulus", 0.01), ("tendons.list[0].friction", 0.1)),
                                      (("material.youngs_modulus", 0.02), ("tendons.list[0].friction", 0.1))]
    assert vs[1].document["tendons"]["list"][0]["friction"] == 0.1


@pytest.mark.slow
@pytest.mark.parametrize("vary, message", [
    ("foo.bar=1:2:3", "the problem file has no 'foo'"),
    ("material.model=1:2:2", "material.model is 'neo_hookean' in the file, not a number"),
    ("material.youngs_modulus=abc", "is neither A:B:N"),
    ("material.youngs_modulus=1:2:0", "the number of values must be 1..1000, got 0"),
    ("tendons.frictio=0,1", "tendons.frictio: unknown key"),
    ("tendons.list[9].friction=0", "tendons.list[9]: the file's list has 4 entries"),
    ("youngs_modulus", "expected KEY=A:B:N"),
    ("tendons.friction=0 --sweep-winch nope", "--sweep-winch nope: no winch named 'nope'"),
])
def test_study_refuses_bad_vary_with_one_line(tmp_path, vary, message):
    vary, *more = vary.split(" ")
    line = one_error_line(cli("study", GRIPPER, "--vary", vary, *more, "--out", tmp_path / "s"))
    assert message in line, line
    assert not (tmp_path / "s" / "study.csv").exists()


@pytest.mark.slow
def test_study_command_writes_table_report_and_picture(tmp_path):
    p = cli("study", GRIPPER, "--vary", "material.youngs_modulus=0.02,0.04", "--max-area", "150",
            "--sweep-steps", "2", "--jobs", "1", "--out", tmp_path / "s", timeout=300)
    assert p.returncode == 0, p.stderr
    lines = (tmp_path / "s" / "study.csv").read_text().splitlines()
    assert lines[0].startswith("material.youngs_modulus,status,certified") and len(lines) == 3
    assert "| 0.04 |" in (tmp_path / "s" / "report.md").read_text()
    assert (tmp_path / "s" / "study.png").stat().st_size > 0
    assert "study: [2/2] youngs_modulus=0.04: ok" in p.stderr


@pytest.mark.slow
def test_calibration_from_several_starts_is_the_same_in_parallel():
    from plush_opt.batch.multistart import calibrate_from_starts
    from plush_opt.fit import FitOptions
    from plush_opt.fit.starts import fit_cost
    from plush_opt.io.measurement import load_measurements
    meas = load_measurements(ROOT / "examples" / "hexapod_leg_measurements.yaml")
    runs = [calibrate_from_starts(meas, None, FitOptions(), 3, jobs=jobs) for jobs in (1, 2)]
    (result, outcomes, best), (_, outcomes_2, best_2) = runs
    assert outcomes == outcomes_2 and best == best_2
    starts = [o.start["youngs_modulus"] for o in outcomes]
    assert len(set(starts)) == 3 and starts[0] == pytest.approx(0.02)
    assert all(o.converged for o in outcomes)
    # every start finds the same minimum here: the scene's start wins the tie
    assert best == 0
    # the whole result is the best start's fit made again: the same cost, bit for bit
    assert fit_cost(meas, result, None) == outcomes[best].cost


@pytest.mark.slow
def test_ctrl_c_ends_the_workers_and_writes_what_finished(tmp_path):
    import csv
    import signal
    import subprocess
    import sys
    out = tmp_path / "s"
    p = subprocess.Popen([sys.executable, "-m", "plush_opt", "study", str(GRIPPER), "--vary",
                          "material.youngs_modulus=0.01:0.08:40", "--max-area", "150", "--sweep-steps", "2",
                          "--jobs", "2", "--out", str(out)], stderr=subprocess.PIPE, text=True)
    seen = []
    for line in p.stderr:           # one line per finished variant (not a terminal: no bar)
        seen.append(line)
        if ": ok (" in line:
            break
    p.send_signal(signal.SIGINT)
    rest = p.stderr.read()
    assert p.wait(timeout=120) == 130, "".join(seen) + rest
    assert "plush-opt: interrupted (SIGINT)" in rest and "Traceback" not in rest
    rows = list(csv.DictReader((out / "study.csv").open()))
    assert len(rows) == 40
    statuses = [r["status"] for r in rows]
    assert statuses.count("interrupted") > 0 and any(s.startswith("ok") for s in statuses)
    assert "Interrupted" in (out / "report.md").read_text()
