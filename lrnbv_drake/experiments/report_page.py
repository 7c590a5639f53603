"""report.html: one page per episode that a packing engineer reads offline in any browser.

It shows the estimated box against the true one (top and side views over the measured
points), the per-dimension errors and interval, the container decision, the curves of box
error, coverage and utility against the pose number, the cycle-time split, and links the
Meshcat replay. The figures are matplotlib PNGs embedded as data URIs, so the page needs no
network and no other file.
"""

from __future__ import annotations

import base64
import html
import io
from collections.abc import Sequence
from typing import Any

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from lrnbv_drake.core.acquisition import Acquisition
from lrnbv_drake.core.boxes import OrientedBox
from lrnbv_drake.core.sensing.sensor import ZoneGeometry

#: The page's sections, in order (tests check each is present).
SECTIONS = ("Box", "Dimensions", "Container", "Progress", "Cycle time", "Replay")


def _figure(**kwargs: Any) -> Figure:
    """A figure on its own Agg canvas: no pyplot state, so pages can be drawn in threads."""
    figure = Figure(**kwargs)
    FigureCanvasAgg(figure)
    return figure


def _png(figure: Figure) -> str:
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=100, bbox_inches="tight")
    return "data:image/png;base64," + base64.b64encode(buffer.getvalue()).decode()


def _box(entry: dict[str, Any] | None) -> OrientedBox | None:
    if entry is None:
        return None
    return OrientedBox(np.array(entry["center"]), np.array(entry["dims"]), entry["yaw"])


def world_points(acquisitions: Sequence[Acquisition], geometry: ZoneGeometry) -> np.ndarray:
    """(n, 3) every valid zone-centre point of the episode, in world."""
    chunks = []
    for a in acquisitions:
        points, valid = geometry.points(a.frame)
        chunks.append(points[valid] @ a.X_WS[:3, :3].T + a.X_WS[:3, 3])
    return np.concatenate(chunks) if chunks else np.zeros((0, 3))


def _views_figure(points: np.ndarray, estimated: OrientedBox | None,
                  true: OrientedBox | None) -> str:
    figure = _figure(figsize=(10, 4.2))
    top, side = figure.subplots(1, 2)
    reference = estimated or true
    centre = reference.center if reference is not None else np.zeros(3)
    near = np.linalg.norm(points[:, :2] - centre[:2], axis=1) < 0.35
    shown = points[near]
    top.scatter(shown[:, 0], shown[:, 1], s=2, c=shown[:, 2], cmap="viridis", label="readings")
    side.scatter(shown[:, 0], shown[:, 2], s=2, c="0.5", label="readings")
    for box, colour, label in ((true, "tab:green", "true"), (estimated, "tab:red", "estimated")):
        if box is None:
            continue
        corners = np.vstack([box.footprint_vertices(), box.footprint_vertices()[:1]])
        style = "--" if label == "true" else "-"
        top.plot(corners[:, 0], corners[:, 1], style, color=colour, lw=1.5, label=label)
        lo, hi = box.aligned().lower, box.aligned().upper
        side.plot([lo[0], hi[0], hi[0], lo[0], lo[0]], [lo[2], lo[2], hi[2], hi[2], lo[2]],
                  style,
                  color=colour, lw=1.5, label=label)
    top.set(title="top view", xlabel="x (m)", ylabel="y (m)", aspect="equal")
    side.set(title="side view (x-z, axis-aligned extent)", xlabel="x (m)", ylabel="z (m)",
             aspect="equal")
    top.legend(loc="upper right", fontsize=8)
    return _png(figure)


def _progress_figure(report: dict[str, Any]) -> str:
    metrics = report.get("metrics", {})
    figure = _figure(figsize=(13, 3.6))
    axes = figure.subplots(1, 3)
    errors = metrics.get("dim_errors_after_each_pose_mm")
    if errors:
        e = np.array([[np.nan if v is None else v for v in row] for row in errors], float)
        n = np.arange(1, len(e) + 1)
        for i, name in enumerate(("length", "width", "height")):
            axes[0].plot(n, e[:, i], marker=".", label=name)
        axes[0].axhspan(-5, 5, color="0.9", label="±5 mm")
        axes[0].set_ylim(-30, 30)
        axes[0].legend(fontsize=8)
    axes[0].set(title="box error after each pose (mm)", xlabel="pose")
    curve = metrics.get("coverage_curve", {})
    for key, values in curve.items():
        axes[1].plot(np.arange(1, len(values) + 1), values, marker=".", label=f"within {key} m")
    axes[1].set(title="surface coverage", xlabel="pose", ylim=(0, 1))
    if curve:
        axes[1].legend(fontsize=8)
    utility = [p["info"].get("utility") for p in report["poses"]]
    axes[2].plot([i + 1 for i, u in enumerate(utility) if u is not None],
                 [u for u in utility if u is not None], marker=".")
    axes[2].set(title="utility of the chosen view", xlabel="pose")
    for axis in axes:
        axis.xaxis.get_major_locator().set_params(integer=True)
    return _png(figure)


def _cycle_figure(cycle: dict[str, float]) -> str:
    figure = _figure(figsize=(6, 1.6))
    axis = figure.subplots()
    left = 0.0
    for key, colour in (("motion_s", "tab:blue"), ("settle_s", "tab:orange"),
                        ("computation_s", "tab:purple")):
        axis.barh(0, cycle[key], left=left, color=colour,
                  label=f"{key[:-2]} {cycle[key]:.1f} s")
        left += cycle[key]
    axis.set(yticks=[], xlabel="seconds", title=f"cycle time {cycle['total_s']:.1f} s")
    axis.legend(fontsize=8, ncol=3, loc="upper center", bbox_to_anchor=(0.5, -0.6))
    return _png(figure)


def _mm(values: Sequence[float] | None) -> list[str]:
    return ["n/a" if values is None else f"{1000 * v:.1f}" for v in (values or [None] * 3)]


def _dimensions_table(report: dict[str, Any]) -> str:
    box = report["estimated_box"] or {}
    metrics = report.get("metrics", {})
    true = metrics.get("true_dims")
    errors = metrics.get("dim_errors_mm") or [None] * 3
    inside = metrics.get("truth_in_interval") or [None] * 3
    rows = []
    estimated, lower, upper = (_mm(box.get(k)) for k in ("dims", "dims_lower", "dims_upper"))
    for i, name in enumerate(("length", "width", "height")):
        cells = [name, estimated[i], f"{lower[i]} to {upper[i]}",
                 "n/a" if true is None else f"{1000 * true[i]:.1f}",
                 "n/a" if errors[i] is None else f"{errors[i]:+.1f}",
                 {True: "yes", False: "no", None: "n/a"}[inside[i]]]
        rows.append("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in cells) + "</tr>")
    header = ("<tr><th>dimension</th><th>estimate (mm)</th><th>interval (mm)</th>"
              "<th>true (mm)</th><th>error (mm)</th><th>truth in interval</th></tr>")
    return f"<table>{header}{''.join(rows)}</table>{_fit_text(box)}"


def _fit_text(box: dict[str, Any]) -> str:
    """What was fitted and how well the model explains the readings, with the warning and the
    command that fixes it where the readings misfit the model."""
    if "shape" not in box:
        return "<p>The box around the object's occupied map cells (no interval).</p>"
    table = box.get("table_misfit")
    text = (f"<p>Fitted as: {html.escape(box['shape'])}, to {box['zones']} zone readings; "
            f"misfit {box['misfit']:.2f}" + ("" if table is None else
                                              f", the bare table's {table:.2f}")
            + " (1 where the model explains the readings to its noise).</p>")
    if box.get("misfit_flag"):
        text += f'<p class="warning"><b>Warning</b>: {html.escape(box["misfit_note"])}.</p>'
    return text


def container_text(report: dict[str, Any]) -> str:
    """The Container section: the container chosen, why, and against the truth whether it
    fits and is the right size."""
    container = report.get("container")
    if container is None:
        return "<p>No box, so no container.</p>"
    extra = ""
    packing = report.get("metrics", {}).get("packing")
    if packing is not None:
        right = packing["right_size_container"]
        extra = (f"<p>Against the true object: fits {'yes' if packing['fits'] else 'no'}; " + (
            f"the right size ({html.escape(right)}): {'yes' if packing['right_size'] else 'no'}"
            if right is not None else "no container holds the true box either") + ".</p>")
    name = container["name"]
    return (f"<p><b>{html.escape(name) if name is not None else 'No container'}</b>: "
            f"{html.escape(container['reason'])}. Margin from {container['margin_from']}, "
            f"clearance {1000 * container['clearance']:.0f} mm.</p>{extra}")


def report_page(report: dict[str, Any], acquisitions: Sequence[Acquisition],
                geometry: ZoneGeometry, replay: bool) -> str:
    """The page's HTML."""
    metrics = report.get("metrics", {})
    points = world_points(acquisitions, geometry)
    views = _views_figure(points, _box(report["estimated_box"]), _box(metrics.get("true_box")))
    title = f"{report['planner']} on {report['object']} (seed {report['seed']})"
    replay_text = ('<p><a href="replay.html">The Meshcat replay of the episode</a> '
                   "(replay.html, beside this page).</p>" if replay else
                   "<p>No replay was written (Meshcat was not allowed).</p>")
    body = [
        f"<h1>{html.escape(title)}</h1>",
        f"<p>{report['n_poses']} poses; ended: {html.escape(report['termination'])}</p>",
        f'<h2>Box</h2><img alt="top and side views" src="{views}">',
        f"<h2>Dimensions</h2>{_dimensions_table(report)}",
        f"<h2>Container</h2>{container_text(report)}",
        f'<h2>Progress</h2><img alt="progress" src="{_progress_figure(report)}">',
        f'<h2>Cycle time</h2><img alt="cycle time" src="{_cycle_figure(report["cycle_time"])}">',
        f"<h2>Replay</h2>{replay_text}",
    ]
    style = ("body{font-family:sans-serif;max-width:1100px;margin:auto}"
             ".warning{background:#fde2c4;padding:6px}"
             "table{border-collapse:collapse}td,th{border:1px solid #bbb;padding:3px 8px}"
             "img{max-width:100%}")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}"
            f"</title><style>{style}</style></head><body>{''.join(body)}</body></html>")
