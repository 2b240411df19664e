"""HTML pieces shared by the report's sections and the campaign page: the stylesheet,
escaping, tables."""

from __future__ import annotations

import html

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:1.2em auto;
max-width:1100px;color:#222;line-height:1.45;padding:0 1em}
h1{font-size:1.6em;margin:.2em 0}h2{border-bottom:1px solid #ddd;padding-bottom:.2em;
margin-top:1.8em}.meta{color:#555;font-size:.9em;overflow-wrap:anywhere}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em;max-width:100%}
.scroll{overflow-x:auto;max-width:100%}
td,th{border:1px solid #ddd;padding:.25em .6em;text-align:right;vertical-align:top}
th{background:#f4f4f4}td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}figure img{max-width:100%;height:auto;display:block}
figcaption{font-size:.88em;color:#444;margin-top:.3em}
.headline{background:#f0f6ff;border-left:5px solid #08519c;padding:.7em 1.1em;margin:.8em 0}
.headline table{font-size:1em;border:none}.headline td{border:none;padding:.1em .8em .1em 0}
.headline .big{font-size:1.35em;font-weight:600;white-space:nowrap}
.verdict{padding:.6em 1em;margin:.6em 0;border-left:5px solid}
.v-none{background:#ebfbee;border-color:#2b8a3e}.v-explained{background:#fff9db;border-color:#f08c00}
.v-unexplained{background:#ffe3e3;border-color:#c92a2a}
.warn{background:#fff4e5;border-left:4px solid #e6550d;padding:.5em 1em}
.ok{color:#2b8a3e}.bad{color:#c92a2a}.small{font-size:.85em;color:#666}
nav.toc{font-size:.92em;columns:2 16em;background:#fafafa;padding:.5em 1em;border:1px solid #eee}
nav.toc a{text-decoration:none}code{overflow-wrap:anywhere}
"""


def _e(x) -> str:
    return html.escape(str(x))


def _table(head, rows) -> str:
    h = "".join(f"<th>{c}</th>" for c in head)
    body = "".join("<tr>" + "".join(f"<td>{c}</td>" for c in r) + "</tr>" for r in rows)
    return f'<div class="scroll"><table><tr>{h}</tr>{body}</table></div>'
