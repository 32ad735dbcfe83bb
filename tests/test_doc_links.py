"""The docs point at things that exist (issue 35): every relative link and
picture of README.md and docs/ names a file that is there, every mention of
a `docs/*.md` file (in the docs, the code, the tools, the tests and the
problem files) names one that is there, and a mention that quotes a section
of it (`docs/model.md, "Friction at via points"`) quotes text that the file
has."""

from __future__ import annotations

import re

from shipped import ROOT

DOCS = [ROOT / "README.md"] + sorted((ROOT / "docs").rglob("*.md"))
SOURCES = DOCS + sorted(p for folder in ("plush_opt", "tools", "tests", "problems", "examples")
                        for p in (ROOT / folder).rglob("*") if p.suffix in (".py", ".yaml", ".md")
                        and p.name != "test_doc_links.py")

LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)\)")
MENTION = re.compile(r"\bdocs/[\w/.-]+?\.md\b")
#: a mention followed by a quoted section: docs/x.md, "Title" / docs/x.md ("Title" / `docs/x.md` "Title"
SECTION = re.compile(r"\b(docs/[\w/.-]+?\.md)`?,?\s*\(?\"([A-Z][\w ,'/-]{2,80})\"")


def _flat(text: str) -> str:
    """One line: comment markers and line breaks inside a sentence folded to spaces."""
    return re.sub(r"\s*\n\s*(#\s*)?", " ", text)


def test_relative_links_and_pictures_exist():
    missing = []
    for doc in DOCS:
        for target in LINK.findall(doc.read_text()):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            if not (doc.parent / target.split("#")[0]).exists():
                missing.append(f"{doc.relative_to(ROOT)}: {target}")
    assert not missing, "\n".join(missing)


def test_every_mentioned_doc_exists():
    missing = []
    for path in SOURCES:
        for name in set(MENTION.findall(path.read_text(errors="replace"))):
            if not (ROOT / name).exists():
                missing.append(f"{path.relative_to(ROOT)}: {name}")
    assert not missing, "\n".join(missing)


def test_every_quoted_section_is_in_its_doc():
    texts = {}
    missing = []
    for path in SOURCES:
        for name, title in SECTION.findall(_flat(path.read_text(errors="replace"))):
            target = ROOT / name
            if not target.exists():
                continue            # reported by the test above
            if name not in texts:
                texts[name] = _flat(target.read_text())
            if title.strip() not in texts[name]:
                missing.append(f"{path.relative_to(ROOT)}: {name} has no {title!r}")
    assert not missing, "\n".join(missing)
