"""docs/results.md's tables regenerated from committed campaign manifests (`lrnbv results`).

A manifest (`benchmarks/campaigns/NAME.yaml`) is the campaign a page cites: its title and the
`lrnbv benchmark` arguments (planners, objects, trials, scenario, seed). Its pooled figures go
between the page's markers `<!-- results: NAME -->` and `<!-- end results: NAME -->`, the prose
around them written by hand; its figures per object go to a page of their own beside it
(`docs/results/NAME.md`), written whole. The tables hold no wall times, so the same manifest
on the same commit gives the same tables (every random choice of a campaign derives from its
seed).
"""

from __future__ import annotations

import dataclasses as dc
import math
import re
import shlex
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from lrnbv_drake.core.evaluation.stats import ALPHA, compare_planners, finite
from lrnbv_drake.core.strict_yaml import load_yaml
from lrnbv_drake.experiments.campaign.figures import planner_label
from lrnbv_drake.experiments.campaign.oracle_table import oracle_line
from lrnbv_drake.experiments.campaign.plan import CampaignConfig
from lrnbv_drake.experiments.campaign.summary import (
    REFERENCE_PLANNER,
    auc_budgets,
    episode_row,
    pooled_table,
    pooled_tests,
    rivals,
)

#: The manifests the page cites.
MANIFEST_DIR = Path(__file__).resolve().parents[3] / "benchmarks" / "campaigns"
#: Arguments the runner sets itself, never a manifest.
RUNNER_ARGS = ("--out", "--jobs", "--backend", "--ray-address", "--replay")


class ManifestError(ValueError):
    """A manifest or page that cannot be used, naming the file and what was expected."""


@dc.dataclass(frozen=True)
class Manifest:
    """One campaign the results page cites."""

    # The file's stem: the campaign's name on the page and in the output folder.
    name: str
    # The page section's title.
    title: str
    # `lrnbv benchmark` arguments (without the runner's: `RUNNER_ARGS`).
    args: tuple[str, ...]

    @property
    def command(self) -> str:
        return shlex.join(["lrnbv", "benchmark", *self.args])


def load_manifest(path: Path) -> Manifest:
    """The manifest at `path`: a mapping with exactly `title` (text) and `args` (text)."""
    try:
        text = Path(path).read_text()
    except OSError as e:
        raise ManifestError(f"campaign manifest '{path}': {e}") from e
    data = load_yaml(text, f"campaign manifest '{path}'", ManifestError)
    if not isinstance(data, dict) or set(data) != {"title", "args"}:
        raise ManifestError(f"campaign manifest '{path}': expected a mapping with exactly the "
                            f"keys 'title' and 'args', got {data!r}")
    if not all(isinstance(data[k], str) and data[k].strip() for k in ("title", "args")):
        raise ManifestError(f"campaign manifest '{path}': 'title' and 'args' must be "
                            "non-empty text")
    args = tuple(shlex.split(data["args"]))
    runner = [a for a in args if a.split("=")[0] in RUNNER_ARGS]
    if runner:
        raise ManifestError(f"campaign manifest '{path}': 'args' may not set {runner}: "
                            "`lrnbv results` chooses where and how the campaign runs")
    return Manifest(Path(path).stem, data["title"].strip(), args)


def manifests(names: Sequence[str] = (), folder: Path = MANIFEST_DIR) -> list[Manifest]:
    """The manifests of `folder` named in `names` (all of them when none is named)."""
    found = {p.stem: p for p in sorted(Path(folder).glob("*.yaml"))}
    unknown = [n for n in names if n not in found]
    if unknown:
        raise ManifestError(f"no campaign manifest {unknown} in '{folder}': expected one of "
                            f"{sorted(found)}")
    return [load_manifest(found[n]) for n in (names or found)]


def _mm(values: Sequence[float]) -> str:
    return ", ".join("n/a" if np.isnan(v) else f"{1000 * v:.1f}" for v in values)


def _median_mm(values: Sequence[float]) -> str:
    v = finite(values)
    return "n/a" if len(v) == 0 else f"{1000 * np.median(v):.1f}"


def objects_table(config: CampaignConfig, rows: Sequence[dict[str, Any]]) -> list[str]:
    """Per object and planner: the worst-dimension error of each trial, the median error of
    L, W and H, and the poses of each trial."""
    header = ["object"]
    for p in config.planners:
        label = planner_label(p)
        header += [f"{label} worst (mm)", f"{label} L, W, H median (mm)", f"{label} poses"]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for obj in (o.label for o in config.objects):
        cells = [obj]
        for p in config.planners:
            mine = sorted((r for r in rows if r["object"] == obj and r["planner"] == p),
                          key=lambda r: r["trial"])
            ok = [r for r in mine if r["status"] == "ok"]
            cells += [_mm([r["worst_err"] for r in mine]) if mine else "n/a",
                      ", ".join(_median_mm([r[f"abs_err_{d}"] for r in ok]) for d in "LWH"),
                      ", ".join("failed" if r["status"] != "ok" else f"{r['n_poses']:g}"
                                for r in mine)]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


#: The per-object tests of the reference planner against the others: the paper's claims
#: (fewer poses, fewer useless ones, IoU, coverage) and the box.
TESTED = (("n_poses", "poses"), ("n_useless_poses", "useless poses"), ("iou", "IoU"),
          ("coverage_1cm", "coverage 1 cm"), ("worst_err", "worst error"))


def tests_table(config: CampaignConfig, rows: Sequence[dict[str, Any]]) -> list[str]:
    """Per object and other planner, each `TESTED` metric's medians (the reference's first)
    and the two-sided U test's p, bold where p < ALPHA; none without a second planner or
    with too few trials for any p below ALPHA (the exact test's least p, 2 / C(2n, n), is
    0.33 at n = 2, 0.1 at 3, 0.029 at 4)."""
    ref, others = REFERENCE_PLANNER, rivals(config)
    if ref not in config.planners or not others or 2 / math.comb(2 * config.trials,
                                                                 config.trials) >= ALPHA:
        return []
    ok = [r for r in rows if r["status"] == "ok"]
    objects = [o.label for o in config.objects]
    tests = {(c.object, c.metric, c.other): c.test for c in compare_planners(
        ok, [m for m, _ in TESTED], ref, others, objects)}

    def median(obj: str, planner: str, metric: str) -> str:
        v = finite(r[metric] for r in ok if r["object"] == obj and r["planner"] == planner)
        if len(v) == 0:
            return "n/a"
        m = float(np.median(v))
        return f"{1000 * m:.1f}" if metric == "worst_err" else f"{m:.3g}"

    header = ["object", "against", *(label for _, label in TESTED)]
    lines = [f"Medians, {planner_label(ref)}'s first, and the two-sided Mann-Whitney p "
             f"(bold: p < {ALPHA:g}; worst error in mm):", "",
             "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for obj in objects:
        for other in others:
            cells = [obj, planner_label(other)]
            for metric, _ in TESTED:
                t = tests[obj, metric, other]
                p = "n/a" if np.isnan(t.p) else f"{t.p:.2g}"
                p = f"**{p}**" if t.significant else p
                cells.append(f"{median(obj, ref, metric)} vs {median(obj, other, metric)}, "
                             f"p {p}")
            lines.append("| " + " | ".join(cells) + " |")
    return ["", *lines]


def _regenerate(manifest: Manifest, rows: Sequence[dict[str, Any]], commit: str) -> str:
    failed = sum(r["status"] != "ok" for r in rows)
    return (f"Regenerate: `.venv/bin/lrnbv results {manifest.name}` "
            f"(benchmarks/campaigns/{manifest.name}.yaml: `{manifest.command}`); at {commit}, "
            f"{len(rows)} episodes, {failed} failed.")


def _rows(records: Sequence[dict[str, Any]]) -> list[dict[str, Any]]:
    budgets = auc_budgets(records)
    return [episode_row(r, budgets.get(r["campaign"]["object"])) for r in records]


def campaign_block(manifest: Manifest, config: CampaignConfig,
                   records: Sequence[dict[str, Any]], commit: str) -> str:
    """The block the results page holds for `manifest`: how to regenerate it, the pooled
    figures, the pooled U tests on one line, and a link to its page per object
    (`detail_page`, at `detail_path`)."""
    rows = _rows(records)
    ok = [r for r in rows if r["status"] == "ok"]
    lines = [f"{_regenerate(manifest, rows, commit)} Per object: "
             f"[results/{manifest.name}.md](results/{manifest.name}.md).", "",
             *pooled_table(config, ok)]
    tests = pooled_tests(config, ok)
    if tests:
        lines.append(f"Pooled U tests of {planner_label(REFERENCE_PLANNER)}: " + "; ".join(
            f"{metric} p {p} (U {u}, n {n})" for metric, u, p, n in tests) + ".")
    if line := oracle_line(config, ok):
        lines.append(line)
    return "\n".join(lines).rstrip() + "\n"


def detail_path(page: Path, manifest: Manifest) -> Path:
    """Where `manifest`'s page per object is written, beside the results page."""
    return Path(page).parent / "results" / f"{manifest.name}.md"


def detail_page(manifest: Manifest, config: CampaignConfig, records: Sequence[dict[str, Any]],
                commit: str) -> str:
    """`manifest`'s page per object, written whole by `lrnbv results`: each object's errors
    and poses per planner and trial, and the per-object U tests."""
    rows = _rows(records)
    lines = [f"# {manifest.title}: per object", "",
             "Written by `lrnbv results`; the pooled figures and what they mean: "
             "[docs/results.md](../results.md).", "", _regenerate(manifest, rows, commit), "",
             "Worst error: an episode's largest of its L, W and H errors, one per trial; "
             "L, W, H: each dimension's median error over the trials; poses: one per trial.",
             "", *objects_table(config, rows), *tests_table(config, rows)]
    return "\n".join(lines).rstrip() + "\n"


def _markers(name: str) -> tuple[str, str]:
    return f"<!-- results: {name} -->", f"<!-- end results: {name} -->"


def splice(page: str, manifest: Manifest, block: str) -> str:
    """`page` with `block` between `manifest`'s markers, or appended under its title where
    the page has none."""
    begin, end = _markers(manifest.name)
    found = re.search(re.escape(begin) + r"\n.*?" + re.escape(end), page, re.S)
    new = f"{begin}\n{block}{end}"
    if found:
        return page[:found.start()] + new + page[found.end():]
    if begin in page or end in page:
        raise ManifestError(f"the results page has one of '{begin}' and '{end}' without the "
                            "other, or in the wrong order")
    return page.rstrip("\n") + f"\n\n## {manifest.title}\n\n{new}\n"
