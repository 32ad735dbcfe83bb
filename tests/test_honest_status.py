"""Honest statuses: ``converged`` only with a finite residual below tolerance;
physics that overflows refused at load; exit 3 always with its result file;
exit codes of ``demo``, of a signal at start-up and of a bad environment."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from plush_opt.apps.cli import main
from plush_opt.solve.certificate import Equilibrium

ROOT = Path(__file__).resolve().parents[1]
CANTILEVER = ROOT / "problems" / "cantilever.yaml"
GRIPPER = ROOT / "problems" / "gripper.yaml"


def _variant(tmp_path: Path, source: Path, old: str, new: str, name="p.yaml") -> Path:
    text = source.read_text()
    assert old in text
    path = tmp_path / name
    path.write_text(text.replace(old, new))
    return path


def _solve(path: Path, out: Path, *extra):
    return main(["-q", "solve", str(path), "-o", str(out), *extra])


# -- item 3: no certificate on non-finite physics ----------------------------

@pytest.mark.parametrize("density, gravity", [("1e200", None), ("1e250", None), ("1e160", "[0.0, -1.0]")])
def test_overflowing_gravity_refused_at_load(tmp_path, capsys, density, gravity):
    path = _variant(tmp_path, CANTILEVER, "density: 1.0e-9", f"density: {density}")
    if gravity is not None:
        path.write_text(path.read_text().replace("gravity: [0.0, -9.81]", f"gravity: {gravity}"))
    out = tmp_path / "r.json"
    assert _solve(path, out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1
    assert "material.density" in err and "gravity" in err
    assert not out.exists()


def test_nonfinite_residual_never_certifies():
    eq = Equilibrium(np.zeros(2), np.zeros(1), True, "converged", 0.0, np.inf, np.inf, True, None, 0, 0.0,
                     "newton")
    assert not eq.converged and "not finite" in eq.status
    eq = Equilibrium(np.zeros(2), np.zeros(1), True, "converged", np.nan, 0.0, 1.0, True, None, 0, 0.0,
                     "newton")
    assert not eq.converged
    ok = Equilibrium(np.zeros(2), np.zeros(1), True, "converged", 1.0, 1e-12, 1.0, True, None, 0, 0.0, "newton")
    assert ok.converged and ok.status == "converged"


# -- item 5: exit 3 writes its result; meaningless moduli refused at load -------

@pytest.mark.parametrize("old, new, key", [
    ("youngs_modulus: 1.0", "youngs_modulus: 1e308", "material.youngs_modulus"),
    ("stiffness: 1.0e+4", "stiffness: 1e308", "pins.stiffness"),
])
def test_meaningless_modulus_refused_at_load(tmp_path, capsys, old, new, key):
    path = _variant(tmp_path, CANTILEVER, old, new)
    out = tmp_path / "r.json"
    assert _solve(path, out) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and key in err and "limit" in err
    assert not out.exists()


@pytest.mark.parametrize("radius", ["1e6", "500"])
def test_solver_error_still_writes_the_result(tmp_path, capsys, radius):
    path = _variant(tmp_path, GRIPPER, "attachment_radius: 2.0", f"attachment_radius: {radius}")
    out = tmp_path / "r.json"
    code = _solve(path, out, "--method", "forward", "-c", "grip=15")
    if code == 2:                            # refused at load (a cap on the radius): also honest
        assert "attachment_radius" in capsys.readouterr().err
        return
    assert code in (0, 3)
    if code == 3:
        doc = json.loads(out.read_text())
        assert doc["converged"] is False and doc["status"]
        assert capsys.readouterr().err.count("\n") <= 2


def test_solver_error_result_document(tmp_path, capsys, monkeypatch):
    """A SolverError inside the forward solve: exit 3, and --out says why."""
    from plush_opt.base.errors import SolverError
    import plush_opt.solve.equilibrium as equilibrium

    def fail(*args, **kwargs):
        raise SolverError("Hessian regularisation failed: no shift made it positive definite")
    monkeypatch.setattr(equilibrium, "solve_newton", fail)
    out = tmp_path / "r.json"
    assert _solve(CANTILEVER, out) == 3
    doc = json.loads(out.read_text())
    assert doc["converged"] is False
    assert doc["status"] == "solver_error" and "Hessian regularisation failed" in doc["reason"]
    assert "Hessian regularisation failed" in capsys.readouterr().err


# -- item 9: exit codes ----------------------------------------------------------

def _env(**extra):
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    env.update(extra)
    return env


def test_bad_linalg_variable_is_exit_2(tmp_path):
    r = subprocess.run([sys.executable, "-m", "plush_opt", "solve", str(CANTILEVER), "-o", str(tmp_path / "r.json")],
                       capture_output=True, text=True, env=_env(PLUSH_OPT_LINALG="bogus"), cwd=tmp_path)
    assert r.returncode == 2, r.stderr
    assert "PLUSH_OPT_LINALG" in r.stderr and "solver error" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("delay", [0.3, 0.6, 1.0])
def test_ctrl_c_during_start_up_is_quiet(tmp_path, delay):
    proc = subprocess.Popen([sys.executable, "-m", "plush_opt", "solve", str(CANTILEVER), "-o",
                             str(tmp_path / "r.json")], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, env=_env(), cwd=tmp_path)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=60)
    if proc.returncode == 0:        # the solve finished before the signal: nothing to check
        return
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    assert len(err.strip().splitlines()) <= 1


def test_ctrl_c_inside_a_c_module_import_is_quiet(monkeypatch, capsys):
    """A Ctrl-C while a C module initialises reaches main() as an ImportError
    raised from the KeyboardInterrupt: still exit 130 and one line."""
    import plush_opt.apps.cli as cli

    def interrupted_import():
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise ImportError("initialization failed") from exc
    monkeypatch.setattr(cli, "build_parser", interrupted_import)
    assert cli.main(["solve", str(CANTILEVER)]) == 130
    err = capsys.readouterr().err
    assert err.strip() == "plush-opt: interrupted (SIGINT)"


def test_ctrl_c_while_the_handlers_are_put_back_changes_nothing(monkeypatch, capsys):
    """A Ctrl-C that lands while main() restores the signal handlers (the
    command done) neither escapes as a traceback nor changes the exit code."""
    import plush_opt.apps.cli as cli
    plain, fired = signal.signal, []

    def signal_then_interrupt(signum, handler):
        old = plain(signum, handler)
        if handler is signal.default_int_handler and not fired:     # (the restore, not the set-up)
            fired.append(signum)
            raise KeyboardInterrupt
        return old
    monkeypatch.setattr(cli.signal, "signal", signal_then_interrupt)
    assert cli.main([]) == 0            # (a bare command prints the overview)
    monkeypatch.undo()
    assert fired
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert capsys.readouterr().err == ""


def test_ctrl_c_while_an_error_is_reported_is_exit_130(monkeypatch, capsys):
    """A Ctrl-C that lands after the command's own handling (while its error
    is described) still ends as one line and exit 130."""
    import plush_opt.apps.cli as cli

    def interrupted(exc):
        raise KeyboardInterrupt
    monkeypatch.setattr(cli, "describe_error", interrupted)
    assert cli.main(["solve", "no-such-file.yaml"]) == 130
    assert capsys.readouterr().err.strip() == "plush-opt: interrupted (SIGINT)"


def test_interrupted_demo_exits_130(tmp_path, monkeypatch, capsys):
    import plush_opt.apps.demo as demo

    def interrupted_run(args):
        return 130
    monkeypatch.setattr(demo, "cmd_run", interrupted_run)
    code = main(["-q", "demo", "--out", str(tmp_path / "demo")])
    assert code == 130
    assert "solver error" not in capsys.readouterr().err
