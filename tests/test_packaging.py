"""The wheel is self-sufficient: built, installed into a fresh virtualenv
without the cholmod extra, and used from an empty folder as a new user
would (the shipped examples, the demo, a run on the emulator compiled on
first use, the four calls of docs/api.md)."""

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from shipped import ROOT

pytestmark = pytest.mark.slow  # builds and installs the wheel in a new virtualenv

BUILD_TIMEOUT = 600    # s: the wheel, then the dependencies' wheels into a new venv


def _sh(cmd, cwd, env, timeout=BUILD_TIMEOUT):
    p = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert p.returncode == 0, f"{' '.join(map(str, cmd))} exited {p.returncode}\n{p.stdout[-3000:]}\n{p.stderr[-3000:]}"
    return p


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(venv bin folder, environment) of a fresh venv with the built wheel installed."""
    if shutil.which("c++") is None and shutil.which("g++") is None:
        pytest.skip("no C++ compiler: the emulator cannot be compiled on first use")
    tmp = tmp_path_factory.mktemp("wheel")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PLUSH_BOARD_EMU")}
    env["PLUSH_OPT_CACHE"] = str(tmp / "cache")      # the emulator is built anew, as on a new machine
    env["OPENBLAS_NUM_THREADS"] = "1"
    # Built from a clean copy: a build/ folder left in the tree would smuggle stale files into the wheel.
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", ".venv", "build", "out", "*.egg-info",
                                                             "__pycache__", ".pytest_cache", ".hypothesis"))
    _sh([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(src)], tmp, env)
    wheel = next((tmp / "dist").glob("plush_opt-*.whl"))
    base = getattr(sys, "_base_executable", sys.executable)
    _sh([base, "-m", "venv", str(tmp / "venv")], tmp, env)
    bin_ = tmp / "venv" / "bin"
    _sh([bin_ / "python", "-m", "pip", "install", "-q", "-c", str(ROOT / "requirements.lock"), str(wheel)], tmp, env)
    return bin_, env


def test_the_wheel_installs_without_cholmod_and_carries_its_files(installed):
    bin_, env = installed
    p = _sh([bin_ / "python", "-c", "import importlib.util as u, plush_opt.base.linalg as l; "
             "print(u.find_spec('sksparse') is None, l.__file__)"], bin_, env)
    assert p.stdout.split()[0] == "True"                 # the sparse backend came from a wheel
    assert "site-packages" in p.stdout


def test_a_new_user_in_an_empty_folder(installed, tmp_path):
    bin_, env = installed
    cli = str(bin_ / "plush-opt")
    _sh([cli, "examples", "ex"], tmp_path, env)
    demo = _sh([cli, "demo", "--out", "d"], tmp_path, env)
    assert (tmp_path / "d" / "pose.png").is_file() and (tmp_path / "d" / "run.png").is_file()
    assert "targets RMS error" in demo.stdout
    run = _sh([cli, "run", "ex/examples/gripper_run.yaml", "--emulator"], tmp_path, env)
    assert "completed on emulator" in run.stderr
    assert list(Path(env["PLUSH_OPT_CACHE"]).glob("emulator-*/plush-board-emu"))
    _sh([str(bin_ / "python"), "-m", "plush_opt", "--version"], tmp_path, env)


def test_the_documented_api_works_from_the_installed_wheel(installed, tmp_path):
    bin_, env = installed
    _sh([str(bin_ / "plush-opt"), "examples", "."], tmp_path, env)
    script = textwrap.dedent("""
        import json, plush_opt
        p = plush_opt.load("problems/gripper.yaml")
        eq = p.equilibrium({"left": 10.0})
        assert eq.converged, eq.status
        result = p.control(method="reparam")
        assert result.converged and set(result.contractions) == {"left", "right", "grip"}
        result.save("r.json")
        assert json.load(open("r.json"))["method"] == "reparam"
    """)
    _sh([str(bin_ / "python"), "-c", script], tmp_path, env)
