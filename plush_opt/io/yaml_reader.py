"""The one YAML reader of every file kind (problem files, board
calibrations, run scripts).

The files are small and written by hand, so the reader refuses what a
hand-written file never needs and a hostile one might use: files over a
size cap and anything that is not a regular file (a FIFO or a device
would block), bytes that are not UTF-8 text, anchors and aliases (so no
"billion laughs"), merge keys, duplicate keys, and tags that build Python
objects. Numbers written with an exponent (``1e-9``, ``2.0e11``) are
numbers. Every failure is one :class:`~plush_opt.base.errors.SceneError` line
that starts with the file name.
"""

from __future__ import annotations

import os
import re
import stat

import yaml

from ..base.errors import SceneError

MAX_FILE_BYTES = 1 << 20          # 1 MiB: the files are small; refuse before parsing


class _YamlRefused(yaml.YAMLError):
    """A YAML feature the problem format does not allow (aliases, merges)."""

    def __init__(self, message, mark=None):
        super().__init__(message)
        self.message = message
        self.mark = mark


# A float with an exponent, as YAML 1.2 and JSON write it.
_FLOAT_12 = re.compile(r"^[-+]?(?:[0-9][0-9_]*(?:\.[0-9_]*)?|\.[0-9_]+)[eE][-+]?[0-9]+$")


class _Resolver(yaml.resolver.Resolver):
    """YAML 1.1 (PyYAML) reads 1e-9 and 2.0e11 as strings; users mean numbers."""


_Resolver.add_implicit_resolver("tag:yaml.org,2002:float", _FLOAT_12, list("-+0123456789."))


class _Guard:
    """Refuses anchors and aliases (so no "billion laughs"), merge keys and
    duplicate keys while composing and constructing."""

    def compose_node(self, parent, index):
        event = self.peek_event()
        if isinstance(event, yaml.AliasEvent):
            raise _YamlRefused(f"alias *{event.anchor} (anchors and aliases are not allowed)",
                               event.start_mark)
        if getattr(event, "anchor", None) is not None:
            raise _YamlRefused(f"anchor &{event.anchor} (anchors and aliases are not allowed)",
                               event.start_mark)
        return super().compose_node(parent, index)

    def construct_mapping(self, node, deep=False):
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == "tag:yaml.org,2002:merge":
                raise _YamlRefused("merge key '<<' is not allowed", key_node.start_mark)
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
                seen.add(key)
            except TypeError:
                raise _YamlRefused("a mapping key must be a plain value", key_node.start_mark)
            if duplicate:
                raise _YamlRefused(f"duplicate key {key!r}", key_node.start_mark)
        return super().construct_mapping(node, deep=deep)

    def construct_object(self, node, deep=False):
        # an explicit tag with a value it cannot hold (!!float abc, !!bool
        # maybe, ...) makes PyYAML's constructors raise plain exceptions
        try:
            return super().construct_object(node, deep=deep)
        except (ValueError, TypeError, KeyError, AttributeError, OverflowError):
            raise _YamlRefused(f"bad {node.tag} value {node.value!r}"
                               if isinstance(node, yaml.ScalarNode) else f"bad {node.tag} value",
                               node.start_mark) from None


class _Loader(_Guard, yaml.reader.Reader, yaml.scanner.Scanner, yaml.parser.Parser,
              yaml.composer.Composer, yaml.constructor.SafeConstructor, _Resolver):
    """Pure-Python safe loader with the guards."""

    def __init__(self, stream):
        yaml.reader.Reader.__init__(self, stream)
        yaml.scanner.Scanner.__init__(self)
        yaml.parser.Parser.__init__(self)
        yaml.composer.Composer.__init__(self)
        yaml.constructor.SafeConstructor.__init__(self)
        _Resolver.__init__(self)


try:
    from yaml._yaml import CParser as _CParser
except ImportError:                      # PyYAML built without libyaml
    _CParser = None
else:
    class _CLoader(_Guard, yaml.composer.Composer, _CParser, yaml.constructor.SafeConstructor,
                   _Resolver):
        """libyaml scans and parses (fast); composing stays in Python so the
        guards see every event."""

        def __init__(self, stream):
            _CParser.__init__(self, stream)
            yaml.composer.Composer.__init__(self)
            yaml.constructor.SafeConstructor.__init__(self)
            _Resolver.__init__(self)


def _duplicate_key_path(node) -> str | None:
    """Key path of the first duplicate key in a composed YAML tree, if any."""
    stack = [(node, "")]
    while stack:
        node, path = stack.pop()
        if isinstance(node, yaml.MappingNode):
            seen, children = {}, []
            for key_node, value_node in node.value:
                if isinstance(key_node, yaml.ScalarNode):
                    key = (key_node.tag, key_node.value)
                    sub = f"{path}.{key_node.value}" if path else str(key_node.value)
                    if key in seen:
                        return (f"line {key_node.start_mark.line + 1}: {sub}: duplicate key "
                                f"(first on line {seen[key] + 1})")
                    seen[key] = key_node.start_mark.line
                    children.append((value_node, sub))
            stack.extend(reversed(children))       # visit in document order
        elif isinstance(node, yaml.SequenceNode):
            stack.extend(reversed([(v, f"{path}[{i}]") for i, v in enumerate(node.value)]))
    return None


def _parse_yaml(text: str, source: str):
    loader = (_Loader if _CParser is None else _CLoader)(text)
    try:
        node = loader.get_single_node()
        if node is None:
            raise SceneError(f"{source}: the file is empty")
        dup = _duplicate_key_path(node)
        if dup is not None:
            raise SceneError(f"{source}: {dup}")
        return loader.construct_document(node)
    except _YamlRefused as exc:
        line = f"line {exc.mark.line + 1}: " if exc.mark is not None else ""
        raise SceneError(f"{source}: {line}{exc.message}") from None
    except yaml.MarkedYAMLError as exc:
        mark = exc.problem_mark or exc.context_mark
        line = f"line {mark.line + 1}: " if mark is not None else ""
        what = " ".join(p for p in (exc.context, exc.problem) if p)
        raise SceneError(f"{source}: {line}invalid YAML: {what}") from None
    except yaml.reader.ReaderError as exc:
        raise SceneError(f"{source}: character {exc.position}: character #x{exc.character:04x} "
                         "is not allowed in YAML") from None
    except yaml.YAMLError as exc:
        raise SceneError(f"{source}: YAML error: {' '.join(str(exc).split())}") from None
    except RecursionError:
        raise SceneError(f"{source}: the YAML is nested too deeply") from None
    except SceneError:
        raise
    except (ValueError, TypeError, KeyError, AttributeError, OverflowError) as exc:
        raise SceneError(f"{source}: YAML value not understood: {exc}") from None
    finally:
        loader.dispose()


def read_yaml(path, *, what: str = "problem file", source: str | None = None,
              max_bytes: int = MAX_FILE_BYTES):
    """Read one YAML document from a file, guarded.

    Parameters
    ----------
    path : str or os.PathLike
        The file.
    what : str
        What the file should be, for messages ("is a directory, not a problem file").
    source : str, optional
        Name at the start of every message; default the file's base name.
    max_bytes : int
        Larger files are refused before they are parsed.

    Returns
    -------
    The document as plain Python data (dict, list, str, int, float, bool, None).

    Raises
    ------
    SceneError
        One line, starting with ``source``, for a missing, unreadable,
        non-regular, oversized, non-text, empty or malformed file.
    """
    if source is None:
        source = os.path.basename(os.fspath(path)) or os.fspath(path)
    raw = _read_bytes(path, what, source, max_bytes)
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise SceneError(f"{source}: not UTF-8 text (byte {exc.start})") from None
    nul = raw.find(b"\0")               # valid UTF-8 has NUL bytes only as NUL characters
    if nul >= 0:
        raise SceneError(f"{source}: not a text file (NUL byte at byte {nul}); not a {what}")
    return _parse_yaml(text, source)


def _read_bytes(path, what: str, source: str, max_bytes: int) -> bytes:
    """At most ``max_bytes`` bytes of a regular file; FIFOs and devices are
    refused before they are opened (opening one may block)."""
    try:
        if not stat.S_ISREG(os.stat(path).st_mode):
            raise IsADirectoryError if os.path.isdir(path) else _NotRegular
        # O_NONBLOCK: should the file be swapped for a FIFO after the check,
        # opening it still returns at once, and fstat below refuses it
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
        with os.fdopen(fd, "rb") as f:
            if not stat.S_ISREG(os.fstat(f.fileno()).st_mode):
                raise _NotRegular
            raw = f.read(max_bytes + 1)
    except FileNotFoundError:
        raise SceneError(f"{source}: no such file ({os.fspath(path)})") from None
    except IsADirectoryError:
        raise SceneError(f"{source}: is a directory, not a {what}") from None
    except _NotRegular:
        raise SceneError(f"{source}: not a regular file (a pipe, socket or device), "
                         f"not a {what}") from None
    except OSError as exc:
        raise SceneError(f"{source}: cannot read: {exc.strerror or exc}") from None
    except ValueError as exc:                     # e.g. a NUL character in the path
        raise SceneError(f"{source}: cannot read: {exc}") from None
    if len(raw) > max_bytes:
        raise SceneError(f"{source}: file larger than {max_bytes} bytes "
                         f"({max_bytes / (1 << 20):g} MiB); not a {what}")
    return raw


class _NotRegular(Exception):
    """The path is a FIFO, socket or device."""
