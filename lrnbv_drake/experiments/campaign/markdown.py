"""Markdown cells and tables of a campaign's pages (summary.md, the oracle's table)."""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence

from lrnbv_drake.core.evaluation.stats import Summary


def fmt(value: float, snap: bool = True) -> str:
    """Three significant digits; with `snap`, 0 for a value that is 0 but for float rounding
    (an error of 1.11e-16 m is no error; a p-value of 1e-12 is not 0)."""
    if not math.isfinite(value):
        return "n/a"
    return f"{round(value, 9) + 0.0 if snap else value:.3g}"


def cell(summary: Summary) -> str:
    """Median [Q1, Q3] (n), the median alone at n = 1, n/a with no value."""
    if summary.n == 0:
        return "n/a"
    if summary.n == 1:  # no quartiles to speak of
        return f"{fmt(summary.median)} (n=1)"
    return f"{fmt(summary.median)} [{fmt(summary.q1)}, {fmt(summary.q3)}] (n={summary.n})"


def first_line(text: str) -> str:
    """The first line of `text`, safe in a markdown table cell."""
    return (text.splitlines() or [""])[0].replace("|", "\\|")


def table(header: Sequence[str], lines: Iterable[Sequence[str]]) -> list[str]:
    """A markdown table's lines, and a blank line after it."""
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(line) + " |" for line in lines]
    out.append("")
    return out
