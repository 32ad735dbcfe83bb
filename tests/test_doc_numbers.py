"""The numbers the docs quote are the code's (issue 35): every cheap block
of tools/doc_numbers.py (docs/api.md's tour, the friction sweep's counts,
the hysteresis loops) is what the code gives now; the expensive ones carry
their command and date."""

import re
import subprocess
import sys

import pytest

from shipped import ROOT

sys.path.insert(0, str(ROOT / "tools"))
import doc_numbers  # noqa: E402


@pytest.mark.slow        # a control run and two friction sweeps
def test_the_docs_cheap_numbers_are_current():
    p = subprocess.run([sys.executable, str(ROOT / "tools" / "doc_numbers.py"), "--check"], capture_output=True,
                       text=True, cwd=ROOT, timeout=600)
    assert p.returncode == 0, p.stdout + p.stderr


def test_every_block_is_in_the_docs_and_every_expensive_one_is_dated():
    docs = "\n".join(path.read_text() for path in (ROOT / "docs").glob("*.md"))
    for name, (_, cheap) in doc_numbers.BLOCKS.items():
        m = re.search(rf"<!-- doc-numbers: {name} -->\n(.*?)\n<!-- /doc-numbers: {name} -->", docs, re.S)
        assert m and m.group(1).strip(), name
        if not cheap:
            assert re.search(r"tools/doc_numbers\.py --only \S+` on \d{4}-\d\d-\d\d", m.group(1)), name


def test_a_roundoff_block_is_current_within_its_tolerances_only():
    """The numbers of a block that the factoriser's round-off moves (the
    friction sweep's loop area, O at an iteration limit): --check takes its
    decimals within 1e-3, its words and whole numbers exactly."""
    old = "at 1,033 nodes: every step converged and checked; loop area 3.8778 mm^2; O = 9.976."
    same = doc_numbers._same_up_to_roundoff
    assert same(old, "at 1,033 nodes: every step converged and checked; loop area 3.8785 mm^2; O = 9.977.")
    assert not same(old, "at 1,018 nodes: every step converged and checked; loop area 4.7744 mm^2; O = 9.976.")
    assert not same(old, "at 1,033 nodes: every step converged and checked; loop area 3.8878 mm^2; O = 9.976.")
    assert not same(old, "at 1,034 nodes: every step converged and checked; loop area 3.8778 mm^2; O = 9.976.")
    assert not same(old, "at 1,033 nodes: 2 of 20 steps converged; loop area 3.8778 mm^2; O = 9.976.")
