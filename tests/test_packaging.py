"""The wheel is self-sufficient: built, installed into a virtualenv of its
locked dependencies without the cholmod extra (made fresh the first time
for each interpreter and lock, then kept: see ``_venv``), and used from an empty folder as a new user
would (the shipped examples, the demo, a run on the emulator compiled on
first use, the four calls of docs/api.md)."""

import fcntl
import hashlib
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


#: Python versions the package supports besides the one running the tests
#: (pyproject.toml's requires-python, README's "Install"): each gets a fresh
#: venv where its interpreter is found (on PATH, or under pyenv's root).
OTHER_PYTHONS = ("3.11", "3.12", "3.13")


def _interpreter(version: str) -> str | None:
    """A working ``python{version}``, or None."""
    candidates = [shutil.which(f"python{version}")]
    pyenv = shutil.which("pyenv")
    if pyenv:
        root = subprocess.run([pyenv, "root"], capture_output=True, text=True).stdout.strip()
        candidates += sorted(str(p) for p in Path(root).glob(f"versions/{version}*/bin/python{version}"))
    for c in filter(None, candidates):
        p = subprocess.run([c, "-c", "import sys; print('%d.%d' % sys.version_info[:2])"],
                           capture_output=True, text=True)
        if p.returncode == 0 and p.stdout.strip() == version:
            return c
    return None


def _install(tmp, python: str):
    """(venv bin folder, environment) of a venv of ``python`` with the built wheel installed."""
    if shutil.which("c++") is None and shutil.which("g++") is None:
        pytest.skip("no C++ compiler: the emulator cannot be compiled on first use")
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PLUSH_BOARD_EMU")}
    env["PLUSH_OPT_CACHE"] = str(tmp / "cache")      # the emulator is built anew, as on a new machine
    env["OPENBLAS_NUM_THREADS"] = "1"
    # Built from a clean copy: a build/ folder left in the tree would smuggle stale files into the wheel.
    src = tmp / "src"
    shutil.copytree(ROOT, src, ignore=shutil.ignore_patterns(".git", ".venv", "build", "out", "*.egg-info",
                                                             "__pycache__", ".pytest_cache", ".hypothesis"))
    _sh([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(tmp / "dist"), str(src)], tmp, env)
    wheel = next((tmp / "dist").glob("plush_opt-*.whl"))
    bin_ = _venv(python, wheel, tmp, env)
    # this wheel anew, and its dependencies checked against the lock (installed where missing)
    _sh([bin_ / "python", "-m", "pip", "install", "-q", "--force-reinstall", "--no-deps", str(wheel)], tmp, env)
    _sh([bin_ / "python", "-m", "pip", "install", "-q", "-c", str(ROOT / "requirements.lock"), str(wheel)], tmp, env)
    return bin_, env


def _venv(python: str, wheel: Path, tmp: Path, env) -> Path:
    """The bin folder of a venv of ``python`` where a wheel of the package
    was installed with its locked dependencies.

    It is made fresh the first time and kept across test runs, keyed by the
    interpreter, the lock and pyproject.toml (like pip's cache, it saves
    downloading and unpacking the same wheels again: a minute per venv);
    any change of those makes a new one. ``PLUSH_TEST_FRESH_VENV=1`` makes
    it in the test's own folder every time."""
    version = subprocess.run([python, "-c", "import sys; print(sys.version)"], capture_output=True,
                             text=True).stdout
    key = hashlib.sha256("\n".join([version, (ROOT / "requirements.lock").read_text(),
                                     (ROOT / "pyproject.toml").read_text()]).encode()).hexdigest()[:16]
    if os.environ.get("PLUSH_TEST_FRESH_VENV") == "1":
        where = tmp / "venv"
    else:
        cache = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "plush_opt-test-venvs"
        where = cache / f"{Path(python).name}-{key}"
    where.parent.mkdir(parents=True, exist_ok=True)
    with open(where.parent / f"{where.name}.lock", "a") as lock:
        fcntl.flock(lock.fileno(), fcntl.LOCK_EX)      # two test sessions at once build it once
        done = where / ".dependencies-installed"
        if not done.is_file():
            shutil.rmtree(where, ignore_errors=True)      # a venv left half-made by an interrupted run
            _sh([python, "-m", "venv", str(where)], tmp, env)
            _sh([where / "bin" / "python", "-m", "pip", "install", "-q", "-c", str(ROOT / "requirements.lock"),
                 str(wheel)], tmp, env)
            done.touch()
    return where / "bin"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(venv bin folder, environment) of a fresh venv of this interpreter with the built wheel installed."""
    return _install(tmp_path_factory.mktemp("wheel"), getattr(sys, "_base_executable", sys.executable))


@pytest.fixture(scope="module", params=[v for v in OTHER_PYTHONS if v != "%d.%d" % sys.version_info[:2]])
def installed_other(request, tmp_path_factory):
    """The same on each other supported Python version whose interpreter is on this machine."""
    python = _interpreter(request.param)
    if python is None:
        pytest.skip(f"no python{request.param} on this machine")
    return _install(tmp_path_factory.mktemp(f"wheel{request.param}"), python)


def test_requires_python_admits_the_versions_tested():
    import tomllib
    spec = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["requires-python"]
    from packaging.specifiers import SpecifierSet
    assert all(v in SpecifierSet(spec) for v in OTHER_PYTHONS), spec
    assert "3.14" not in SpecifierSet(spec)        # not tested: not claimed


def test_the_demo_on_every_supported_python(installed_other, tmp_path):
    """``pip install`` of the wheel and the demo (a solve, a run on the
    emulator compiled on first use) in a fresh venv of Python 3.11-3.13."""
    bin_, env = installed_other
    demo = _sh([str(bin_ / "plush-opt"), "demo", "--out", "d"], tmp_path, env)
    assert (tmp_path / "d" / "pose.png").is_file() and (tmp_path / "d" / "run.png").is_file()
    assert "targets RMS error" in demo.stdout


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
