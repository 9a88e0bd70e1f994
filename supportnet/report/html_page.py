"""A :class:`~supportnet.report.document.Document` as one self-contained HTML page: every figure
embedded as a base64 ``data:`` URI, the style and the few lines of script inline, no file or
network resource needed. Clicking a figure shows it at full size (Escape or a click closes it).
"""

from __future__ import annotations

import base64
import html
import re
from pathlib import Path

from supportnet.report.document import (
    Block,
    BulletList,
    Document,
    Figure,
    Paragraph,
    Table,
    plain_text,
)

__all__ = ["inline_html", "to_html"]

_INLINE = re.compile(r"`([^`]+)`|\*\*([^*]+)\*\*|\[([^\]]+)\]\(([^)\s]+)\)")

STYLE = """
body { font: 15px/1.5 system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; color: #1b1b1b;
       margin: 0 auto; max-width: 1140px; padding: 1.5em 2em 4em; }
h1 { font-size: 1.9em; margin-bottom: .2em; }
h2 { font-size: 1.45em; border-bottom: 1px solid #ccc; padding-bottom: .2em; margin-top: 2em; }
h3 { font-size: 1.15em; margin-top: 1.6em; }
h4 { font-size: 1em; }
code { font: .9em ui-monospace, SFMono-Regular, Menlo, Consolas, monospace; background: #f1f1f1;
       padding: .05em .3em; border-radius: 3px; }
table { border-collapse: collapse; margin: .6em 0 1.2em; font-size: .92em; }
th, td { border: 1px solid #c8c8c8; padding: .25em .6em; vertical-align: top; }
th { background: #efefef; }
tr:nth-child(even) td { background: #fafafa; }
td.r, th.r { text-align: right; font-variant-numeric: tabular-nums; }
.caption { font-style: italic; margin-bottom: .2em; }
figure { margin: 1em 0 1.8em; }
figure img { max-width: 100%; height: auto; border: 1px solid #bbb; cursor: zoom-in; display: block; }
figcaption { margin-top: .4em; font-size: .93em; color: #333; max-width: 1100px; }
.path { font-family: ui-monospace, monospace; font-size: .85em; color: #666; }
nav.toc { background: #f6f6f6; border: 1px solid #ddd; padding: .5em 1.2em; margin: 1em 0; }
nav.toc ul { margin: .2em 0; padding-left: 1.2em; }
#zoom { position: fixed; inset: 0; background: rgba(0, 0, 0, .88); overflow: auto; cursor: zoom-out;
        z-index: 10; }
#zoom img { display: block; margin: 1em auto; max-width: none; min-width: min(92vw, 1800px);
            background: #fff; }
"""

SCRIPT = """
document.addEventListener('click', function (e) {
  var zoom = document.getElementById('zoom');
  if (e.target.matches('figure img')) {
    zoom.querySelector('img').setAttribute('src', e.target.getAttribute('src'));
    zoom.hidden = false;
  } else if (zoom.contains(e.target)) {
    zoom.hidden = true;
  }
});
document.addEventListener('keydown', function (e) {
  if (e.key === 'Escape') { document.getElementById('zoom').hidden = true; }
});
"""


def inline_html(text: str) -> str:
    """The inline marks of ``text`` as HTML (escaped). A link to an anchor or a web address stays
    a link; a link to a file beside the report is shown as its path (the page needs no files)."""
    out, last = [], 0
    for m in _INLINE.finditer(text):
        out.append(html.escape(text[last : m.start()]))
        code, bold, label, href = m.groups()
        if code is not None:
            out.append(f"<code>{html.escape(code)}</code>")
        elif bold is not None:
            out.append(f"<strong>{html.escape(bold)}</strong>")
        elif href.startswith(("#", "http://", "https://")):
            out.append(f'<a href="{html.escape(href)}">{inline_html(label)}</a>')
        else:
            out.append(f'{inline_html(label)} <span class="path">({html.escape(href)})</span>')
        last = m.end()
    out.append(html.escape(text[last:]))
    return "".join(out)


WIDE = 1100
"""Pixels a figure may take on the page; narrower ones (e.g. 624-pixel synthetic images) are shown
enlarged up to twice their size."""


def _png_width(path: Path) -> int | None:
    """A PNG's width from its header (``None`` for another format)."""
    with open(path, "rb") as f:
        head = f.read(24)
    return int.from_bytes(head[16:20], "big") if head[:8] == b"\x89PNG\r\n\x1a\n" else None


def _data_uri(path: Path) -> str:
    suffix = path.suffix.lower().lstrip(".")
    mime = {"png": "image/png", "jpg": "image/jpeg", "jpeg": "image/jpeg", "svg": "image/svg+xml"}[suffix]
    return f"data:{mime};base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _block(block: Block, root: Path, number: dict[int, int]) -> str:
    if isinstance(block, Paragraph):
        return f"<p>{inline_html(block.text)}</p>"
    if isinstance(block, BulletList):
        return "<ul>" + "".join(f"<li>{inline_html(i)}</li>" for i in block.items) + "</ul>"
    if isinstance(block, Table):
        align = block.alignment()
        head = "".join(
            f'<th class="{a}">{inline_html(h)}</th>' for h, a in zip(block.header, align, strict=True)
        )
        rows = "".join(
            "<tr>"
            + "".join(f'<td class="{a}">{inline_html(c)}</td>' for c, a in zip(row, align, strict=True))
            + "</tr>"
            for row in block.rows
        )
        caption = f'<div class="caption">{inline_html(block.caption)}</div>' if block.caption else ""
        return f"{caption}<table><thead><tr>{head}</tr></thead><tbody>{rows}</tbody></table>"
    if isinstance(block, Figure):
        n = number[id(block)]
        alt = html.escape(block.alt or plain_text(block.caption).split(".")[0], quote=True)
        path = root / block.path
        width = _png_width(path)
        style = f' style="width: {min(2 * width, WIDE)}px"' if width and width < WIDE // 2 + 150 else ""
        return (
            f'<figure id="figure-{n}"><img src="{_data_uri(path)}" alt="{alt}"{style} '
            f'title="click for full size"><figcaption><strong>Figure {n}.</strong> '
            f'{inline_html(block.caption)} <span class="path">({html.escape(block.path)})</span>'
            "</figcaption></figure>"
        )
    raise TypeError(f"not a block: {block!r}")


def to_html(doc: Document, root: Path) -> str:
    """``doc`` as one HTML page; figure paths are read relative to ``root`` and embedded."""
    root = Path(root)
    number = {id(f): i for i, f in enumerate(doc.figures(), start=1)}
    sections = doc.anchors()
    toc = "".join(
        f'<li style="margin-left:{(depth - 1) * 1.2}em"><a href="#{anchor}">{inline_html(s.title)}</a></li>'
        for depth, s, anchor in sections
        if depth <= 2
    )
    body = [f"<h1>{inline_html(doc.title)}</h1>"]
    body += [_block(b, root, number) for b in doc.blocks]
    body.append(f'<nav class="toc"><strong>Contents</strong><ul>{toc}</ul></nav>')
    for depth, section, anchor in sections:
        level = min(depth + 1, 6)
        body.append(f'<h{level} id="{anchor}">{inline_html(section.title)}</h{level}>')
        body += [_block(b, root, number) for b in section.blocks]
    return (
        '<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n'
        '<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<title>{html.escape(plain_text(doc.title))}</title>\n<style>{STYLE}</style>\n</head>\n<body>\n"
        + "\n".join(body)
        + '\n<div id="zoom" hidden><img alt="full size"></div>\n'
        + f"<script>{SCRIPT}</script>\n</body>\n</html>\n"
    )
