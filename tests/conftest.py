"""Shared fixtures: where problem files live, and what the YAML reader did."""

import signal
from pathlib import Path

import pytest
import yaml

import plush_opt.io.yaml_reader as yaml_reader

ROOT = Path(__file__).resolve().parent.parent

# A suite started in the background of a non-interactive shell (`make test &`)
# inherits SIGINT ignored, and so would every command it starts: the Ctrl-C
# tests need what a terminal gives (Python's KeyboardInterrupt here, the
# default action in the commands they start).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)


@pytest.fixture
def problems_dir() -> Path:
    """The shipped problem files."""
    return ROOT / "problems"


@pytest.fixture
def bad_dir() -> Path:
    """Deliberately invalid problem files used by the loader tests."""
    return ROOT / "tests" / "bad"


class ReaderStages(list):
    """The stages the YAML reader reached, in order (one entry per event):

    ``"parse"``      the file's text went to the YAML parser,
    ``"node"``       one YAML node was composed,
    ``"walk"``       the composed tree was walked (the duplicate-key check),
    ``"construct"``  the document was built as Python data.

    A stage in ``forbidden`` fails the test the moment it is reached (an
    ``AssertionError`` from inside the reader), so a file whose refusal
    regressed to after expanding fails at once instead of expanding.
    """

    def __init__(self):
        super().__init__()
        self.forbidden: set[str] = set()

    def reach(self, stage: str) -> None:
        self.append(stage)
        assert stage not in self.forbidden, f"the reader reached {stage!r}: {self.summary()}"

    def summary(self) -> str:
        return ", ".join(f"{s} x{self.count(s)}" for s in dict.fromkeys(self)) or "nothing"


@pytest.fixture
def reader_stages(monkeypatch) -> ReaderStages:
    """Record what :mod:`plush_opt.io.yaml_reader` does while the test runs
    (the reader works as before; see :class:`ReaderStages`)."""
    stages = ReaderStages()

    def wrap(owner, name, stage):
        original = getattr(owner, name)

        def recorded(*args, **kwargs):
            stages.reach(stage)
            return original(*args, **kwargs)
        monkeypatch.setattr(owner, name, recorded)

    wrap(yaml_reader, "_parse_yaml", "parse")
    wrap(yaml_reader._Guard, "compose_node", "node")
    wrap(yaml_reader, "_duplicate_key_path", "walk")
    wrap(yaml.constructor.BaseConstructor, "construct_document", "construct")
    return stages
