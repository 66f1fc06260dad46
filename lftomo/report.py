"""A self-contained HTML report: figures embedded as base64 PNG, metrics as tables."""

from __future__ import annotations

import base64
import html
import json
from pathlib import Path
from typing import Any, Sequence


def _img(path: Path, alt: str) -> str:
    data = base64.b64encode(Path(path).read_bytes()).decode("ascii")
    return f'<img src="data:image/png;base64,{data}" alt="{html.escape(alt)}" data-file="{html.escape(Path(path).name)}">'


def _table(rows: dict[str, Any]) -> str:
    out = ["<table>"]
    for k, v in rows.items():
        if isinstance(v, float):
            v = f"{v:.4g}"
        elif isinstance(v, (list, tuple)):
            v = ", ".join(f"{x:.4g}" if isinstance(x, float) else str(x) for x in v)
        out.append(f"<tr><th>{html.escape(str(k))}</th><td>{html.escape(str(v))}</td></tr>")
    out.append("</table>")
    return "\n".join(out)


CSS = """
body { font-family: system-ui, sans-serif; max-width: 1200px; margin: 2em auto; color: #222; line-height: 1.45; }
h1 { margin-bottom: 0.2em; } h2 { border-bottom: 1px solid #ccc; padding-bottom: 0.2em; margin-top: 2em; }
img { max-width: 100%; border: 1px solid #ddd; margin: 0.5em 0; }
table { border-collapse: collapse; margin: 0.5em 0; } th, td { padding: 0.2em 0.8em; border-bottom: 1px solid #eee; text-align: left; }
th { font-weight: 600; } .note { color: #555; font-size: 0.95em; } code { background: #f4f4f4; padding: 0 0.2em; }
"""


def write_report(directory: str | Path, title: str, sections: Sequence[dict[str, Any]], metrics: dict[str, Any],
                 *, intro: str = "") -> Path:
    """Write ``index.html`` (figures embedded, also kept beside it as PNG) and ``metrics.json``.

    Each section: ``{"title": str, "text": str, "figures": [(path, caption)], "table": dict}``.
    """
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>",
             f"<style>{CSS}</style></head><body>", f"<h1>{html.escape(title)}</h1>"]
    if intro:
        parts.append(f"<p class='note'>{intro}</p>")
    for sec in sections:
        parts.append(f"<h2>{html.escape(sec['title'])}</h2>")
        if sec.get("text"):
            parts.append(f"<p>{sec['text']}</p>")
        for path, caption in sec.get("figures", []):
            parts.append(f"<figure>{_img(path, caption)}<figcaption class='note'>{html.escape(caption)}</figcaption></figure>")
        if sec.get("table"):
            parts.append(_table(sec["table"]))
    parts.append("</body></html>")
    index = d / "index.html"
    from .io import atomic_write_text

    # metrics first, the report last: a report on disk always has its metrics beside it
    atomic_write_text(d / "metrics.json", json.dumps(metrics, indent=2, default=_json_default))
    atomic_write_text(index, "\n".join(parts))
    return index


def _json_default(o):
    import numpy as np

    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (np.floating, np.integer, np.bool_)):
        return o.item()
    if isinstance(o, Path):
        return str(o)
    raise TypeError(f"not JSON serialisable: {type(o).__name__}")
