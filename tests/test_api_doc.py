"""docs/api.md's runnable examples: each block marked ``<!-- api-run: NAME -->``
is a Python block and the text it prints; the block runs (in a scratch
folder holding the shipped problems) and must print that text, every
number equal to the digits printed in the doc and ``...`` standing for
what changes from run to run (times, round-off residuals)."""

from __future__ import annotations

import contextlib
import io
import re

import pytest

from shipped import ROOT

DOC = ROOT / "docs" / "api.md"
BLOCK = re.compile(r"<!-- api-run: (\S+) -->\n```python\n(.*?)```\n.*?```text\n(.*?)```\n<!-- /api-run: \1 -->",
                   re.S)
NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"


def _blocks():
    found = BLOCK.findall(DOC.read_text())
    assert found, f"{DOC}: no api-run block"
    return found


def _pattern(line: str) -> tuple[re.Pattern, list[str]]:
    """A doc line as a regex: its numbers captured, ``...`` anything."""
    parts, numbers = [], []
    for piece in re.split(rf"(\.\.\.|{NUMBER})", line):
        if piece == "...":
            parts.append(".*?")
        elif piece and re.fullmatch(NUMBER, piece):
            parts.append(f"({NUMBER})")
            numbers.append(piece)
        else:
            parts.append(re.escape(piece))
    return re.compile("".join(parts)), numbers


def _same_number(doc: str, got: str) -> bool:
    """``got`` equals ``doc`` to the digits the doc prints (half a unit of its last digit)."""
    mantissa, _, exponent = doc.lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    unit = 10.0 ** (int(exponent or 0) - decimals)
    return abs(float(got) - float(doc)) <= 0.5 * unit * (1 + 1e-9)


def check_printed(expected: str, printed: str) -> None:
    want, got = expected.rstrip("\n").splitlines(), printed.rstrip("\n").splitlines()
    assert len(want) == len(got), f"{len(got)} lines printed, the doc shows {len(want)}:\n{printed}"
    for w, g in zip(want, got):
        pattern, numbers = _pattern(w)
        m = pattern.fullmatch(g)
        assert m, f"printed\n  {g}\nthe doc shows\n  {w}"
        for doc_number, value in zip(numbers, m.groups()):
            assert _same_number(doc_number, value), f"{value} printed, the doc shows {doc_number}:\n  {g}"


def test_the_checker_compares_digits_and_skips_ellipses():
    check_printed("O=0.0004305, t=...s, n=8\n", "O=0.00043054, t=0.21s, n=8\n")
    for printed in ("O=0.0004312, t=0.2s, n=8", "O=0.0004305, t=0.2s, n=9", "O=0.0004305, t=0.2s"):
        with pytest.raises(AssertionError):
            check_printed("O=0.0004305, t=...s, n=8", printed)


@pytest.mark.slow        # a control run
@pytest.mark.parametrize("name, code, expected", _blocks(), ids=[b[0] for b in _blocks()])
def test_the_documented_example_prints_what_the_doc_shows(name, code, expected, tmp_path, monkeypatch):
    import matplotlib
    matplotlib.use("Agg")
    (tmp_path / "problems").symlink_to(ROOT / "problems")
    monkeypatch.chdir(tmp_path)
    out = io.StringIO()
    with contextlib.redirect_stdout(out):
        exec(compile(code, f"{DOC}:{name}", "exec"), {"__name__": "__main__"})  # noqa: S102 - the doc's own code
    check_printed(expected, out.getvalue())
