"""Every `plush-opt` command the README and docs/ give a user to type
parses as written (issue 35: a quoted sweep without its required --out
failed with exit 2). Commands are the lines of shell blocks and the
backticked ones that name a file; synopses (``[...]``, ``A|B``, ``...``,
placeholders in capitals such as FILE or TOL) and bare mentions of a
command or an option are not commands."""

import re
import shlex

import pytest

from plush_opt.apps.cli import build_parser
from shipped import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_INLINE = re.compile(r"`((?:[A-Z_]+=\S+ )*(?:\.venv/bin/)?plush-opt [^`]+)`")
_PLACEHOLDER = re.compile(r"[A-Z]{2,}(\.[a-z]+)?")


def _shell_lines(text: str):
    """(line number, line) of the shell blocks' commands in ``text``, with
    backslash continuations joined and comments cut."""
    fence, held = None, None
    for number, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fence = line.strip()[3:] if fence is None else None
            continue
        if fence not in ("sh", "bash", "console", "shell", ""):
            continue
        line = line.split(" #")[0].strip().removeprefix("$ ")
        start, joined = (held or (number, ""))
        joined += line
        if joined.endswith("\\"):
            held = (start, joined[:-1] + " ")
            continue
        held = None
        yield start, joined


def _arguments(command: str) -> list[str] | None:
    """The arguments after `plush-opt` (environment settings and the
    virtualenv's path dropped), or None for a synopsis."""
    if any(mark in command for mark in ("[", "|", "...", "<")):
        return None
    words = shlex.split(command)
    while words and re.fullmatch(r"[A-Z_]+=\S+", words[0]):
        words.pop(0)
    if not words or not words[0].endswith("plush-opt"):
        return None
    if any(_PLACEHOLDER.fullmatch(w) for w in words[1:]):
        return None
    return words[1:]


def _commands():
    for page in PAGES:
        text = page.read_text()
        for m in _INLINE.finditer(text):
            if re.search(r"\.(yaml|json|csv)\b|/", m.group(1).split("plush-opt", 1)[1]):
                yield page.name, text[:m.start()].count("\n") + 1, " ".join(m.group(1).split())
        for number, line in _shell_lines(text):
            if re.match(r"(?:[A-Z_]+=\S+ )*(?:\.venv/bin/)?plush-opt ", line):
                yield page.name, number, " ".join(line.split())


COMMANDS = sorted(set(_commands()))


def test_the_docs_give_commands():
    assert len(COMMANDS) > 30


@pytest.mark.parametrize("page, line, command", COMMANDS, ids=[f"{p}:{n}" for p, n, _ in COMMANDS])
def test_a_documented_command_parses(page, line, command, capsys):
    args = _arguments(command)
    if args is None:
        pytest.skip("a synopsis")
    try:
        build_parser().parse_args(args)
    except SystemExit as exc:
        pytest.fail(f"{page}:{line}: `{command}` exits {exc.code}: {capsys.readouterr().err.strip()}")
