"""`plush-opt bench` runs and writes its report (the figures themselves live
in docs/benchmarks.md, never in tests)."""

import json
import subprocess
import sys

import pytest

from shipped import ROOT

pytestmark = pytest.mark.slow  # each runs the command line on several meshes


def test_bench_writes_markdown_and_json(tmp_path):
    p = subprocess.run([sys.executable, "-m", "plush_opt", "bench",
                        str(ROOT / "problems" / "hexapod_leg.yaml"), "--sizes", "150",
                        "--repeats", "1", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    report = json.loads((tmp_path / "bench.json").read_text())
    row = report["rows"][0]
    assert row["problem"] == "hexapod_leg" and 100 <= row["nodes"] <= 200
    assert row["forward_certified"] and row["resolve_certified"] and row["inverse_reparam_certified"]
    # each control iterate is a certified pose: at least its own factorisation
    assert row["control_factorisations"] >= 1 and row["control_factor_ratio"] >= 1
    assert report["machine"]["cores"] >= 1
    md = (tmp_path / "bench.md").read_text()
    assert "| hexapod_leg |" in md and "Inverse control" in md
    assert "bench:" in p.stderr            # progress shown


def test_bench_runs_both_elements_and_skips_large_inverse_solves(tmp_path):
    """``--elements P1,P2`` benches each size with both elements; the
    factorisation table compares CHOLMOD's two modes where installed;
    ``--inverse-max-nodes`` skips the inverse solves and says so."""
    p = subprocess.run([sys.executable, "-m", "plush_opt", "bench",
                        str(ROOT / "problems" / "hexapod_leg.yaml"), "--sizes", "150",
                        "--elements", "P1,P2", "--inverse-max-nodes", "10",
                        "--repeats", "1", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    rows = json.loads((tmp_path / "bench.json").read_text())["rows"]
    assert [r["element"] for r in rows] == ["P1", "P2"]
    assert all(r["forward_certified"] and "inverse_reparam_s" not in r for r in rows)
    assert all(r["inverse_skipped"] == "above --inverse-max-nodes 10" for r in rows)
    md = (tmp_path / "bench.md").read_text()
    assert "| hexapod_leg | P2 |" in md and "inverse solves skipped" in md
    if rows[0]["factor_mode"].startswith("cholmod"):
        assert "simplicial against supernodal" in md


@pytest.mark.parametrize("args, key", [(["--sizes", "a,b"], "--sizes"), (["--sizes", "accuracy=-1"], "--sizes"),
                                       (["--elements", "P3"], "--elements"),
                                       (["--inverse-max-nodes", "-1"], "--inverse-max-nodes")])
def test_bench_rejects_bad_options(tmp_path, args, key):
    p = subprocess.run([sys.executable, "-m", "plush_opt", "bench", *args,
                        "--out", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and key in p.stderr and "Traceback" not in p.stderr


def test_bench_rejects_bad_sizes(tmp_path):
    p = subprocess.run([sys.executable, "-m", "plush_opt", "bench", "--sizes", "a,b",
                        "--out", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "--sizes" in p.stderr and "Traceback" not in p.stderr


def test_bench_times_the_parts_inside_the_same_solve(tmp_path):
    """The forward ratios come from one solve timed whole and by parts: the
    parts never exceed the whole, and a certified solve factors at least once."""
    p = subprocess.run([sys.executable, "-m", "plush_opt", "bench",
                        str(ROOT / "problems" / "hexapod_leg.yaml"), "--sizes", "150",
                        "--inverse-max-nodes", "10", "--repeats", "1", "--out", str(tmp_path)],
                       capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    row = json.loads((tmp_path / "bench.json").read_text())["rows"][0]
    parts = row["forward_parts"]
    assert parts["factorisations"] >= 1 and parts["evaluations"] >= parts["factorisations"]
    assert parts["evaluate_s"] + parts["factorise_s"] <= parts["total_s"]
    assert row["forward_ratio"] >= 1.0 and row["forward_factor_ratio"] >= 1.0


def test_bench_peers_compares_the_same_problem(tmp_path):
    """``--peers``: each installed peer solves the same problem to the same
    pose (displacements agree to 1e-6 of their size), in one run."""
    from plush_opt.apps.bench_peers import available_peers
    peers = available_peers()
    if not peers:
        pytest.skip("neither FElupe nor scikit-fem installed (the [bench] extra)")
    p = subprocess.run([sys.executable, "-m", "plush_opt", "bench", "--peers", "--sizes", "200",
                        "--repeats", "1", "--out", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr
    rows = json.loads((tmp_path / "peers.json").read_text())["rows"]
    assert [r["solver"] for r in rows] == ["plush_opt"] + peers
    assert all(r["converged"] and r["max_difference"] < 1e-6 for r in rows), rows
    assert all(r["nodes"] == rows[0]["nodes"] for r in rows)
    assert "ours / this" in (tmp_path / "peers.md").read_text()


def test_bench_peers_rejects_what_it_cannot_compare(tmp_path):
    p = subprocess.run([sys.executable, "-m", "plush_opt", "bench", "--peers", "--sizes", "file",
                        "--out", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "--sizes" in p.stderr and "Traceback" not in p.stderr


def test_bench_times_a_body_without_pins_whose_hessian_is_gauged():
    """hexapod_stand (no pins, on a frictionless floor) at about 3,000
    nodes: its Hessian is gauged on an assembly, though its model is a
    low-rank one (the bench read the low-rank term of it and failed)."""
    from plush_opt.apps.bench import bench_one
    row = bench_one(ROOT / "problems" / "hexapod_stand.yaml", 3000, 1, lambda line: None, inverse_max_nodes=0)
    assert row["forward_certified"] and row["hessian_form"] in ("low_rank", "assembled")
    assert (row["low_rank_k"] is None) == (row["hessian_form"] == "assembled")
