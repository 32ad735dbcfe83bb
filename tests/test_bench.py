"""`plush-opt bench` runs and writes its report (the figures themselves live
in docs/benchmarks.md, never in tests)."""

import json
import subprocess
import sys

from shipped import ROOT


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
    assert report["machine"]["cores"] >= 1
    md = (tmp_path / "bench.md").read_text()
    assert "| hexapod_leg |" in md and "Inverse control" in md
    assert "bench:" in p.stderr            # progress shown


def test_bench_rejects_bad_sizes(tmp_path):
    p = subprocess.run([sys.executable, "-m", "plush_opt", "bench", "--sizes", "a,b",
                        "--out", str(tmp_path)], capture_output=True, text=True, timeout=60)
    assert p.returncode == 2 and "--sizes" in p.stderr and "Traceback" not in p.stderr
