"""docs/model.md's cantilever table ("Element accuracy") is what
`python -m plush_opt.apps.cantilever` prints (issue 35): nodes, deflections
and errors to the digits shown; the solve times are that run's and vary by
host."""

from __future__ import annotations

import pytest

from plush_opt.apps.cantilever import deflection_rows, format_table
from shipped import ROOT

pytestmark = pytest.mark.slow       # fourteen meshes, up to 12,712 nodes

DOC = ROOT / "docs" / "model.md"


def _without_times(table: str) -> list[str]:
    return [line.rsplit("|", 2)[0] for line in table.splitlines() if line.startswith("| P")]


def test_the_cantilever_table_is_what_the_command_prints():
    text = DOC.read_text()
    start = text.index("| element | max_area | nodes | deflection | error | solve [s] |")
    doc = _without_times(text[start:].split("\n\n")[0])
    made = _without_times(format_table(deflection_rows()))
    assert doc == made, "docs/model.md's cantilever table differs: run python -m plush_opt.apps.cantilever"
    assert "Reference tip deflection 0.214863 mm" in text
    assert "reference (Timoshenko, plane strain): 0.214863" in format_table(deflection_rows(areas=(64.0,)))
