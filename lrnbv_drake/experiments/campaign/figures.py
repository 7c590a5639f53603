"""Campaign figures: the paper's Fig. 3 layout and the coverage-versus-poses curves.

Drawn with matplotlib's object API on the Agg canvas, without pyplot: no window, no global
backend to set, safe to call from any process. Rows are results.csv rows (see
`summary.episode_row`): the columns read are named in `FIG3_PANELS`; NaN values (failed
episodes, reports without metrics) are left out and an empty panel says n/a. Panels of a row
that show the same kind of value share one range, so a 2 mm gap never fills a panel.
"""

from __future__ import annotations

import dataclasses as dc
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
from matplotlib.axes import Axes
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from lrnbv_drake.core.evaluation.stats import finite

PLANNER_LABELS = {"lrnbv": "LR-NBV", "nbv": "NBV", "heu": "HEU", "oracle": "oracle"}
PLANNER_COLORS = {"lrnbv": "tab:blue", "nbv": "tab:orange", "heu": "tab:green",
                  "oracle": "tab:gray"}


def planner_label(planner: str) -> str:
    """The paper's name of a planner."""
    return PLANNER_LABELS.get(planner, planner.upper())


def _color(planners: Sequence[str], planner: str) -> str:
    return PLANNER_COLORS.get(planner, f"C{3 + planners.index(planner)}")


@dc.dataclass(frozen=True)
class Panel:
    """One column of the Fig. 3 grid: a results.csv column per planner, shown as an error
    against `true_column` when given, times `scale`. Panels of one row on the same `axis`
    share its range: "error" (symmetric about 0, the truth dashed), "fraction" ([0, 1]) or
    "count" (from 0, whole ticks), so that a gap looks as large as it is."""

    column: str
    title: str
    true_column: str | None = None
    scale: float = 1.0
    axis: str = "fraction"


#: (a) the box: each dimension's error against the true one, and the IoU; (b) the coverage
#: and the effort (the paper's (c): its (b) shows photographs of the objects).
FIG3_PANELS: tuple[Panel, ...] = (
    Panel("est_L", "(a) L error (mm)", "true_L", 1000.0, "error"),
    Panel("est_W", "(a) W error (mm)", "true_W", 1000.0, "error"),
    Panel("est_H", "(a) H error (mm)", "true_H", 1000.0, "error"),
    Panel("iou", "(a) IoU"),
    Panel("coverage_1cm", "(b) coverage, 1 cm"),
    Panel("n_poses", "(b) poses", axis="count"),
    Panel("n_useless_poses", "(b) useless poses", axis="count"),
)
#: Smallest half range of the error axis, mm: below it noise would look like a trend.
MIN_ERROR_RANGE_MM = 5.0


def _na(ax: Axes, text: str) -> None:
    ax.text(0.5, 0.5, text, ha="center", va="center", transform=ax.transAxes, fontsize=8,
            color="0.4", wrap=True)


def panel_values(rows: Sequence[Mapping[str, object]], planner: str,
                 panel: Panel) -> np.ndarray:
    """What a panel shows of one planner: its finite values (errors, scaled, when the panel
    has a true column)."""
    mine = [r for r in rows if r["planner"] == planner]
    values = np.array([float(r[panel.column]) for r in mine], dtype=float)
    if panel.true_column is not None:
        values = values - np.array([float(r[panel.true_column]) for r in mine], dtype=float)
    return finite(values * panel.scale)


def _boxes(ax: Axes, samples: Sequence[np.ndarray], planners: Sequence[str]) -> None:
    positions = np.arange(1, len(planners) + 1)
    ax.set_xticks(positions, [planner_label(p) for p in planners], fontsize=8)
    ax.set_xlim(0.4, len(planners) + 0.6)
    shown = [(pos, s, p) for pos, s, p in zip(positions, samples, planners, strict=True)
             if len(s)]
    if not shown:
        _na(ax, "n/a")
        return
    parts = ax.boxplot([s for _, s, _ in shown], positions=[pos for pos, _, _ in shown],
                       widths=0.6, patch_artist=True, showfliers=False, manage_ticks=False)
    for box, (_, _, planner) in zip(parts["boxes"], shown, strict=True):
        box.set_facecolor(_color(planners, planner))
        box.set_alpha(0.5)
    # Five trials per box: show every one, spread sideways so equal values stay visible.
    for pos, sample, _ in shown:
        ax.scatter(pos + np.linspace(-0.12, 0.12, len(sample)), sample, s=9, color="k",
                   zorder=3)


def _share_axes(axes: Sequence[Axes], panels: Sequence[Panel],
                samples: Sequence[Sequence[np.ndarray]]) -> None:
    """One range per axis kind across a row's panels."""
    def largest(kind: str, absolute: bool) -> float:
        values = [np.abs(v) if absolute else v for panel, row in zip(panels, samples,
                                                                     strict=True)
                  if panel.axis == kind for v in row if len(v)]
        return float(max((v.max() for v in values), default=0.0))

    error = max(largest("error", absolute=True), MIN_ERROR_RANGE_MM) * 1.15
    count = largest("count", absolute=False)
    for ax, panel in zip(axes, panels, strict=True):
        if panel.axis == "error":
            ax.set_ylim(-error, error)
            ax.axhline(0.0, color="k", linestyle="--", linewidth=1, label="true")
        elif panel.axis == "count":
            ax.set_ylim(0, max(count, 1.0) * 1.1 + 0.5)
            ax.yaxis.set_major_locator(MaxNLocator(integer=True))
        else:
            ax.set_ylim(0, 1.02)


def plot_campaign(rows: Sequence[Mapping[str, object]], objects: Sequence[str],
                  planners: Sequence[str], path: Path) -> Figure:
    """Fig. 3 of the paper, saved to `path`: a row per object, a box plot per planner in each
    panel. `rows` are the finished episodes."""
    height = 1.9 * len(objects) + 0.8
    fig = Figure(figsize=(2.0 * len(FIG3_PANELS), height))
    FigureCanvasAgg(fig)
    # Fixed margins: constrained layout would cost more than drawing the whole grid.
    fig.subplots_adjust(left=0.06, right=0.99, bottom=0.45 / height, top=1 - 0.7 / height,
                        wspace=0.45, hspace=0.35)
    axes = fig.subplots(len(objects), len(FIG3_PANELS), squeeze=False)
    for i, obj in enumerate(objects):
        of_object = [r for r in rows if r["object"] == obj]
        samples = [[panel_values(of_object, p, panel) for p in planners]
                   for panel in FIG3_PANELS]
        for j, panel in enumerate(FIG3_PANELS):
            _boxes(axes[i][j], samples[j], planners)
            axes[i][j].tick_params(labelsize=8)
            if i == 0:
                axes[i][j].set_title(panel.title, fontsize=9)
        _share_axes(axes[i], FIG3_PANELS, samples)
        axes[i][0].set_ylabel(obj, fontsize=9)
    fig.suptitle("Per object: (a) the box, each dimension's error against the true one "
                 "(dashed: 0) and the IoU; (b) coverage and effort (the paper's Fig. 3 (c)). "
                 "Dots: episodes.", fontsize=10)
    fig.savefig(path, dpi=110)
    return fig


def hold_last(curves: Sequence[np.ndarray], length: int) -> np.ndarray:
    """(n_curves, length): each curve cut to `length` poses, or extended by holding its last
    value, as `metrics.coverage_auc` does: an episode that stopped keeps its final coverage."""
    return np.array([np.concatenate([c[:length], np.full(max(length - len(c), 0), c[-1])])
                     for c in curves])


def plot_coverage_curves(curves: Mapping[tuple[str, str], Sequence[np.ndarray]],
                         objects: Sequence[str], planners: Sequence[str], path: Path) -> Figure:
    """Coverage at the primary threshold after each pose, saved to `path`: the median over the
    episodes of a planner with the band between the quartiles, one panel per object."""
    fig = Figure(figsize=(3.4 * len(objects) + 0.6, 3.2))
    FigureCanvasAgg(fig)
    fig.subplots_adjust(left=0.6 / (3.4 * len(objects) + 0.6), right=0.99, bottom=0.16, top=0.82,
                        wspace=0.08)
    axes = fig.subplots(1, len(objects), squeeze=False, sharey=True)[0]
    for ax, obj in zip(axes, objects, strict=True):
        ax.set_title(obj, fontsize=9)
        ax.set_xlabel("poses")
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        drawn = False
        for planner in planners:
            runs = [c for c in curves.get((obj, planner), []) if len(c)]
            if not runs:
                continue
            length = max(len(c) for c in runs)
            q1, median, q3 = np.percentile(hold_last(runs, length), [25, 50, 75], axis=0)
            poses = np.arange(1, length + 1)
            color = _color(planners, planner)
            ax.plot(poses, median, color=color, marker=".",
                    label=f"{planner_label(planner)} (n={len(runs)})")
            ax.fill_between(poses, q1, q3, color=color, alpha=0.25, linewidth=0)
            drawn = True
        if drawn:
            ax.legend(fontsize=7, loc="lower right")
            ax.set_ylim(0, 1)
        else:
            _na(ax, "n/a: no coverage curves\n(no finished episode\nreports metrics)")
    axes[0].set_ylabel("coverage, primary threshold")
    fig.suptitle("Coverage after each pose: median and interquartile band (an ended episode "
                 "holds its final coverage)", fontsize=10)
    fig.savefig(path, dpi=110)
    return fig
