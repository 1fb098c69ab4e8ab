"""Links between the project's Markdown pages: headings' anchors as GitHub makes them, and every relative link.

Used by tests/test_docs.py. A link is ``[text](target)`` outside code (fenced blocks and inline code
spans are not text); its target is an ``http(s)``/``mailto`` address (not checked: no internet here),
``#anchor`` on the same page, or a relative path with an optional ``#anchor``.
"""

from __future__ import annotations

import re
import unicodedata
from pathlib import Path

_FENCE = re.compile(r"^\s*(```|~~~)")
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
_CODE_SPAN = re.compile(r"(`+)(.+?)\1")
_LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(([^()\s]+(?:\([^()]*\))?[^()\s]*)(?:\s+\"[^\"]*\")?\)")


def prose_lines(text: str):
    """``(line number, line)`` of the lines outside fenced code blocks."""
    fenced = False
    for number, line in enumerate(text.splitlines(), start=1):
        if _FENCE.match(line):
            fenced = not fenced
            continue
        if not fenced:
            yield number, line


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, punctuation but ``-`` and ``_`` dropped, spaces to ``-``."""
    text = _CODE_SPAN.sub(lambda match: match.group(2), heading).strip().lower()
    kept = "".join(char for char in text if char in " -_" or unicodedata.category(char)[0] in "LN")
    return kept.replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every heading's anchor on a page, repeated headings numbered ``-1``, ``-2`` as GitHub does."""
    seen: dict[str, int] = {}
    found = set()
    for _, line in prose_lines(text):
        match = _HEADING.match(line)
        if not match:
            continue
        base = slug(match.group(2))
        count = seen.get(base, 0)
        seen[base] = count + 1
        found.add(base if count == 0 else f"{base}-{count}")
    return found


def links(text: str):
    """``(line number, target)`` of every link on a page, outside code."""
    for number, line in prose_lines(text):
        for match in _LINK.finditer(_CODE_SPAN.sub("", line)):
            yield number, match.group(1)


def broken_links(page: Path, root: Path) -> list[str]:
    """What on ``page`` does not resolve: ``page:line: target (why)``, relative to ``root`` for the messages."""
    problems = []
    text = page.read_text()
    for number, target in links(text):
        if re.match(r"^(https?|mailto):", target):
            continue
        path_part, _, anchor = target.partition("#")
        where = f"{page.relative_to(root)}:{number}: {target}"
        if path_part:
            resolved = (page.parent / path_part).resolve()
            if not resolved.exists():
                problems.append(f"{where} (no such file)")
                continue
            if root.resolve() not in resolved.parents and resolved != root.resolve():
                problems.append(f"{where} (outside the repository)")
                continue
        else:
            resolved = page
        if anchor:
            if resolved.suffix != ".md" or resolved.is_dir():
                problems.append(f"{where} (an anchor into a file that is not a Markdown page)")
            elif anchor not in anchors(resolved.read_text()):
                problems.append(f"{where} (no heading with that anchor)")
    return problems
