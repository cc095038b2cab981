"""The experiments' tables: Markdown and CSV, cells formatted alike (mean ± s.d. over seeds where shown)."""
from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from ..imageio import atomic_write

#: Metrics whose seed spread the Markdown tables show as "mean ± s.d." (the CSVs hold every *_sd).
SPREAD_SHOWN = ("block_err", "caustic_block_err", "mean_err", "caustic_mean_err")


def _fmt(v, digits=4):
    if v is None:
        return ""
    if isinstance(v, float):
        if math.isnan(v):
            return "n/a"
        if v == 0:
            return "0"
        if abs(v) >= 1000:
            return f"{v:,.0f}"
        if abs(v) < 1e-3:
            return f"{v:.2e}"
        return f"{v:.{digits}g}"
    if isinstance(v, int) and not isinstance(v, bool):
        return f"{v:,}"
    return str(v)


def write_csv(path: Path, rows: list[dict], columns) -> Path:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(columns), extrasaction="ignore")
    w.writeheader()
    for row in rows:
        w.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in columns})
    text = buf.getvalue()
    return atomic_write(path, lambda tmp: tmp.write_text(text, encoding="utf-8"))


def _cell(row: dict, col: str) -> str:
    """A table cell: the value, and "± s.d." over seeds for the metrics in SPREAD_SHOWN."""
    v, sd = row.get(col), row.get(col + "_sd")
    if col in SPREAD_SHOWN and isinstance(v, float) and isinstance(sd, float) and math.isfinite(sd):
        return f"{_fmt(v, 3)} ± {_fmt(sd, 2)}"
    return _fmt(v)


def markdown_table(rows: list[dict], columns, headers=None) -> str:
    headers = headers or {}
    head = "| " + " | ".join(headers.get(c, c) for c in columns) + " |"
    sep = "| " + " | ".join("---" for _ in columns) + " |"
    body = ["| " + " | ".join(_cell(r, c) for c in columns) + " |" for r in rows]
    return "\n".join([head, sep, *body]) + "\n"
