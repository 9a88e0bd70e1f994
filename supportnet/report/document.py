"""A small document model (sections, paragraphs, lists, tables, figures with captions) and its
Markdown rendering: one source of truth for a report written both as ``report.md`` and as a
self-contained HTML page (:mod:`supportnet.report.html_page`).

Text in paragraphs, list items, table cells and captions may use three inline marks, the same in
both renderings: ```code```, ``**bold**`` and ``[label](#anchor-or-url)``. Figures name a PNG by
its path relative to the report's folder.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

__all__ = [
    "Block",
    "BulletList",
    "Document",
    "Figure",
    "Paragraph",
    "Section",
    "Table",
    "plain_text",
    "slug",
    "to_markdown",
]


@dataclass
class Paragraph:
    text: str


@dataclass
class BulletList:
    items: list[str]


@dataclass
class Table:
    header: list[str]
    rows: list[list[str]]
    caption: str = ""
    align: str = ""
    """One letter per column, ``l`` or ``r``; empty: the first column left, the others right."""

    def alignment(self) -> str:
        return self.align or "l" + "r" * (len(self.header) - 1)


@dataclass
class Figure:
    path: str
    """The PNG, relative to the report's folder (forward slashes)."""
    caption: str
    alt: str = ""


Block = Paragraph | BulletList | Table | Figure


@dataclass
class Section:
    title: str
    blocks: list[Block] = field(default_factory=list)
    sections: list[Section] = field(default_factory=list)

    def add(self, *blocks: Block) -> Section:
        self.blocks.extend(blocks)
        return self

    def section(self, title: str) -> Section:
        child = Section(title)
        self.sections.append(child)
        return child


@dataclass
class Document(Section):
    """The whole page: a top-level section whose title is the page's."""

    def walk(self) -> list[tuple[int, Section]]:
        """Every section with its depth (1 = a top-level section), in reading order."""
        out: list[tuple[int, Section]] = []

        def visit(sections: list[Section], depth: int) -> None:
            for s in sections:
                out.append((depth, s))
                visit(s.sections, depth + 1)

        visit(self.sections, 1)
        return out

    def anchors(self) -> list[tuple[int, Section, str]]:
        """:meth:`walk` with each section's anchor, made unique as GitHub does (``-1``, ``-2``)."""
        seen: dict[str, int] = {}
        out = []
        for depth, s in self.walk():
            base = slug(s.title)
            count = seen.get(base, 0)
            seen[base] = count + 1
            out.append((depth, s, base if count == 0 else f"{base}-{count}"))
        return out

    def figures(self) -> list[Figure]:
        """Every figure in reading order (their numbers are their positions here, from 1)."""
        found = [b for b in self.blocks if isinstance(b, Figure)]
        for _, s in self.walk():
            found += [b for b in s.blocks if isinstance(b, Figure)]
        return found


_LINK = re.compile(r"\[([^\]]+)\]\(([^)\s]+)\)")
_MARKS = re.compile(r"`([^`]+)`|\*\*([^*]+)\*\*")


def plain_text(text: str) -> str:
    """``text`` without its inline marks (for headings compared across renderings, alt texts)."""
    text = _LINK.sub(r"\1", text)
    return _MARKS.sub(lambda m: m.group(1) or m.group(2), text)


def slug(text: str) -> str:
    """A heading's anchor: lower case, words joined by ``-`` (GitHub's rule for plain ASCII)."""
    words = re.sub(r"[^\w\s-]", "", plain_text(text).lower(), flags=re.UNICODE)
    return re.sub(r"\s+", "-", words.strip())


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md_block(block: Block, number: dict[int, int]) -> list[str]:
    if isinstance(block, Paragraph):
        return [block.text, ""]
    if isinstance(block, BulletList):
        return [*(f"- {item}" for item in block.items), ""]
    if isinstance(block, Table):
        rule = ["---:" if a == "r" else "---" for a in block.alignment()]
        lines = [
            "| " + " | ".join(_md_cell(h) for h in block.header) + " |",
            "|" + "|".join(rule) + "|",
            *("| " + " | ".join(_md_cell(c) for c in row) + " |" for row in block.rows),
            "",
        ]
        return ([f"*{block.caption}*", ""] if block.caption else []) + lines
    if isinstance(block, Figure):
        n = number[id(block)]
        alt = block.alt or plain_text(block.caption).split(".")[0]
        return [
            f"[![{_md_cell(alt)}]({block.path})]({block.path})",
            "",
            f"**Figure {n}.** {block.caption} ([{Path(block.path).name}]({block.path}))",
            "",
        ]
    raise TypeError(f"not a block: {block!r}")


def to_markdown(doc: Document) -> str:
    """``doc`` as GitHub-flavoured Markdown; each figure is its image, linked to the PNG file."""
    number = {id(f): i for i, f in enumerate(doc.figures(), start=1)}
    lines = [f"# {doc.title}", ""]
    for block in doc.blocks:
        lines += _md_block(block, number)
    for depth, section in doc.walk():
        lines += [f"{'#' * (depth + 1)} {section.title}", ""]
        for block in section.blocks:
            lines += _md_block(block, number)
    return "\n".join(lines).rstrip() + "\n"
