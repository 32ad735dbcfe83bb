"""The shared file reading: one guarded YAML reader and one Checker for
problem files, board calibrations and run scripts."""

import os
import threading

import numpy as np
import pytest
import yaml

from plush_opt.board.board_file import load_calibration
from plush_opt.base.errors import SceneError
from plush_opt.io import Checker, load_run_script, load_scene, read_yaml
from plush_opt.io.run_script import FORMAT

RUN = {"format": FORMAT, "problem": "problem.yaml", "board": "board.yaml", "rate": 20,
       "steps": [{"set": {"grip": 5.0}}, "release"]}


def _run_script(folder, text: str):
    (folder / "problem.yaml").write_text("format: plush-opt/1\n")
    (folder / "board.yaml").write_text("format: plush-board/1\n")
    path = folder / "run.yaml"
    path.write_text(text)
    return path


def _one_line(exc) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and "Traceback" not in msg, msg
    return msg


# -- run scripts on the shared reader -------------------------------------------

def test_run_script_refuses_duplicate_keys(tmp_path):
    path = _run_script(tmp_path, yaml.safe_dump(RUN, sort_keys=False).replace(
        "- set:\n    grip: 5.0\n", "- set: {grip: 5.0, grip: 15.0}\n"))
    with pytest.raises(SceneError, match=r"run\.yaml: line \d+: steps\[0\]\.set\.grip: duplicate key") as e:
        load_run_script(path)
    _one_line(e)


def test_run_script_refuses_aliases(tmp_path):
    text = yaml.safe_dump(RUN, sort_keys=False) + "description: &d x\n"
    with pytest.raises(SceneError, match=r"run\.yaml: line \d+: anchor &d \(anchors and aliases"):
        load_run_script(_run_script(tmp_path, text))


def test_run_script_reads_exponents_as_numbers(tmp_path):
    text = yaml.safe_dump(RUN, sort_keys=False).replace("rate: 20", "rate: 1e1")
    assert load_run_script(_run_script(tmp_path, text)).rate == 10.0
    text = text.replace("grip: 5.0", "grip: 5e-1")
    assert load_run_script(_run_script(tmp_path, text)).steps[0].contraction == {"grip": 0.5}


def test_run_script_not_utf8_is_one_clear_line(tmp_path):
    path = _run_script(tmp_path, "")
    path.write_bytes(yaml.safe_dump(RUN).encode() + b"description: caf\xe9\n")
    with pytest.raises(SceneError, match=r"run\.yaml: not UTF-8 text \(byte \d+\)$") as e:
        load_run_script(path)
    _one_line(e)


def test_calibration_refuses_duplicate_keys_and_reads_exponents(tmp_path):
    path = tmp_path / "board.yaml"
    path.write_text("format: plush-board/1\nname: b\nname: c\n")
    with pytest.raises(SceneError, match=r"board\.yaml: line 3: name: duplicate key"):
        load_calibration(path)
    path.write_text("format: plush-board/1\nname: b\nwinches:\n- {name: w, spool_radius: 6e0, "
                    "ticks_per_rev: 1.2e1, gear_ratio: 1e2, limits: [0, 2.5e1], max_speed: 15}\n")
    w = load_calibration(path).winch("w")
    assert (w.spool_radius, w.ticks_per_rev, w.gear_ratio, w.limits) == (6.0, 12.0, 100.0, (0.0, 25.0))


# -- the reader -----------------------------------------------------------------

def test_nul_bytes_are_one_clear_line(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_bytes(b"format: plush-opt/1\nname: a\x00b\n")
    for read in (load_scene, load_run_script, load_calibration):
        with pytest.raises(SceneError, match=r"p\.yaml: not a text file \(NUL byte at byte 27\)") as e:
            read(path)
        _one_line(e)


def test_control_characters_are_one_clear_line(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_bytes(b"name: a\x07b\n")
    with pytest.raises(SceneError, match=r"^p\.yaml: character 7: character #x0007 is not allowed") as e:
        read_yaml(path)
    _one_line(e)


@pytest.mark.skipif(not hasattr(os, "mkfifo"), reason="no FIFOs here")
def test_a_fifo_is_refused_without_blocking(tmp_path):
    fifo = tmp_path / "pipe.yaml"
    os.mkfifo(fifo)
    outcome = []

    def read():
        with pytest.raises(SceneError) as e:
            read_yaml(fifo, what="run script")
        outcome.append(str(e.value))
    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    reader.join(10.0)
    if reader.is_alive():                      # unblock the reader before failing
        with open(fifo, "wb"):
            pass
        pytest.fail("reading a FIFO blocked")
    assert outcome == ["pipe.yaml: not a regular file (a pipe, socket or device), not a run script"]


def test_device_and_directory_are_refused(tmp_path):
    with pytest.raises(SceneError, match=r"^null: not a regular file"):
        read_yaml(os.devnull)
    with pytest.raises(SceneError, match=r"is a directory, not a board calibration file$"):
        load_calibration(tmp_path)


def test_size_cap_is_a_parameter(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("a: 1\n" + "# padding\n" * 4)
    assert read_yaml(path, max_bytes=50) == {"a": 1}
    with pytest.raises(SceneError, match=r"file larger than 40 bytes"):
        read_yaml(path, max_bytes=40)


def test_reader_returns_plain_data(tmp_path):
    path = tmp_path / "p.yaml"
    path.write_text("a: [1, 2.5, 1e3, true, null, x]\n")
    assert read_yaml(path) == {"a": [1, 2.5, 1000.0, True, None, "x"]}


# -- the Checker ------------------------------------------------------------------

def test_checker_messages():
    ck = Checker("f.yaml")
    with pytest.raises(SceneError, match=r"^f\.yaml: a\.b: expected a number, got boolean true$"):
        ck.number(True, "a.b")
    with pytest.raises(SceneError, match=r"^f\.yaml: x\[1\]: must be > 0, got -2\.0$"):
        ck.number(-2, "x[1]", gt=0)
    with pytest.raises(SceneError, match=r"^f\.yaml: rat: unknown key \(did you mean 'rate'\?\); "
                                         r"allowed keys: rate, steps$"):
        ck.mapping({"rat": 1}, "", ("rate", "steps"))
    with pytest.raises(SceneError, match=r"^f\.yaml: the document must be a mapping of keys"):
        ck.document([1], ("a",))
    assert ck.number(np.float64(1e1), "n") == 10.0
    assert ck.point(np.array([1, 2]), "p") == (1.0, 2.0)
    assert ck.points([[0, 0], [1, 2]], "pts").shape == (2, 2)
    with pytest.raises(SceneError, match=r"^f\.yaml: n: expected an integer, got number 1\.0$"):
        ck.integer(1.0, "n")
