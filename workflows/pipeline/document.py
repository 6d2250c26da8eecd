"""A report as a list of blocks, rendered to Markdown and to one self-contained HTML page.

Blocks: ``("h", level, text)``, ``("p", text)``, ``("table", header, rows)``,
``("img", path, caption)`` and ``("pre", text)``. The Markdown links the images by their path
relative to the report; the HTML embeds them as base64 ``data:`` URIs (RFC 2397), so the page
is one file that can be mailed or archived without its folder.
"""

from __future__ import annotations

import base64
import html
from pathlib import Path

STYLE = ("body{font-family:system-ui,sans-serif;max-width:70em;margin:2em auto;padding:0 1em;"
         "line-height:1.45}table{border-collapse:collapse;margin:1em 0}td,th{border:1px solid "
         "#bbb;padding:.25em .6em;text-align:right}th{background:#eee}td:first-child,"
         "th:first-child{text-align:left}pre{background:#f6f6f6;padding:1em;overflow-x:auto}"
         "img{max-width:100%}figcaption{color:#555;font-size:.9em}")


def _cell(v) -> str:
    return str(v).replace("|", "\\|")


def markdown(blocks: list[tuple], base: Path) -> str:
    out = []
    for b in blocks:
        kind = b[0]
        if kind == "h":
            out.append("#" * b[1] + " " + b[2])
        elif kind == "p":
            out.append(b[1])
        elif kind == "table":
            header, rows = b[1], b[2]
            out.append("| " + " | ".join(map(_cell, header)) + " |")
            out.append("|" + "|".join("---" for _ in header) + "|")
            out += ["| " + " | ".join(map(_cell, r)) + " |" for r in rows]
        elif kind == "img":
            out.append(f"![{b[2]}]({Path(b[1]).relative_to(base).as_posix()})")
            out.append("")
            out.append(f"*{b[2]}*")
        elif kind == "pre":
            out.append("```\n" + b[1].rstrip() + "\n```")
        out.append("")
    return "\n".join(out)


def html_page(blocks: list[tuple], title: str) -> str:
    e = html.escape
    out = ["<!DOCTYPE html>", "<html lang=\"en\"><head><meta charset=\"utf-8\">",
           f"<title>{e(title)}</title><style>{STYLE}</style></head><body>"]
    for b in blocks:
        kind = b[0]
        if kind == "h":
            out.append(f"<h{b[1]}>{e(b[2])}</h{b[1]}>")
        elif kind == "p":
            out.append(f"<p>{e(b[1])}</p>")
        elif kind == "table":
            out.append("<table><tr>" + "".join(f"<th>{e(str(h))}</th>" for h in b[1]) + "</tr>")
            out += ["<tr>" + "".join(f"<td>{e(str(v))}</td>" for v in r) + "</tr>" for r in b[2]]
            out.append("</table>")
        elif kind == "img":
            data = base64.b64encode(Path(b[1]).read_bytes()).decode("ascii")
            out.append(f"<figure><img alt=\"{e(b[2])}\" src=\"data:image/png;base64,{data}\">"
                       f"<figcaption>{e(b[2])}</figcaption></figure>")
        elif kind == "pre":
            out.append(f"<pre>{e(b[1])}</pre>")
    out.append("</body></html>")
    return "\n".join(out) + "\n"
