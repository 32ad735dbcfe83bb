"""docs/comparison.md's main table quotes the current code (issue 35): on
each file's own mesh every method ends at the objective the table prints
(to its six digits) on a mesh of the nodes it prints, and the bilevel
method refuses the rows it says it refuses. The errors and times of the
table come from a compare run and are not re-measured here."""

from __future__ import annotations

import pytest

import plush_opt
from plush_opt.base.errors import SceneError
from shipped import ROOT

pytestmark = pytest.mark.slow      # 30 control runs, a few seconds each on the tentacles

DOC = ROOT / "docs" / "comparison.md"
HEADER = "| problem | nodes | method | final O |"


def _rows():
    """(problem, nodes, method, objective text) of every row of the main table."""
    text = DOC.read_text()
    lines = text[text.index(HEADER):].split("\n\n")[0].splitlines()[2:]
    rows, problem, nodes = [], None, None
    for line in lines:
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        problem, nodes = cells[0] or problem, cells[1] or nodes
        rows.append((problem, int(nodes), cells[2], cells[3]))
    return rows


def _path(problem: str):
    for path in (ROOT / "problems" / f"{problem}.yaml", ROOT / "problems" / "compare" / f"{problem}.yaml"):
        if path.exists():
            return path
    raise AssertionError(f"docs/comparison.md names {problem}, which is no shipped problem")


def test_the_table_covers_every_method_on_every_compared_file():
    rows = _rows()
    assert len(rows) >= 27 and {m for _, _, m, _ in rows} == {"reparam", "clip", "bilevel"}


@pytest.mark.parametrize("problem", sorted({r[0] for r in _rows()}))
def test_the_objectives_of_the_main_table_are_the_codes(problem):
    p = plush_opt.load(_path(problem))
    for _, nodes, method, shown in (r for r in _rows() if r[0] == problem):
        assert p.mesh.n_nodes == nodes, f"{problem}: {p.mesh.n_nodes} nodes, the doc says {nodes}"
        if shown == "refused":
            with pytest.raises(SceneError):
                p.control(method=method)
            continue
        result = p.control(method=method)
        assert result.objective == pytest.approx(float(shown), rel=1e-5), (
            f"{problem} {method}: O = {result.objective:.6g}, docs/comparison.md says {shown}")
