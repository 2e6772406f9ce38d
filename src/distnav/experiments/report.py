"""The demo report: one ``index.html`` (and ``REPORT.md``) linking every experiment's figures and key numbers."""

from __future__ import annotations

import html
import json
from pathlib import Path
from typing import Any

from distnav import __version__
from distnav.experiments.common import atomic_write_text, to_jsonable

__all__ = ["write_report"]


def _fmt(v: Any) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    if isinstance(v, (dict, list)):
        return json.dumps(to_jsonable(v))
    return str(v)


def write_report(out_dir: Path, entries: list[tuple[str, str, Any, dict[str, Any], float]]) -> Path:
    """Write ``out_dir/index.html`` and ``out_dir/REPORT.md``; returns the HTML path.

    ``entries`` are ``(name, title, context, results, seconds)``; ``results["headline"]`` (a flat dict of
    label → value), if present, becomes the key-number table.
    """
    out_dir = Path(out_dir)
    md = [f"# distnav demo report (distnav {__version__})", ""]
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>distnav demo report</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:auto}img{max-width:520px;margin:4px;"
        "border:1px solid #ccc}table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:2px 8px}"
        "</style></head><body>",
        f"<h1>distnav demo report</h1><p>distnav {__version__}. Quick variants of every paper reproduction; "
        "run <code>distnav reproduce NAME --out DIR</code> for the full ones.</p>",
    ]
    for name, title, ctx, results, seconds in entries:
        rel = Path(name)
        parts.append(f"<h2 id='{html.escape(name)}'>{html.escape(title)}</h2>")
        parts.append(f"<p>{seconds:.1f} s &middot; <a href='{rel}/results.json'>results.json</a></p>")
        md += [f"## {title}", "", f"{seconds:.1f} s — [{rel}/results.json]({rel}/results.json)", ""]
        headline = results.get("headline", {}) if isinstance(results, dict) else {}
        if headline:
            parts.append("<table><tr><th>quantity</th><th>value</th></tr>")
            md += ["| quantity | value |", "|---|---|"]
            for k, v in headline.items():
                parts.append(f"<tr><td>{html.escape(str(k))}</td><td>{html.escape(_fmt(v))}</td></tr>")
                label = str(k).replace("|", "\\|")
                md.append(f"| {label} | {_fmt(v)} |")
            parts.append("</table>")
            md.append("")
        for fig in ctx.figures:
            parts.append(f"<a href='{rel}/{fig}'><img src='{rel}/{fig}' alt='{html.escape(fig)}'></a>")
            md.append(f"![{fig}]({rel}/{fig})")
        md.append("")
    parts.append("</body></html>")
    index = out_dir / "index.html"
    atomic_write_text(index, "\n".join(parts))
    atomic_write_text(out_dir / "REPORT.md", "\n".join(md) + "\n")
    return index
