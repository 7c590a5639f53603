"""`lrnbv benchmark`: the paper's evaluation campaign, every planner on every object for several
trials, run in parallel processes (or Ray tasks), resumable, and summarised.

What DIR (`--out`) holds:

- `episodes/<planner>__<object>__<trial>.json`: each finished episode's report.json plus a
  `campaign` entry (seed, placement, status, error and traceback), written as soon as it ends;
- `runs/<planner>__<object>__<trial>/`: that episode's own files (frames.npz, report.json,
  replay.html with `--replay`);
- `results.csv` (one row per episode), `summary.md` (medians, IQRs, Mann-Whitney U tests),
  `figure.png` (the paper's Fig. 3 layout) and `coverage_curves.png`, rewritten after every run.

Seeds are paired: each (object, trial) gets its own seed, derived from (base seed, object,
trial) by `numpy.random.SeedSequence` and independent of the planner, so on the same (object,
trial) every planner sees the same sensor-noise stream and the same placement. The U tests
compare planners on the same draws, and adding a planner later compares it on those too.

Rerunning the same command resumes: an episode whose JSON says "ok" is skipped (after checking
that it was run with the same scenario, seed and placement), a failed or missing one runs again.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses as dc
import hashlib
import json
import logging
import math
import multiprocessing
import os
import sys
import time
import traceback
import zlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np
from pydrake.common.yaml import yaml_dump_typed
from tqdm import tqdm

from lrnbv_drake.core import objects
from lrnbv_drake.core.stats import ALPHA, Summary, compare_planners, group_summaries, summarize
from lrnbv_drake.experiments.episode import PLANNERS, make_meshcat, run_episode
from lrnbv_drake.experiments.figures import planner_label, plot_campaign, plot_coverage_curves
from lrnbv_drake.station.scenario import Scenario, ScenarioError, load_scenario

log = logging.getLogger(__name__)

#: The planner the U tests compare the others against.
REFERENCE_PLANNER = "lrnbv"
BACKENDS = ("local", "ray")


class CampaignError(ValueError):
    """Settings that cannot make a campaign, or a DIR holding a different one."""


@dc.dataclass(frozen=True)
class CampaignObject:
    """An object of the campaign: `label` names it in file names and tables, `source` is what
    the scenario loads (a built-in name or an absolute mesh path)."""

    label: str
    source: str


@dc.dataclass(frozen=True)
class PlacementRange:
    """Where `--random-placement` puts an object: uniform footprint centre (m) and yaw (deg).
    The default keeps all 13 HEU poses around every paper object reachable (checked at the
    corners; beyond x = 0.5 the far poses over the tall vertical box leave the arm's reach)."""

    x: tuple[float, float] = (0.45, 0.50)
    y: tuple[float, float] = (-0.08, 0.08)
    yaw_deg: tuple[float, float] = (-180.0, 180.0)

    def sample(self, rng: np.random.Generator) -> tuple[float, float, float]:
        """One (x, y, yaw_deg)."""
        return tuple(float(rng.uniform(lo, hi)) for lo, hi in (self.x, self.y, self.yaw_deg))


@dc.dataclass
class CampaignConfig:
    """One campaign: what runs (planners x objects x trials) and how."""

    out_dir: Path
    planners: tuple[str, ...]
    objects: tuple[CampaignObject, ...]
    trials: int
    # The cell, sensor and placement; its object name is replaced by each of `objects`.
    scenario: Scenario = dc.field(default_factory=Scenario)
    # Base seed every episode's seed derives from.
    seed: int = 0
    # Random placement per trial; None keeps the scenario's.
    placement: PlacementRange | None = None
    # Parallel episodes (local processes, or Ray CPUs of a local Ray instance); 1 runs them in
    # this process, one after the other.
    jobs: int = 1
    backend: str = "local"
    # A running Ray cluster to use instead of starting a local one.
    ray_address: str | None = None
    # Write each episode's Meshcat replay.html (slower).
    replay: bool = False


@dc.dataclass(frozen=True)
class Episode:
    """One (planner, object, trial) with its fully specified scenario."""

    planner: str
    object: CampaignObject
    trial: int
    scenario: Scenario
    # Hash of the scenario (seed, placement, cell, sensor): what resuming checks.
    fingerprint: str
    replay: bool = False

    @property
    def key(self) -> str:
        """`<planner>__<object>__<trial>`: the episode's file names."""
        return f"{self.planner}__{self.object.label}__{self.trial}"

    def campaign_fields(self) -> dict[str, Any]:
        """What the campaign adds to the episode's report: who, which draw, where."""
        obj = self.scenario.object
        return {"episode": self.key, "planner": self.planner, "object": self.object.label,
                "object_source": self.object.source, "trial": self.trial,
                "seed": self.scenario.seed, "object_pose": [obj.x, obj.y, obj.yaw_deg],
                "fingerprint": self.fingerprint, "run_dir": f"runs/{self.key}"}


#: (scenario, planner, run folder, write a replay) -> the episode's report dict.
EpisodeFn = Callable[[Scenario, str, Path, bool], dict[str, Any]]


def simulate(scenario: Scenario, planner: str, out_dir: Path, replay: bool) -> dict[str, Any]:
    """The real episode: `run_episode`, with a Meshcat for the replay only when asked."""
    meshcat = make_meshcat(live=False) if replay else None
    return run_episode(scenario, planner, out_dir, meshcat).report


# ---------------------------------------------------------------- episodes and seeds


def trial_streams(base_seed: int, label: str, trial: int) -> tuple[int, np.random.Generator]:
    """(episode seed, placement generator) of one (object, trial), the same for every planner.

    Two children of one SeedSequence, so the seed and the placement are independent streams;
    the object enters by a CRC of its label, stable across processes (unlike `hash`).
    """
    root = np.random.SeedSequence([base_seed, zlib.crc32(label.encode()), trial])
    seed_child, placement_child = root.spawn(2)
    # 31 bits: a seed any consumer takes as a non-negative int.
    seed = int(seed_child.generate_state(1)[0]) >> 1
    return seed, np.random.default_rng(placement_child)


def plan_episodes(config: CampaignConfig) -> list[Episode]:
    """Every (planner, object, trial), objects and trials outermost so that the planners of
    one (object, trial) run close together."""
    episodes = []
    for obj in config.objects:
        for trial in range(config.trials):
            seed, rng = trial_streams(config.seed, obj.label, trial)
            placed = config.scenario.object
            x, y, yaw = ((placed.x, placed.y, placed.yaw_deg) if config.placement is None
                         else config.placement.sample(rng))
            scenario = dc.replace(config.scenario, seed=seed, object=dc.replace(
                placed, name=obj.source, x=x, y=y, yaw_deg=yaw))
            fingerprint = hashlib.sha256(yaml_dump_typed(scenario).encode()).hexdigest()[:16]
            episodes.extend(Episode(p, obj, trial, scenario, fingerprint, config.replay)
                            for p in config.planners)
    return episodes


def execute(episode: Episode, out_dir: Path, episode_fn: EpisodeFn) -> dict[str, Any]:
    """Runs one episode into out_dir/runs/<key> and returns its record; an exception becomes a
    "failed" record with the traceback, so one bad episode never stops the campaign."""
    started = time.perf_counter()
    fields = episode.campaign_fields()
    try:
        report = episode_fn(episode.scenario, episode.planner, out_dir / fields["run_dir"],
                            episode.replay)
    except Exception as e:
        return failed_record(episode, f"{type(e).__name__}: {e}", traceback.format_exc(),
                             time.perf_counter() - started)
    fields |= {"status": "ok", "error": "", "traceback": "",
               "episode_seconds": time.perf_counter() - started}
    return {**report, "campaign": fields}


def failed_record(episode: Episode, error: str, trace: str, seconds: float) -> dict[str, Any]:
    """The record of an episode that did not finish."""
    return {"campaign": episode.campaign_fields() | {
        "status": "failed", "error": error, "traceback": trace, "episode_seconds": seconds}}


# ---------------------------------------------------------------- backends


def _run_serial(todo: Sequence[Episode], out_dir: Path, episode_fn: EpisodeFn,
                config: CampaignConfig) -> Iterator[dict[str, Any]]:
    for episode in todo:
        yield execute(episode, out_dir, episode_fn)


def _run_processes(todo: Sequence[Episode], out_dir: Path, episode_fn: EpisodeFn,
                   config: CampaignConfig) -> Iterator[dict[str, Any]]:
    # 'spawn': a forked child would inherit Drake's threads and locks mid-state.
    pool = ProcessPoolExecutor(max_workers=config.jobs,
                               mp_context=multiprocessing.get_context("spawn"))
    try:
        futures = {pool.submit(execute, ep, out_dir, episode_fn): ep for ep in todo}
        for future in as_completed(futures):
            try:
                yield future.result()
            except Exception as e:  # the worker died (e.g. a crash in native code)
                yield failed_record(futures[future], f"{type(e).__name__}: {e}",
                                    traceback.format_exc(), math.nan)
    finally:
        # On Ctrl-C or an error here, drop the episodes not yet started.
        pool.shutdown(cancel_futures=True)


def _run_ray(todo: Sequence[Episode], out_dir: Path, episode_fn: EpisodeFn,
             config: CampaignConfig) -> Iterator[dict[str, Any]]:
    try:
        import ray
    except ImportError:
        raise CampaignError("--backend ray needs Ray: pip install 'lrnbv-drake[ray]' "
                            "(or pip install ray), or use --backend local") from None
    started_here = not ray.is_initialized()
    if started_here:
        if config.ray_address:
            ray.init(address=config.ray_address, logging_level=logging.WARNING)
        else:
            ray.init(num_cpus=config.jobs, logging_level=logging.WARNING)
    try:
        # No Ray retries: a failure is recorded, and the next run of the command retries it.
        task = ray.remote(num_cpus=1, max_retries=0)(execute)
        pending = {task.remote(ep, out_dir, episode_fn): ep for ep in todo}
        while pending:
            (done,), _ = ray.wait(list(pending), num_returns=1)
            episode = pending.pop(done)
            try:
                yield ray.get(done)
            except Exception as e:  # the worker or the node died
                yield failed_record(episode, f"{type(e).__name__}: {e}", traceback.format_exc(),
                                    math.nan)
    finally:
        if started_here:
            ray.shutdown()


def _backend(config: CampaignConfig):
    if config.backend == "ray":
        return _run_ray
    if config.backend != "local":
        raise CampaignError(f"unknown backend '{config.backend}': expected one of "
                            f"{', '.join(BACKENDS)}")
    return _run_serial if config.jobs == 1 else _run_processes


# ---------------------------------------------------------------- the campaign


def _write_json(path: Path, data: dict[str, Any]) -> None:
    """Writes through a temporary file, so an interrupted run never leaves half a record."""
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=1))
    os.replace(tmp, path)


def _finished_record(path: Path, episode: Episode) -> dict[str, Any] | None:
    """The record at `path` if it is a finished ("ok") run of `episode`, else None."""
    try:
        record = json.loads(path.read_text())
        fields = record["campaign"]
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError) as e:
        log.warning("%s is unreadable (%s): running the episode again", path, e)
        return None
    if fields.get("status") != "ok":
        return None
    if fields.get("fingerprint") != episode.fingerprint:
        raise CampaignError(
            f"{path} was run with other settings (scenario, seed or placement) than this "
            f"command gives {episode.key}: use another --out, or delete the file to rerun it")
    return record


def run_campaign(config: CampaignConfig, episode_fn: EpisodeFn = simulate,
                 progress: bool = True) -> list[dict[str, Any]]:
    """Runs every episode not yet finished in config.out_dir, writes each record as it ends,
    then results.csv, summary.md and the figures; returns the records in plan order."""
    out_dir = config.out_dir.resolve()
    (out_dir / "episodes").mkdir(parents=True, exist_ok=True)
    episodes = plan_episodes(config)
    records: dict[str, dict[str, Any]] = {}
    for ep in episodes:
        done = _finished_record(out_dir / "episodes" / f"{ep.key}.json", ep)
        if done is not None:
            records[ep.key] = done
    todo = [ep for ep in episodes if ep.key not in records]
    failed = 0
    with tqdm(total=len(episodes), initial=len(records), unit="episode", desc="benchmark",
              disable=not progress, dynamic_ncols=True) as bar:
        for record in _backend(config)(todo, out_dir, episode_fn, config):
            fields = record["campaign"]
            key = fields["episode"]
            _write_json(out_dir / "episodes" / f"{key}.json", record)
            records[key] = record
            if fields["status"] != "ok":
                failed += 1
                bar.write(f"{key} failed: {fields['error']}")
            bar.set_postfix(failed=failed, refresh=False)
            bar.update()
    ordered = [records[ep.key] for ep in episodes]
    write_outputs(config, ordered)
    return ordered


# ---------------------------------------------------------------- results


@dc.dataclass(frozen=True)
class Metric:
    """A results.csv column summarised and tested, with its label in summary.md."""

    column: str
    label: str


METRICS: tuple[Metric, ...] = (
    Metric("est_L", "estimated L (m)"),
    Metric("est_W", "estimated W (m)"),
    Metric("est_H", "estimated H (m)"),
    Metric("abs_err_L", "abs. L error (m)"),
    Metric("abs_err_W", "abs. W error (m)"),
    Metric("abs_err_H", "abs. H error (m)"),
    Metric("iou", "IoU"),
    Metric("coverage_1cm", "coverage, 1 cm"),
    Metric("coverage_2cm", "coverage, 2 cm"),
    Metric("auc_1cm", "coverage AUC, 1 cm"),
    Metric("n_poses", "poses"),
    Metric("n_useless_poses", "useless poses"),
    Metric("wall_seconds", "wall time (s)"),
)

CSV_COLUMNS: tuple[str, ...] = (
    "planner", "object", "trial", "seed", "status", "n_poses", "n_useless_poses",
    "coverage_1cm", "coverage_2cm", "auc_1cm", "auc_2cm", "iou",
    "est_L", "est_W", "est_H", "true_L", "true_W", "true_H", "abs_err_L", "abs_err_W",
    "abs_err_H", "object_x", "object_y", "object_yaw_deg", "termination", "wall_seconds",
    "error",
)


def _num(value: Any) -> float:
    """A metric value as float, NaN for missing (None in the JSON)."""
    return math.nan if value is None else float(value)


def _count(value: Any) -> int | float:
    """A count as int, NaN for missing."""
    return math.nan if value is None else int(value)


def _three(values: Sequence[Any] | None) -> list[float]:
    return [_num(v) for v in values] if values else [math.nan] * 3


def episode_row(record: dict[str, Any]) -> dict[str, Any]:
    """The results.csv row of an episode record; NaN where the report has no value (a failed
    episode, or a report without `metrics`)."""
    fields = record["campaign"]
    metrics = record.get("metrics") or {}
    coverage, auc = metrics.get("coverage") or {}, metrics.get("auc") or {}
    x, y, yaw = fields["object_pose"]
    row = {
        "planner": fields["planner"], "object": fields["object"], "trial": fields["trial"],
        "seed": fields["seed"], "status": fields["status"],
        "n_poses": _count(metrics.get("n_poses", record.get("n_poses"))),
        "n_useless_poses": _count(metrics.get("n_useless_poses")),
        "coverage_1cm": _num(coverage.get("0.01")), "coverage_2cm": _num(coverage.get("0.02")),
        "auc_1cm": _num(auc.get("0.01")), "auc_2cm": _num(auc.get("0.02")),
        "iou": _num(metrics.get("iou")),
        "object_x": x, "object_y": y, "object_yaw_deg": yaw,
        "termination": record.get("termination", ""),
        "wall_seconds": _num((record.get("timing") or {}).get("wall_seconds")),
        "error": fields["error"],
    }
    for prefix, key in (("est", "estimated_dims"), ("true", "true_dims"),
                        ("abs_err", "abs_dim_errors")):
        row.update(zip((f"{prefix}_{d}" for d in "LWH"), _three(metrics.get(key)), strict=True))
    return row


def coverage_curves(records: Iterable[dict[str, Any]]) -> dict[tuple[str, str], list[np.ndarray]]:
    """{(object, planner): coverage-after-each-pose curves at the primary threshold} of the
    finished episodes that report metrics."""
    curves: dict[tuple[str, str], list[np.ndarray]] = {}
    for record in records:
        metrics, fields = record.get("metrics"), record["campaign"]
        if fields["status"] != "ok" or not metrics:
            continue
        curve = metrics["coverage_curve"][f"{metrics['primary_threshold']:g}"]
        curves.setdefault((fields["object"], fields["planner"]), []).append(
            np.array([_num(v) for v in curve]))
    return curves


def write_results_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    """One line per episode; missing numbers are written `nan`."""
    with path.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=CSV_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)


def _fmt(value: float) -> str:
    return "n/a" if not math.isfinite(value) else f"{value:.3g}"


def _cell(summary: Summary) -> str:
    if summary.n == 0:
        return "n/a"
    return f"{_fmt(summary.median)} [{_fmt(summary.q1)}, {_fmt(summary.q3)}] (n={summary.n})"


def _first_line(text: str) -> str:
    """The first line of `text`, safe in a markdown table cell."""
    return (text.splitlines() or [""])[0].replace("|", "\\|")


def _table(header: Sequence[str], lines: Iterable[Sequence[str]]) -> list[str]:
    out = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    out += ["| " + " | ".join(line) + " |" for line in lines]
    out.append("")
    return out


def summary_markdown(config: CampaignConfig, rows: Sequence[dict[str, Any]],
                     records: Sequence[dict[str, Any]]) -> str:
    """summary.md: settings, failures, medians with quartiles, and the U tests."""
    planners, object_labels = config.planners, [o.label for o in config.objects]
    ok = [r for r in rows if r["status"] == "ok"]
    failed = [r for r in rows if r["status"] != "ok"]
    placement = ("the scenario's, (x, y, yaw) = "
                 f"({config.scenario.object.x}, {config.scenario.object.y}, "
                 f"{config.scenario.object.yaw_deg} deg)" if config.placement is None else
                 f"random per trial: x in {list(config.placement.x)} m, y in "
                 f"{list(config.placement.y)} m, yaw in {list(config.placement.yaw_deg)} deg")
    lines = [
        "# Benchmark campaign", "",
        f"- planners: {', '.join(planner_label(p) for p in planners)}",
        f"- objects: {', '.join(object_labels)}",
        f"- trials: {config.trials} per planner and object; base seed {config.seed}; every "
        "planner gets the same seed and placement on the same (object, trial) (paired)",
        f"- placement: {placement}",
        f"- episodes: {len(rows)}, finished {len(ok)}, failed {len(failed)}", "",
    ]
    if failed:
        lines += ["## Failed episodes", "",
                  "Their tracebacks are in episodes/<episode>.json; rerun the same command to "
                  "retry them. They are left out of every statistic below.", ""]
        lines += _table(["episode", "error"], (
            [f["episode"], _first_line(f["error"])] for f in (r["campaign"] for r in records)
            if f["status"] != "ok"))
    no_metrics = sorted({r["campaign"]["planner"] for r in records
                         if r["campaign"]["status"] == "ok" and not r.get("metrics")})
    lines += ["## Medians and quartiles", "",
              "Each cell: median [Q1, Q3] (n = finished episodes with a value); the IQR is "
              "Q3 - Q1. n/a: no value, because every episode failed or the reports carry no "
              "`metrics`."]
    if no_metrics:
        lines += ["", f"The reports of {', '.join(planner_label(p) for p in no_metrics)} "
                  "carry no `metrics` (box, IoU, coverage, useless poses): those are n/a and "
                  "only poses and wall time are summarised."]
    lines.append("")
    summaries = group_summaries(ok, [m.column for m in METRICS])
    empty = summarize([])
    for obj in object_labels:
        lines += [f"### {obj}", ""]
        lines += _table(["metric", *(planner_label(p) for p in planners)], (
            [m.label, *(_cell(summaries.get((obj, p), {}).get(m.column, empty))
                        for p in planners)] for m in METRICS))
    return "\n".join(lines + _comparison_section(config, ok)) + "\n"


def _comparison_section(config: CampaignConfig, ok: Sequence[dict[str, Any]]) -> list[str]:
    ref = REFERENCE_PLANNER
    others = [p for p in config.planners if p != ref]
    lines = ["## Mann-Whitney U tests", ""]
    if ref not in config.planners or not others:
        ran = ", ".join(planner_label(p) for p in config.planners)
        return [*lines, f"n/a: the tests compare {planner_label(ref)} against the other "
                f"planners, and this campaign ran {ran}.", ""]
    lines += [
        f"Two-sided `scipy.stats.mannwhitneyu` of {planner_label(ref)} against each other "
        "planner, per object and metric, over the finished episodes. U is "
        f"{planner_label(ref)}'s statistic: 0 when all its values are below the other's, "
        f"n1 x n2 when all above. * marks p < {ALPHA:g}. p is exact without ties (n <= 8) and "
        "exact over the permutations of the tied ranks with ties (small samples); n/a when a "
        "planner has no value; notes flag equal samples and sample sizes too small to ever "
        f"reach p < {ALPHA:g}.", ""]
    object_labels = [o.label for o in config.objects]
    tests = {(c.object, c.metric, c.other): c.test for c in compare_planners(
        ok, [m.column for m in METRICS], ref, others, object_labels)}
    header = ["metric"]
    for other in others:
        header += [f"vs {planner_label(other)}: {h}" for h in ("U", "p", "method; note")]
    for obj in object_labels:
        body = []
        for metric in METRICS:
            line = [metric.label]
            for other in others:
                t = tests[obj, metric.column, other]
                line += [_fmt(t.u), _fmt(t.p) + (" *" if t.significant else ""),
                         "; ".join(filter(None, (t.method, t.note)))]
            body.append(line)
        lines += [f"### {obj}", "", *_table(header, body)]
    return lines


def write_outputs(config: CampaignConfig, records: Sequence[dict[str, Any]]) -> None:
    """results.csv, summary.md, figure.png and coverage_curves.png from the records."""
    out_dir = config.out_dir
    rows = [episode_row(r) for r in records]
    write_results_csv(out_dir / "results.csv", rows)
    (out_dir / "summary.md").write_text(summary_markdown(config, rows, records))
    object_labels = [o.label for o in config.objects]
    ok = [r for r in rows if r["status"] == "ok"]
    plot_campaign(ok, object_labels, config.planners, out_dir / "figure.png")
    plot_coverage_curves(coverage_curves(records), object_labels, config.planners,
                         out_dir / "coverage_curves.png")


# ---------------------------------------------------------------- command line


def resolve_objects(spec: str) -> tuple[CampaignObject, ...]:
    """`paper`, `all`, a folder of meshes, or comma-separated built-in names / mesh files."""
    expected = ("expected paper, all, a folder of .obj/.stl/.ply meshes, or comma-separated "
                f"built-in objects ({', '.join(objects.BUILTIN_OBJECTS)}) or mesh files")
    if spec == "paper":
        return tuple(CampaignObject(n, n) for n in objects.PAPER_OBJECTS)
    if spec == "all":
        return tuple(CampaignObject(n, n) for n in objects.BUILTIN_OBJECTS)
    folder = Path(spec)
    if folder.is_dir():
        meshes = sorted(p for p in folder.iterdir()
                        if p.is_file() and p.suffix.lower() in objects.MESH_SUFFIXES)
        if not meshes:
            raise CampaignError(f"--objects '{spec}': the folder holds no .obj, .stl or .ply "
                                "file")
    else:
        meshes = []
        for item in filter(None, (s.strip() for s in spec.split(","))):
            if item in objects.BUILTIN_OBJECTS:
                meshes.append(item)
            elif Path(item).suffix.lower() in objects.MESH_SUFFIXES:
                meshes.append(Path(item))
            else:
                raise CampaignError(f"--objects '{spec}': unknown object '{item}': {expected}")
        if not meshes:
            raise CampaignError(f"--objects '{spec}': no object given: {expected}")
    found = tuple(CampaignObject(m, m) if isinstance(m, str) else
                  CampaignObject(m.stem, str(m.resolve())) for m in meshes)
    labels = [o.label for o in found]
    if len(set(labels)) != len(labels):
        raise CampaignError(f"--objects '{spec}': two objects share a name in {labels}: "
                            "rename one, the name keys its files")
    return found


def _planners(text: str) -> tuple[str, ...]:
    names = tuple(dict.fromkeys(p.strip() for p in text.split(",") if p.strip()))
    unknown = [p for p in names if p not in PLANNERS]
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"--planners '{text}': {', '.join(unknown) or 'none given'} not available; "
            f"expected a comma-separated subset of {', '.join(PLANNERS)}")
    return names


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got '{text}'")
    return value


def _interval(text: str) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        lo = hi = math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
        raise argparse.ArgumentTypeError(f"expected MIN,MAX with MIN <= MAX, got '{text}'")
    return lo, hi


def add_benchmark_command(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds `benchmark` to the `lrnbv` command's subparsers."""
    default = PlacementRange()
    parser = subparsers.add_parser(
        "benchmark", help="run the paper's campaign: every planner on every object, N trials",
        description=__doc__.split("\n\n")[0])
    parser.add_argument("--planners", type=_planners, default=PLANNERS,
                        help=f"comma-separated planners (default: {','.join(PLANNERS)})")
    parser.add_argument("--objects", default="paper",
                        help="paper (the four), all (every built-in), a folder of .obj/.stl/"
                             ".ply meshes, or comma-separated built-in names or mesh files")
    parser.add_argument("--trials", type=_positive_int, default=5,
                        help="trials per planner and object (default 5)")
    parser.add_argument("--out", required=True, help="campaign folder; rerun to resume")
    parser.add_argument("--jobs", type=_positive_int, default=os.cpu_count() or 1,
                        help="episodes run at once (default: the CPU count)")
    parser.add_argument("--backend", choices=BACKENDS, default="local",
                        help="local processes, or Ray tasks (needs the 'ray' extra)")
    parser.add_argument("--ray-address",
                        help="a running Ray cluster (default: start a local one with --jobs CPUs)")
    parser.add_argument("--scenario", help="scenario YAML: cell, sensor, object scale and "
                                           "placement; its object is replaced by --objects")
    parser.add_argument("--seed", type=int,
                        help="base seed, from which each (object, trial) derives its own "
                             "(default: the scenario's)")
    parser.add_argument("--random-placement", action="store_true",
                        help="a random object x, y, yaw per trial (the same for every planner)")
    parser.add_argument("--x-range", type=_interval, default=default.x, metavar="MIN,MAX",
                        help=f"random placement x, m (default {default.x[0]},{default.x[1]})")
    parser.add_argument("--y-range", type=_interval, default=default.y, metavar="MIN,MAX",
                        help=f"random placement y, m (default {default.y[0]},{default.y[1]})")
    parser.add_argument("--yaw-range", type=_interval, default=default.yaw_deg,
                        metavar="MIN,MAX", help="random placement yaw, degrees (default "
                                                f"{default.yaw_deg[0]:g},{default.yaw_deg[1]:g})")
    parser.add_argument("--replay", action="store_true",
                        help="write each episode's Meshcat replay.html (slower)")
    return parser


def config_from_args(args: argparse.Namespace) -> CampaignConfig:
    """The campaign the parsed arguments describe; checks every object mesh loads."""
    scenario = load_scenario(filename=args.scenario) if args.scenario else Scenario()
    found = resolve_objects(args.objects)
    for obj in found:
        try:
            objects.load_object_mesh(obj.source, scenario.object.scale)
        except (ValueError, FileNotFoundError) as e:
            raise CampaignError(f"--objects '{args.objects}': {e}") from e
    placement = (PlacementRange(args.x_range, args.y_range, args.yaw_range)
                 if args.random_placement else None)
    return CampaignConfig(
        out_dir=Path(args.out), planners=tuple(args.planners), objects=found,
        trials=args.trials, scenario=scenario,
        seed=scenario.seed if args.seed is None else args.seed, placement=placement,
        jobs=args.jobs, backend=args.backend, ray_address=args.ray_address, replay=args.replay)


def run_benchmark(args: argparse.Namespace) -> int:
    """`lrnbv benchmark`: 0 when every episode finished, 1 when some failed, 2 on bad input."""
    try:
        config = config_from_args(args)
        records = run_campaign(config)
    except (CampaignError, ScenarioError) as e:
        print(f"lrnbv benchmark: error: {e}", file=sys.stderr)
        return 2
    failed = [r["campaign"]["episode"] for r in records if r["campaign"]["status"] != "ok"]
    print(f"{len(records) - len(failed)} of {len(records)} episodes finished; wrote "
          f"{config.out_dir}/results.csv, summary.md, figure.png, coverage_curves.png")
    if failed:
        print(f"{len(failed)} failed ({', '.join(failed)}): see {config.out_dir}/episodes/; "
              "rerun the same command to retry them", file=sys.stderr)
        return 1
    return 0
