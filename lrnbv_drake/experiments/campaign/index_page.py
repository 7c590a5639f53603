"""index.html: the campaign's front page, readable offline, beside summary.md: the summary
figures and one row per episode linking its report.html."""

from __future__ import annotations

import html
from collections.abc import Sequence
from pathlib import Path
from typing import Any

FIGURES = ("figure.png", "coverage_curves.png")


def _cell(value: Any, digits: int = 1) -> str:
    if isinstance(value, float):
        return "" if value != value else f"{value:.{digits}f}"  # NaN: empty
    return html.escape(str(value))


def index_page(out_dir: Path, records: Sequence[dict[str, Any]],
               rows: Sequence[dict[str, Any]]) -> str:
    """The page's HTML; links are relative to the campaign folder `out_dir`."""
    lines = []
    for record, row in zip(records, rows, strict=True):
        run_dir = record["campaign"]["run_dir"]
        report = out_dir / run_dir / "report.html"
        link = (f'<a href="{html.escape(run_dir)}/report.html">report</a>'
                if report.exists() else html.escape(row["status"]))
        errors = " / ".join(_cell(row[f"abs_err_{d}"] * 1000) for d in "LWH")
        cells = [_cell(row["object"]), _cell(row["planner"]), _cell(row["trial"]),
                 _cell(row["n_poses"], 0), errors, _cell(row["iou"], 3),
                 _cell(row["container"] or ""), _cell(row["cycle_s"]), link]
        lines.append("<tr>" + "".join(f"<td>{c}</td>" for c in cells) + "</tr>")
    header = ("<tr><th>object</th><th>planner</th><th>trial</th><th>poses</th>"
              "<th>|error| L / W / H (mm)</th><th>IoU</th><th>container</th>"
              "<th>cycle (s)</th><th>episode</th></tr>")
    figures = "".join(f'<p><img alt="{name}" src="{name}"></p>' for name in FIGURES
                      if (out_dir / name).exists())
    style = ("body{font-family:sans-serif;max-width:1200px;margin:auto}"
             "table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:2px 6px}"
             "img{max-width:100%}")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>Campaign</title>"
            f"<style>{style}</style></head><body><h1>Campaign</h1>"
            f'<p>The statistics and the U tests are in <a href="summary.md">summary.md</a>, '
            f'every number in <a href="results.csv">results.csv</a>.</p>{figures}'
            f"<table>{header}{''.join(lines)}</table></body></html>")
