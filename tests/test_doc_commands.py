"""Every `plush-opt` command and every `python tools/...` command the
README and docs/ give a user to type parses as written (issue 35: a quoted
sweep without its required --out failed with exit 2). Commands are the
lines of shell blocks and the backticked ones that name a file (a tool's:
any); synopses (``[...]``, ``A|B``, ``...``, placeholders in capitals such
as FILE or TOL) and bare mentions of a command or an option are left out.
A tool is run up to its argument parser and stopped there."""

import argparse
import re
import runpy
import shlex
import sys

import pytest

from plush_opt.apps.cli import build_parser
from shipped import ROOT

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
_INLINE = re.compile(r"`((?:[A-Z_]+=\S+ )*(?:\.venv/bin/)?plush-opt [^`]+)`")
_TOOL = re.compile(r"(?:[A-Z_]+=\S+ )*(?:\.venv/bin/)?python (tools/\w+\.py)(?= |$)(.*)")
_PLACEHOLDER = re.compile(r"[A-Z]+|[A-Z]{2,}\.[a-z]+")


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


def _prose(text: str) -> str:
    """``text`` with its fenced blocks blanked (lines kept, so that line
    numbers hold), for the backticks of its prose to pair up."""
    out, fenced = [], False
    for line in text.splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
            out.append("")
        else:
            out.append("" if fenced else line)
    return "\n".join(out)


def _arguments(command: str, program: str = "plush-opt") -> list[str] | None:
    """The arguments after ``program`` (environment settings and the
    virtualenv's path dropped), or None for a synopsis."""
    if any(mark in command for mark in ("[", "|", "...", "<")):
        return None
    words = shlex.split(command)
    while words and (re.fullmatch(r"[A-Z_]+=\S+", words[0]) or words[0].endswith("/python")
                     or words[0] == "python"):
        words.pop(0)
    if not words or not words[0].endswith(program):
        return None
    if any(_PLACEHOLDER.fullmatch(w) for w in words[1:]):
        return None
    return words[1:]


def _commands():
    for page in PAGES:
        text = page.read_text()
        prose = _prose(text)
        for m in _INLINE.finditer(prose):
            if re.search(r"\.(yaml|json|csv)\b|/", m.group(1).split("plush-opt", 1)[1]):
                yield page.name, prose[:m.start()].count("\n") + 1, " ".join(m.group(1).split())
        for number, line in _shell_lines(text):
            if re.match(r"(?:[A-Z_]+=\S+ )*(?:\.venv/bin/)?plush-opt ", line):
                yield page.name, number, " ".join(line.split())


def _tool_commands():
    for page in PAGES:
        text = page.read_text()
        prose = _prose(text)
        lines = [(prose[:m.start()].count("\n") + 1, m.group(1)) for m in re.finditer(r"`([^`]+)`", prose)]
        for number, line in [*lines, *_shell_lines(text)]:
            m = _TOOL.fullmatch(" ".join(line.split()))
            if m:
                yield page.name, number, f"python {m.group(1)}{m.group(2)}"


COMMANDS = sorted(c for c in set(_commands()) if _arguments(c[2]) is not None)
TOOL_COMMANDS = sorted(c for c in set(_tool_commands()) if _arguments(c[2], c[2].split()[1]) is not None)


def test_the_docs_give_commands():
    assert len(COMMANDS) > 30


@pytest.mark.parametrize("page, line, command", COMMANDS, ids=[f"{p}:{n}" for p, n, _ in COMMANDS])
def test_a_documented_command_parses(page, line, command, capsys):
    args = _arguments(command)
    try:
        build_parser().parse_args(args)
    except SystemExit as exc:
        pytest.fail(f"{page}:{line}: `{command}` exits {exc.code}: {capsys.readouterr().err.strip()}")


class _Parsed(Exception):
    """Raised by the argument parser once a tool's arguments parsed."""


def test_the_docs_give_tool_commands():
    assert len(TOOL_COMMANDS) > 20


@pytest.mark.parametrize("page, line, command", TOOL_COMMANDS, ids=[f"{p}:{n}" for p, n, _ in TOOL_COMMANDS])
def test_a_documented_tool_command_parses(page, line, command, monkeypatch, capsys):
    tool = command.split()[1]
    args = _arguments(command, tool)
    assert (ROOT / tool).is_file(), f"{page}:{line}: no {tool}"
    if "argparse" not in (ROOT / tool).read_text():
        assert not args, f"{page}:{line}: {tool} takes no arguments"
        return
    known = argparse.ArgumentParser.parse_known_args

    def parse_args(self, args=None, namespace=None):
        extras = known(self, args, namespace)[1]
        if extras:
            self.error(f"unrecognized arguments: {' '.join(extras)}")
        raise _Parsed

    def parse_known_args(self, *a, **k):
        known(self, *a, **k)
        raise _Parsed

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_args)
    monkeypatch.setattr(argparse.ArgumentParser, "parse_known_args", parse_known_args)
    monkeypatch.setattr(sys, "argv", [tool, *args])
    monkeypatch.syspath_prepend(str(ROOT / "tools"))
    try:
        runpy.run_path(str(ROOT / tool), run_name="__main__")
    except _Parsed:
        return
    except SystemExit as exc:
        pytest.fail(f"{page}:{line}: `{command}` exits {exc.code}: {capsys.readouterr().err.strip()}")
    pytest.fail(f"{page}:{line}: {tool} ran to its end without parsing its arguments")
