"""A griffe extension for the API reference: hyprog's docstrings are plain-text reST that reads
well in ``help()`` and an editor; mkdocstrings renders docstrings as Markdown, so before they
are rendered this turns

- reST simple tables (``====  ====`` borders) into Markdown tables,
- Sphinx roles (``:mod:`x```, ``:func:`~a.b```) into code spans (``x``, ``b``),
- a paragraph's closing ``::`` (a literal block follows) into ``:``.

The code is not changed; only the rendered documentation. Loaded by ``mkdocs.yml``
(``extensions``).
"""

from __future__ import annotations

import re

import griffe

ROLE = re.compile(r":(?:mod|func|class|meth|data|attr|obj|exc|ref):`(~?[^`]+)`")
BORDER = re.compile(r"^(\s*)(=+)(\s+=+)+\s*$")


def _columns(border: str) -> list[tuple[int, int | None]]:
    """Start and end of each column from a border line (the last column runs to the end)."""
    spans = [(m.start(), m.end()) for m in re.finditer(r"=+", border)]
    return [(s, spans[i + 1][0] if i + 1 < len(spans) else None)
            for i, (s, _) in enumerate(spans)]


def _cells(line: str, cols) -> list[str]:
    return [line[s:e].strip() if e is not None else line[s:].strip() for s, e in cols]


def _table(lines: list[str]) -> list[str]:
    """A reST simple table (its lines, borders included) as Markdown table lines."""
    indent = re.match(r"\s*", lines[0]).group(0)
    cols = _columns(lines[0])
    borders = [i for i, line in enumerate(lines) if BORDER.match(line)]
    header_end = borders[1] if len(borders) > 2 else None
    rows: list[list[str]] = []
    header: list[str] | None = None
    for i, line in enumerate(lines):
        if i in borders:
            if i == header_end and rows:
                header, rows = [" ".join(c) for c in rows[0]], []
            continue
        if not line.strip():
            continue
        cells = _cells(line, cols)
        if any(cells[:-1]) or not rows:  # text before the last column: a new row
            rows.append([[c] if c else [] for c in cells])
        else:  # only the last column: a continuation of the row above
            for j, c in enumerate(cells):
                if c:
                    rows[-1][j].append(c)
    body = [[" ".join(c).replace("|", "\\|") for c in row] for row in rows]
    header = header or [""] * len(cols)
    out = [indent + "| " + " | ".join(header) + " |",
           indent + "|" + "|".join("---" for _ in cols) + "|"]
    out += [indent + "| " + " | ".join(r) + " |" for r in body]
    return ["", *out, ""]


def _role(m: re.Match) -> str:
    target = m.group(1)
    return f"`{target[1:].split('.')[-1] if target.startswith('~') else target}`"


def _table_end(lines: list[str], top: int) -> int:
    """The bottom border of the table whose top border is line ``top``: the first border
    after it that a blank line (or the end of the text) follows."""
    for j in range(top + 1, len(lines)):
        if BORDER.match(lines[j]) and (j + 1 == len(lines) or not lines[j + 1].strip()):
            return j
    return len(lines) - 1


def to_markdown(text: str) -> str:
    """The docstring ``text`` with its reST tables, roles and ``::`` made Markdown."""
    lines = text.splitlines()
    out: list[str] = []
    i = 0
    while i < len(lines):
        if BORDER.match(lines[i]):
            end = _table_end(lines, i)
            out += _table(lines[i:end + 1])
            i = end + 1
        else:
            out.append(lines[i])
            i += 1
    md = ROLE.sub(_role, "\n".join(out))
    return re.sub(r"(\S)::$", r"\1:", md, flags=re.M)


class RestToMarkdown(griffe.Extension):
    """Rewrite every docstring with :func:`to_markdown` as it is loaded."""

    def on_instance(self, *, obj: griffe.Object, **kwargs) -> None:
        if obj.docstring is not None:
            obj.docstring.value = to_markdown(obj.docstring.value)
