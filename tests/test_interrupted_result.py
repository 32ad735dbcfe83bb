"""A control run of the gradient loop interrupted by a signal writes its
result: the last accepted iterate (a certified equilibrium), marked
``converged: false``, ``reason: interrupted``, the signal in ``status`` and
``signal``;
the command exits with the signal's status (issue 34)."""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from cli_helpers import interrupt

ROOT = Path(__file__).resolve().parents[1]
EXPECTED = {"SIGINT": 130, "SIGTERM": 143, "SIGHUP": 129}
WAIT = 120.0

# `plush-opt solve` whose loop reports each accepted iterate on stdout and,
# from the first step on, takes 2 s per trial: a signal then lands mid-run
SLOW_SOLVE = textwrap.dedent("""
    import sys, time
    from plush_opt.control import gradient
    iterate, trial = gradient.Controller._iterate, gradient.Controller._trial

    def reported(self, *args):
        it = iterate(self, *args)
        print(f"ITERATE {it.iteration}", flush=True)
        return it

    def slow(self, *args):
        if len(self.history) >= 2:
            time.sleep(2.0)
        return trial(self, *args)

    gradient.Controller._iterate, gradient.Controller._trial = reported, slow
    from plush_opt.apps.cli import main
    sys.exit(main(sys.argv[1:]))
""")


# `plush-opt solve` that says when control starts and then waits 2 s before
# its starting solve: a signal then lands before the first iterate
SLOW_START = textwrap.dedent("""
    import sys, time
    from plush_opt.control import gradient
    iterates = gradient.Controller.iterates

    def late(self):
        print("STARTING", flush=True)
        time.sleep(2.0)
        yield from iterates(self)

    gradient.Controller.iterates = late
    from plush_opt.apps.cli import main
    sys.exit(main(sys.argv[1:]))
""")


def _env():
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return env


@pytest.mark.parametrize("name, method", [("SIGTERM", "reparam"), ("SIGINT", "clip"), ("SIGHUP", "reparam")])
def test_interrupted_control_run_writes_an_interrupted_result(tmp_path, name, method):
    out = tmp_path / "r.json"
    proc = subprocess.Popen([sys.executable, "-c", SLOW_SOLVE, "solve", "problems/gripper.yaml",
                             "--method", method, "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), cwd=ROOT)
    deadline = time.monotonic() + WAIT
    for line in proc.stdout:
        if line.startswith("ITERATE 1"):
            break
        if time.monotonic() > deadline:
            proc.kill()
            pytest.fail("no accepted step within the wait")
    else:
        proc.wait()
        pytest.fail(f"the run ended before a step: {proc.stderr.read()[-2000:]}")
    code, err = interrupt(proc, name, WAIT)
    assert code == EXPECTED[name], err[-2000:]
    assert "Traceback" not in err, err
    assert err.strip().splitlines() == [f"plush-opt: interrupted ({name})"], err
    doc = json.loads(out.read_text())
    assert doc["converged"] is False
    assert doc["reason"] == "interrupted" and doc["signal"] == name
    assert doc["status"] == f"interrupted by {name}"
    assert doc["timing"]["iterations"] >= 1
    assert all(math.isfinite(v) for v in doc["contractions"].values())
    assert doc["residual_norm"] is not None and math.isfinite(doc["residual_norm"])
    assert not [p for p in tmp_path.iterdir() if p.name != "r.json"]      # no temp file left


def test_a_signal_before_the_first_iterate_writes_no_result(tmp_path):
    """Interrupted before the starting equilibrium is certified: nothing to report."""
    out = tmp_path / "r.json"
    proc = subprocess.Popen([sys.executable, "-c", SLOW_START, "solve", "problems/gripper.yaml", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), cwd=ROOT)
    assert proc.stdout.readline().strip() == "STARTING", proc.stderr.read()[-2000:]
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=WAIT)
    assert proc.returncode == 143, err[-2000:]
    assert not out.exists()


def test_interrupted_demo_writes_an_interrupted_result(tmp_path):
    """``demo`` ended by a signal mid-control: its result.json is the run so
    far, marked interrupted, and it exits with the signal's status."""
    out = tmp_path / "demo"
    proc = subprocess.Popen([sys.executable, "-c", SLOW_SOLVE, "demo", "--no-board", "--out", str(out)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env(), cwd=ROOT)
    for line in proc.stdout:
        if line.startswith("ITERATE 1"):
            break
    else:
        proc.wait()
        pytest.fail(f"the demo ended before a step: {proc.stderr.read()[-2000:]}")
    code, err = interrupt(proc, "SIGTERM", WAIT)
    assert code == 143, err[-2000:]
    assert err.strip().splitlines() == ["plush-opt: interrupted (SIGTERM)"], err
    doc = json.loads((out / "result.json").read_text())
    assert doc["converged"] is False and doc["reason"] == "interrupted" and doc["signal"] == "SIGTERM"
    assert doc["status"] == "interrupted by SIGTERM"
    assert doc["timing"]["iterations"] >= 1
    assert sorted(p.name for p in out.iterdir()) == ["result.json"]     # nothing else, no temp file
