"""docs/quickstart.md works as written (issue 35): its files are written
into an empty folder and each of its commands runs there with exit 0."""

import os
import re
import shlex
import subprocess
import sys

import pytest

from shipped import ROOT

pytestmark = pytest.mark.slow      # two solves and a run on the emulator

DOC = ROOT / "docs" / "quickstart.md"


def _blocks(marker: str):
    return re.findall(rf"<!-- {marker} -->\n```\w+\n(.*?)```", DOC.read_text(), re.S)


def test_the_quickstart_runs_as_written(tmp_path):
    files = re.findall(r"<!-- file: (\S+) -->\n```yaml\n(.*?)```", DOC.read_text(), re.S)
    assert [name for name, _ in files] == ["first.yaml", "board.yaml", "run.yaml"]
    for name, text in files:
        (tmp_path / name).write_text(text)
    commands = [line for block in _blocks("run") for line in block.strip().splitlines()]
    assert len(commands) == 3 and all(c.startswith("plush-opt ") for c in commands)
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    said = {}
    for command in commands:
        args = shlex.split(command)[1:]
        p = subprocess.run([sys.executable, "-m", "plush_opt", *args], cwd=tmp_path, env=env,
                           capture_output=True, text=True, timeout=600)
        assert p.returncode == 0, (command, p.stdout, p.stderr)
        assert "warning" not in p.stderr, (command, p.stderr)
        said[command] = p.stdout + p.stderr
    # the clause of the control run's line the page quotes, as it prints it
    quoted = re.search(r"The line it prints says\s+`(bound\s+active:.*?)`", DOC.read_text(), re.S)
    control = next(out for command, out in said.items() if "--out result.json" in command)
    assert quoted and " ".join(quoted.group(1).split()) in control, control
    doc = __import__("json").loads((tmp_path / "result.json").read_text())
    assert doc["converged"] is True
    assert (tmp_path / "forward.png").is_file() and (tmp_path / "result.png").is_file()
    assert "completed on emulator" in p.stderr
