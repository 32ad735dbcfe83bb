"""The Arduino sketch compiles (on the host, against a stub Arduino API) and
serves the protocol through the same core as the emulator."""

import shutil
import subprocess
from pathlib import Path

import pytest

HW = Path(__file__).resolve().parents[2] / "hw"


def test_sketch_compiles_and_answers():
    for tool in ("make", "g++"):
        if shutil.which(tool) is None:
            pytest.fail(f"{tool} not found: the firmware check needs make and g++ (apt-get install make g++)",
                        pytrace=False)
    r = subprocess.run(["make", "-s", "-C", str(HW), "firmware-check"], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "1 OK board=plush-winch fw=1.1.0 proto=1 winches=4" in r.stdout
    assert "firmware-check: ok" in r.stdout


def test_missing_compiler_is_named_with_the_fix(tmp_path):
    r = subprocess.run(["make", "-s", "-C", str(HW), "CXX=no-such-g++", f"BUILD={tmp_path}/build"],
                       capture_output=True, text=True, timeout=60)
    assert r.returncode != 0
    assert "C++ compiler 'no-such-g++' not found" in r.stderr and "apt-get install g++" in r.stderr
    assert not (tmp_path / "build").exists()
