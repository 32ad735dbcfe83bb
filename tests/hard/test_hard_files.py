"""Bad meshes and bad files through the command line, as a user meets them:
``python -m plush_opt solve FILE --out OUT``.

Every invalid input must end in exit status 2, exactly one line on stderr
that names the file, the key and the list index, no traceback, and no
result file. The invocations are independent processes, so they run
concurrently once per module; each test then checks one of them.

The loader's own tests (tests/test_scene.py) call ``load_scene`` on
tests/bad/; here the same files, the invalid files of problems/hard/invalid/
and a few generated ones go through the CLI end to end.
"""

from __future__ import annotations

import concurrent.futures
import json
import os
import re

import numpy as np
import pytest

import plush_opt.problem
from hardlib import HARD, INVALID, ROOT, assert_one_line_error, cli, expect_line
from plush_opt.base.errors import SceneError
from spec_checker import check_result

pytestmark = pytest.mark.slow  # one process per file, all started by the first test

BAD = ROOT / "tests" / "bad"
INVALID_FILES = sorted(INVALID.glob("*.yaml"))
#: the loader's bad files that cover cases of the issue not in problems/hard/invalid/
#: (each CLI run costs a process start, so not all of tests/bad/)
BAD_FILES = [BAD / f"{stem}.yaml" for stem in (
    "billion_laughs", "degenerate_triangle", "duplicate_tendon", "string_as_number",
    "empty_winches", "unknown_key", "nan_value", "syntax_error", "wrong_format")]


#: files better made than committed: key -> expected error pattern
GENERATED = {
    "five_megabytes": r"file larger than 1048576 bytes \(1 MiB\); not a problem file",
    "alias_bomb": r"line 1: anchor &a0 \(anchors and aliases are not allowed\)",
    # random bytes hold a NUL (not text) or an invalid sequence (not UTF-8), whichever comes first
    "random_bytes": r"not UTF-8 text \(byte \d+\)|not a text file \(NUL byte at byte \d+\)",
    "empty": r"the file is empty",
    "truncated": r"tendons\.list\[0\]",
    "no_such_file": r"no such file",
    "a_directory": r"is a directory, not a problem file",
}
#: how far the reader gets before it refuses each GENERATED file: "read" (the
#: bytes are refused, never parsed), "compose" (refused while composing the
#: YAML: never walked nor built, so aliases are never expanded), "check" (a
#: small document, built and refused by the checker)
REFUSED_AT = {"five_megabytes": "read", "alias_bomb": "compose", "random_bytes": "read",
              "empty": "compose", "truncated": "check", "no_such_file": "read", "a_directory": "read"}
#: the reader's stages (tests/conftest.py) a file refused at each point never reaches
NOT_REACHED = {"read": {"parse", "node", "walk", "construct"}, "compose": {"walk", "construct"},
               "check": set()}


def _generate(folder):
    """Write the GENERATED files into ``folder``: key -> path."""
    folder.mkdir(parents=True, exist_ok=True)
    gripper = (ROOT / "problems" / "gripper.yaml").read_bytes()
    paths = {key: folder / f"{key}.yaml" for key in GENERATED}
    paths["five_megabytes"].write_bytes(
        gripper + b"# padding padding padding padding padding padding padding\n" * 90_000)
    assert paths["five_megabytes"].stat().st_size > 5_000_000
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 10) + "]" for i in range(1, 30)]
    paths["alias_bomb"].write_text("\n".join(lines) + "\n")      # 10^30 "lol"s if expanded
    paths["random_bytes"].write_bytes(b"format: plush-opt/1\n"
                                      + np.random.default_rng(7).bytes(4000) + b"\xff\xfe")
    paths["empty"].write_text("")
    # cut in the middle of the first tendon's entry
    paths["truncated"].write_bytes(gripper[: gripper.index(b"- name: left\n      winch") + 27])
    paths["a_directory"].mkdir(exist_ok=True)
    return paths


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Every CLI invocation of this module, run concurrently: key -> (process, out path, input path)."""
    tmp = tmp_path_factory.mktemp("cli")
    jobs = {}
    for path in INVALID_FILES:
        jobs[f"invalid/{path.stem}"] = (path, ())
    for path in BAD_FILES:
        jobs[f"bad/{path.stem}"] = (path, ())
    for key, path in _generate(tmp / "generated").items():
        jobs[f"generated/{key}"] = (path, ())
    for name in ("underpinned_one_pin", "underpinned_one_node", "underpinned_island",
                 "underpinned_hinge"):
        jobs[f"hard/{name}"] = (HARD / f"{name}.yaml", ())
    jobs["hard/inverted_explicit"] = (HARD / "inverted_explicit.yaml", ("--method", "forward"))
    jobs["hard/sliver_explicit"] = (HARD / "sliver_explicit.yaml", ("--method", "forward"))

    def run(key):
        path, extra = jobs[key]
        out = tmp / "out" / key.replace("/", "__") / "result.json"
        out.parent.mkdir(parents=True, exist_ok=True)
        p = cli("solve", path, *extra, "--out", out)
        return key, p, out, path

    workers = min(8, (os.cpu_count() or 2) + 1)
    with concurrent.futures.ThreadPoolExecutor(workers) as pool:
        return {key: (p, out, path) for key, p, out, path in pool.map(run, sorted(jobs))}


@pytest.mark.parametrize("path", INVALID_FILES, ids=lambda p: p.stem)
def test_invalid_hard_file_exit_2_one_line_names_file_key_index(runs, path):
    p, out, _ = runs[f"invalid/{path.stem}"]
    assert_one_line_error(p, path.name, expect_line(path))
    assert not out.exists() and not any(out.parent.iterdir())
    assert p.stdout == ""


@pytest.mark.parametrize("path", BAD_FILES, ids=lambda p: p.stem)
def test_loader_bad_files_through_the_cli(runs, path):
    p, out, _ = runs[f"bad/{path.stem}"]
    assert_one_line_error(p, path.name, expect_line(path))
    assert not out.exists()


@pytest.mark.parametrize("key", sorted(GENERATED))
def test_generated_bad_files_through_the_cli(runs, key, reader_stages, monkeypatch):
    p, out, path = runs[f"generated/{key}"]
    assert_one_line_error(p, f"{key}.yaml", GENERATED[key])
    assert not out.exists()
    # refused up front, not after expanding: loaded as the command loads it,
    # the file stops in the reader where REFUSED_AT says, and no model is built
    reader_stages.forbidden = NOT_REACHED[REFUSED_AT[key]]
    monkeypatch.setattr(plush_opt.problem, "from_scene", _never_called)
    with pytest.raises(SceneError, match=GENERATED[key]):
        plush_opt.problem.load(path)
    if REFUSED_AT[key] == "compose":
        assert reader_stages.count("node") <= 3, reader_stages.summary()   # up to the first anchor


def _never_called(*args, **kwargs):
    raise AssertionError("a scene was built from a file the reader should refuse")


@pytest.mark.parametrize("name, missing", [("underpinned_one_pin", 1), ("underpinned_one_node", 1),
                                           ("underpinned_island", 2), ("underpinned_hinge", 1)])
def test_underpinned_cli_exit_2_before_solving(runs, name, missing):
    p, out, _ = runs[f"hard/{name}"]
    assert_one_line_error(p, f"{name}.yaml",
                          rf"pins: .*free to .*{missing} more pin\(s\) at distinct points are needed")
    assert not out.exists()


def test_inverted_explicit_triangles_through_the_cli(runs):
    p, out, _ = runs["hard/inverted_explicit"]
    assert p.returncode == 0, p.stderr
    doc = check_result(out)                   # the independent numpy checker
    X = np.asarray(doc["model"]["rest_nodes"])
    tri = np.asarray(doc["model"]["triangles"])
    d1, d2 = X[tri[:, 1]] - X[tri[:, 0]], X[tri[:, 2]] - X[tri[:, 0]]
    assert np.all(d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0] > 0)
    assert doc["converged"] is True and doc["min_hessian_eigenvalue"] > 0


def test_sliver_mesh_cli_exit_3_with_an_honest_result(runs):
    p, out, _ = runs["hard/sliver_explicit"]
    assert p.returncode == 3, p.stderr
    assert re.fullmatch(r"plush-opt: not converged: residual stalled at \S+ of the force scale, "
                        r"above gtol .*round-off floor.*", p.stderr.strip())
    doc = json.loads(out.read_text())
    assert doc["converged"] is False and doc["status"].startswith("residual stalled at ")
    assert doc["residual_norm"] > 0
