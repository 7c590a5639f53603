"""`lrnbv benchmark`: planning, pairing of seeds, resuming, failures, outputs, backends.

Most tests inject a synthetic episode function whose reports carry `metrics` built by the real
`EpisodeMetrics.to_dict()`, with values chosen so that medians, quartiles and U tests can be
worked by hand; one test runs the real `run_episode` end to end.
"""

import argparse
import csv
import dataclasses as dc
import json
import math
import os
import sys
from pathlib import Path

import numba
import numpy as np
import pytest

from lrnbv_drake.cli.benchmark import add_benchmark_command, config_from_args, run_benchmark
from lrnbv_drake.core.evaluation import objects
from lrnbv_drake.core.evaluation.metrics import (
    BoxMetrics,
    EpisodeMetrics,
    coverage_auc,
    useless_poses,
)
from lrnbv_drake.core.evaluation.stats import compare_planners
from lrnbv_drake.experiments.campaign.figures import (
    FIG3_PANELS,
    plot_campaign,
    plot_coverage_curves,
)
from lrnbv_drake.experiments.campaign.index_page import index_page
from lrnbv_drake.experiments.campaign.plan import (
    CampaignConfig,
    CampaignError,
    CampaignObject,
    PlacementRange,
    plan_episodes,
    resolve_objects,
    trial_streams,
)
from lrnbv_drake.experiments.campaign.run import run_campaign
from lrnbv_drake.experiments.campaign.summary import coverage_curves, episode_row
from lrnbv_drake.experiments.episode import SIMULATION_PLANNERS
from lrnbv_drake.experiments.report import rounded

TRUE_DIMS = {"horizontal_box": (0.30, 0.20, 0.12), "vertical_box": (0.12, 0.10, 0.25)}
ALL_PLANNERS = ("lrnbv", "nbv", "heu")


def _parse(argv):
    parser = argparse.ArgumentParser(prog="lrnbv")
    add_benchmark_command(parser.add_subparsers(dest="command", required=True))
    return parser.parse_args(["benchmark", *argv])


def _objects(*names):
    return tuple(CampaignObject(n, n) for n in names)


def _config(tmp_path, planners=ALL_PLANNERS, names=("horizontal_box", "vertical_box"),
            trials=5, **kw):
    return CampaignConfig(out_dir=tmp_path / "campaign", planners=planners,
                          objects=_objects(*names), trials=trials, **kw)


def synthetic_metrics(planner, obj, trial):
    """Hand-chosen metrics: LR-NBV takes 5 + trial poses, NBV 12 + 2 trial, HEU 13; L is
    over-estimated by 2 mm x trial (LR-NBV), 10 + 2 trial mm (NBV) or 20 mm (HEU)."""
    n = {"lrnbv": 5 + trial, "nbv": 12 + 2 * trial, "heu": 13}[planner]
    curve = np.linspace(0.8 / n, 0.8, n)
    if planner == "nbv":
        curve[2] = curve[1]  # a pose that adds nothing: one useless pose
    true = np.array(TRUE_DIMS[obj])
    err_l = {"lrnbv": 0.002 * trial, "nbv": 0.010 + 0.002 * trial, "heu": 0.020}[planner]
    errors = np.array([err_l, 0.0, -0.01])
    iou = {"lrnbv": 0.90 - 0.01 * trial, "nbv": 0.80 - 0.01 * trial, "heu": 0.85}[planner]
    curves = {0.01: curve, 0.02: np.minimum(curve + 0.1, 1.0)}
    return EpisodeMetrics(
        box=BoxMetrics(True, true + errors, true, errors, np.abs(errors), iou),
        primary_threshold=0.01,
        coverage={t: float(c[-1]) for t, c in curves.items()},
        coverage_curve=curves,
        auc={t: coverage_auc(c) for t, c in curves.items()},
        useless=useless_poses(curve),
    ).to_dict()


@dc.dataclass
class FakeEpisodes:
    """A stand-in for `simulate`: writes and returns a report shaped like run_episode's.

    Args:
        trial_of_seed: maps an episode seed back to its trial (the synthetic values use it).
        fail: (object, trial) whose episodes raise.
        without_metrics: planners whose reports have no `metrics` (HEU today).
    """

    trial_of_seed: dict[int, int]
    fail: tuple[str, int] | None = None
    without_metrics: tuple[str, ...] = ()
    calls: list[tuple[str, str, int]] = dc.field(default_factory=list)

    def __call__(self, scenario, planner, out_dir, replay):
        obj, trial = scenario.object.name, self.trial_of_seed[scenario.seed]
        self.calls.append((planner, obj, trial))
        if (obj, trial) == self.fail:
            raise RuntimeError(f"simulated crash on {obj} trial {trial}")
        report = {
            "planner": planner, "object": obj, "object_scale": scenario.object.scale,
            "object_pose": [scenario.object.x, scenario.object.y, scenario.object.yaw_deg],
            "seed": scenario.seed, "termination": "synthetic", "poses": [],
            "motion_failures": [], "timing": {"wall_seconds": 1.0 + trial},
            "scenario": "", "pid": os.getpid(), "numba_threads": numba.get_num_threads(),
        }
        metrics = synthetic_metrics(planner, obj, trial)
        report["n_poses"] = metrics["n_poses"]
        if planner not in self.without_metrics:
            report["metrics"] = metrics
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "report.json").write_text(json.dumps(report))
        return report


def _fake(config, **kw):
    seeds = {trial_streams(config.seed, o.label, t)[0]: t
             for o in config.objects for t in range(config.trials)}
    assert len(seeds) == len(config.objects) * config.trials  # no two trials share a seed
    return FakeEpisodes(seeds, **kw)


def _csv(path):
    with path.open() as f:
        return list(csv.DictReader(f))


def _png_size(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    return int.from_bytes(data[16:20], "big"), int.from_bytes(data[20:24], "big")


# ---------------------------------------------------------------- the real episode


def test_tiny_campaign_end_to_end_and_resume(tmp_path):
    """Two HEU episodes on two workers, with HEU's ellipse cut to 5 poses by a scenario file
    (which the workers must be given), resumed without running or rewriting anything."""
    out = tmp_path / "heu"
    scenario = tmp_path / "five_poses.yaml"
    scenario.write_text("heu: {n_poses: 5}\n")
    argv = ["--planners", "heu", "--objects", "horizontal_box", "--trials", "2", "--jobs", "2",
            "--scenario", str(scenario), "--out", str(out)]
    assert run_benchmark(_parse(argv)) == 0
    rows = _csv(out / "results.csv")
    assert [(r["planner"], r["object"], r["trial"], r["status"]) for r in rows] == [
        ("heu", "horizontal_box", "0", "ok"), ("heu", "horizontal_box", "1", "ok")]
    assert all(r["n_poses"] == "5" for r in rows)
    assert all(r["termination"] == "visited the 5 ellipse poses" for r in rows)
    assert rows[0]["seed"] != rows[1]["seed"]
    for r in rows:
        key = f"heu__horizontal_box__{r['trial']}"
        record = json.loads((out / "episodes" / f"{key}.json").read_text())
        assert record["campaign"]["status"] == "ok" and record["seed"] == int(r["seed"])
        run = out / "runs" / key
        assert json.loads((run / "report.json").read_text())["seed"] == int(r["seed"])
        assert (run / "frames.npz").is_file() and not (run / "replay.html").exists()
    summary = (out / "summary.md").read_text()
    assert "| poses | 5 [5, 5] (n=2) |" in summary
    if "metrics" in record:
        assert 0 < float(rows[0]["coverage_1cm"]) <= 1 and 0 <= float(rows[0]["iou"]) <= 1
    else:  # before the episode reports metrics
        assert rows[0]["iou"] == "nan" and "The reports of HEU carry no `metrics`" in summary
    _png_size(out / "figure.png")
    _png_size(out / "coverage_curves.png")
    # The container and the cycle time per episode, and index.html linking every report.
    assert all(r["container"] == "L 32x23x15" and r["fits"] == "1.0" for r in rows)
    # The cycle is the arm's 5 moves (more than a second each), the waits for frames and the
    # computation measured (machine-dependent, so only its sum is checked).
    assert all(float(r["cycle_s"]) == pytest.approx(
        float(r["motion_s"]) + float(r["settle_s"]) + float(r["computation_s"]))
        and float(r["motion_s"]) > 5 for r in rows)
    index = (out / "index.html").read_text()
    for r in rows:
        link = f'href="runs/heu__horizontal_box__{r["trial"]}/report.html"'
        assert link in index and (out / link[6:-1]).is_file()
    assert '<img alt="figure.png" src="figure.png">' in index
    # Rerunning resumes: nothing runs again, nothing is rewritten.
    stamps = {p: p.stat().st_mtime_ns for p in out.glob("*/*") if p.is_file()}
    stamps |= {p: p.stat().st_mtime_ns for p in out.glob("runs/*/*")}
    assert run_benchmark(_parse(argv)) == 0
    assert {p: p.stat().st_mtime_ns for p in stamps} == stamps


# ---------------------------------------------------------------- seeds and placement


def test_seeds_and_placements_are_paired_across_planners():
    config = CampaignConfig(Path("unused"), ALL_PLANNERS, _objects("horizontal_box", "flange"),
                            trials=3, seed=11, placement=PlacementRange())
    episodes = plan_episodes(config)
    assert len(episodes) == 3 * 2 * 3
    draws = {}
    for ep in episodes:
        o = ep.scenario.object
        draw = (ep.scenario.seed, o.x, o.y, o.yaw_deg, ep.fingerprint)
        assert draws.setdefault((ep.object.label, ep.trial), draw) == draw  # same per planner
        assert 0.45 <= o.x <= 0.50 and -0.08 <= o.y <= 0.08 and -180 <= o.yaw_deg <= 180
    assert len({d[0] for d in draws.values()}) == len({d[1:4] for d in draws.values()}) == 6
    # Deterministic, and independent of which planners run: a planner added later gets the
    # same draws.
    assert plan_episodes(config) == episodes
    heu_only = plan_episodes(dc.replace(config, planners=("heu",)))
    assert [(e.key, e.scenario) for e in heu_only] == [
        (e.key, e.scenario) for e in episodes if e.planner == "heu"]
    # Another base seed, other draws.
    other = plan_episodes(dc.replace(config, seed=12))
    assert {e.scenario.seed for e in other}.isdisjoint({d[0] for d in draws.values()})


def test_without_random_placement_the_scenario_placement_is_kept(tmp_path):
    config = _config(tmp_path, trials=2)
    placed = config.scenario.object
    for ep in plan_episodes(config):
        o = ep.scenario.object
        assert (o.x, o.y, o.yaw_deg) == (placed.x, placed.y, placed.yaw_deg)
        assert o.name == ep.object.source


# ---------------------------------------------------------------- outputs


@pytest.fixture(scope="module")
def synthetic_campaign(tmp_path_factory):
    config = _config(tmp_path_factory.mktemp("synthetic"))
    fake = _fake(config)
    records = run_campaign(config, fake, progress=False)
    return config, fake, records


def test_results_csv_matches_the_reports(synthetic_campaign):
    config, _, records = synthetic_campaign
    rows = _csv(config.out_dir / "results.csv")
    assert len(rows) == len(records) == 3 * 2 * 5
    for row, record in zip(rows, records, strict=True):
        trial = int(row["trial"])
        m = synthetic_metrics(row["planner"], row["object"], trial)
        assert row["status"] == "ok" and row["error"] == ""
        assert int(row["seed"]) == record["seed"] == record["campaign"]["seed"]
        assert int(row["n_poses"]) == m["n_poses"]
        assert int(row["n_useless_poses"]) == (1 if row["planner"] == "nbv" else 0)
        assert float(row["coverage_1cm"]) == pytest.approx(0.8)
        assert float(row["coverage_2cm"]) == pytest.approx(0.9)
        assert float(row["iou"]) == pytest.approx(m["iou"])
        for i, d in enumerate("LWH"):
            assert float(row[f"est_{d}"]) == pytest.approx(m["estimated_dims"][i])
            assert float(row[f"true_{d}"]) == pytest.approx(TRUE_DIMS[row["object"]][i])
            assert float(row[f"abs_err_{d}"]) == pytest.approx(m["abs_dim_errors"][i])
        assert float(row["wall_seconds"]) == 1.0 + trial
        # The AUC over the most poses any planner took on the object (NBV's 12 + 2 x 4).
        curve = np.array(m["coverage_curve"]["0.01"])
        assert float(row["auc_1cm"]) == pytest.approx(coverage_auc(curve, 20))
    # Seeds paired across planners in the CSV too.
    seeds = {}
    for row in rows:
        assert seeds.setdefault((row["object"], row["trial"]), row["seed"]) == row["seed"]


def test_summary_medians_quartiles_and_u_tests(synthetic_campaign):
    config, _, _ = synthetic_campaign
    summary = (config.out_dir / "summary.md").read_text()
    box = summary.split("### horizontal_box")[1].split("###")[0]
    # Poses: LR-NBV 5..9 -> 7 [6, 8]; NBV 12..20 step 2 -> 16 [14, 18]; HEU 13.
    assert "| poses | 7 [6, 8] (n=5) | 16 [14, 18] (n=5) | 13 [13, 13] (n=5) |" in box
    # |L error|: LR-NBV 0, 2, 4, 6, 8 mm -> 0.004 [0.002, 0.006].
    assert "| abs. L error (m) | 0.004 [0.002, 0.006] (n=5) |" in box
    tests = summary.split("## Mann-Whitney U tests")[1]
    box_tests = tests.split("### horizontal_box")[1].split("###")[0]
    # Every LR-NBV pose count is below every NBV's and HEU's: U = 0, p = 2 / C(10, 5) = 0.00794,
    # exact (without ties against NBV, over the tied ranks against HEU's constant 13).
    assert "| poses | 0 | 0.00794 * | exact | 0 | 0.00794 * | exact, ties |" in box_tests
    # Width: no error for anyone -> equal constant samples, p = 1, not significant.
    equal = "12.5 | 1 | exact, ties; all values equal"
    assert f"| estimated W (m) | {equal} | {equal} |" in box_tests


def test_the_summary_pools_every_object_per_planner(synthetic_campaign):
    """Worst-dimension error: max(|L error|, 0, 10 mm): LR-NBV's L errors (0-8 mm) never
    exceed its 10 mm height error, so 10 mm every episode; NBV's 10-18 mm step 2 on both
    objects: median 14, p95 18 (numpy's linear percentile of the ten), max 18; HEU's 20. The
    synthetic reports carry no interval, misfit or container: n/a. Pooled U of LR-NBV's ten
    10 mm against NBV's: two NBV values tie (20 pairs, half each), the rest lie above: U = 10;
    every LR-NBV pose count (5-9) lies below NBV's (12-20): U = 0."""
    config, _, _ = synthetic_campaign
    pooled = (config.out_dir / "summary.md").read_text().split("## Over every object")[1]
    pooled = pooled.split("## Medians")[0]
    na = "n/a | n/a | n/a | n/a"
    assert f"| LR-NBV | 10.0 | 10.0 | 10.0 | {na} | 7 [6, 8] (n=10) |" in pooled
    assert f"| NBV | 14.0 | 18.0 | 18.0 | {na} |" in pooled
    assert f"| HEU | 20.0 | 20.0 | 20.0 | {na} | 13 [13, 13] (n=10) |" in pooled
    assert "| worst error, vs NBV | 10 |" in pooled and "| poses, vs NBV | 0 |" in pooled
    assert "| worst error, vs HEU | 0 |" in pooled and "| 10 / 10 |" in pooled


def test_float_noise_in_a_report_is_rounded_away_before_the_u_tests(tmp_path):
    """LR-NBV's height error 1e-17 m above the others' (as float arithmetic leaves it): the
    record, results.csv and report.json hold the same rounded number, and the U test sees
    equal samples, not LR-NBV ranked above every other planner."""
    config = _config(tmp_path, names=("horizontal_box",))
    fake = _fake(config)

    def noisy(scenario, planner, out_dir, replay):
        report = fake(scenario, planner, out_dir, replay)
        if "metrics" in report and planner == "lrnbv":
            report["metrics"]["abs_dim_errors"][2] += 1e-17
        return report
    records = run_campaign(config, noisy, progress=False)
    assert 0.01 + 1e-17 != 0.01
    assert all(r["metrics"]["abs_dim_errors"][2] == 0.01 for r in records)
    assert {float(row["abs_err_H"]) for row in _csv(config.out_dir / "results.csv")} == {0.01}
    summary = (config.out_dir / "summary.md").read_text()
    line = next(x for x in summary.splitlines() if x.startswith("| abs. H error (m) | n/a")
                or (x.startswith("| abs. H error (m) |") and "all values equal" in x))
    assert "*" not in line.split("|")[3]


def test_figures_are_drawn(synthetic_campaign):
    config, _, records = synthetic_campaign
    width, height = _png_size(config.out_dir / "figure.png")
    assert width > height > 0  # 7 panels across, 2 objects down
    _png_size(config.out_dir / "coverage_curves.png")
    rows = [episode_row(r) for r in records]
    fig = plot_campaign(rows, ["horizontal_box", "vertical_box"], ALL_PLANNERS,
                        config.out_dir / "again.png")
    assert len(fig.axes) == 2 * len(FIG3_PANELS)
    length = fig.axes[0]
    assert [t.get_text() for t in length.get_xticklabels()] == ["LR-NBV", "NBV", "HEU"]
    (true_line,) = [line for line in length.get_lines() if line.get_linestyle() == "--"]
    assert true_line.get_ydata()[0] == 0.0  # errors around the truth
    # The dots are the episodes: LR-NBV's five length errors, 0 to 8 mm.
    dots = length.collections[0].get_offsets()[:, 1]
    np.testing.assert_allclose(sorted(dots), 2.0 * np.arange(5))
    # L, W and H share one range about 0 that holds the largest error (HEU's 20 mm in L) with
    # a margin, so a 2 mm gap looks as small as it is; pose counts have whole ticks from 0.
    (shared,) = {fig.axes[j].get_ylim() for j in range(3)}
    assert shared == pytest.approx((-23.0, 23.0))
    poses = fig.axes[[p.column for p in FIG3_PANELS].index("n_poses")]
    ticks = [t for t in poses.get_yticks() if 0 <= t <= poses.get_ylim()[1]]
    assert ticks[0] == 0 and all(float(t).is_integer() for t in ticks)
    assert [p.title[:3] for p in FIG3_PANELS] == ["(a)"] * 4 + ["(b)"] * 3
    # The curves: LR-NBV's median reaches 0.8 after 7 poses (5..9) and holds it.
    curves = plot_coverage_curves(coverage_curves(records), ["horizontal_box"], ALL_PLANNERS,
                                  config.out_dir / "again_curves.png")
    median = curves.axes[0].get_lines()[0].get_ydata()
    assert len(median) == 9 and median[6:] == pytest.approx([0.8] * 3) and median[5] < 0.8


def test_an_accuracy_never_reached_ranks_the_same_for_every_planner():
    """Short LR-NBV episodes and HEU's 13 poses that all never reach 5 mm: one value for
    "never" (the pose cap + 1), so the U test finds no difference; with each episode's own
    length + 1 it found p = 0.008."""
    def row(planner, trial, n_poses, poses_to):
        return episode_row({
            "campaign": {"planner": planner, "object": "gripper", "trial": trial, "seed": trial,
                         "object_pose": [0.5, 0, 0], "status": "ok", "error": ""},
            "n_poses": n_poses, "scenario": "max_poses: 20\n",
            "metrics": {"n_poses": n_poses, "poses_to_5mm": poses_to, "poses_to_10mm": 4}})
    rows = ([row("lrnbv", t, n, None) for t, n in enumerate((5, 8, 7, 9, 6))]
            + [row("heu", t, 13, None) for t in range(5)])
    assert {r["poses_to_5mm"] for r in rows} == {21.0}
    assert [r["poses_to_10mm"] for r in rows] == [4.0] * 10
    (comparison,) = compare_planners(rows, ["poses_to_5mm"], "lrnbv", ["heu"], ["gripper"])
    assert not comparison.test.significant


def test_figures_say_na_without_values(tmp_path):
    rows = [episode_row({"campaign": {"planner": "heu", "object": "flange", "trial": 0,
                                      "seed": 1, "object_pose": [0.5, 0, 0], "status": "ok",
                                      "error": ""}, "n_poses": 13})]
    fig = plot_campaign(rows, ["flange"], ["heu"], tmp_path / "f.png")
    iou = fig.axes[FIG3_PANELS.index(next(p for p in FIG3_PANELS if p.column == "iou"))]
    assert [t.get_text() for t in iou.texts] == ["n/a"]
    assert [t.get_text() for t in fig.axes[5].texts] == []  # poses: 13 is there
    curves = plot_coverage_curves({}, ["flange"], ["heu"], tmp_path / "c.png")
    assert curves.axes[0].texts[0].get_text().startswith("n/a")


def test_reports_without_metrics_degrade_to_na(tmp_path):
    config = _config(tmp_path, names=("horizontal_box",), trials=3)
    run_campaign(config, _fake(config, without_metrics=("heu",)), progress=False)
    rows = [r for r in _csv(config.out_dir / "results.csv") if r["planner"] == "heu"]
    assert {r["n_poses"] for r in rows} == {"13"}  # from the report's own n_poses
    assert {r["iou"] for r in rows} == {r["coverage_1cm"] for r in rows} == {"nan"}
    summary = (config.out_dir / "summary.md").read_text()
    assert "The reports of HEU carry no `metrics`" in summary
    assert "| IoU | 0.89 [0.885, 0.895] (n=3) | 0.79 [0.785, 0.795] (n=3) | n/a |" in summary
    assert "| n/a | n/a | n/a; no values in b |" in summary  # LR-NBV vs HEU on IoU


def test_episode_row_of_a_failed_record_and_of_a_missing_box():
    failed = {"campaign": {"planner": "nbv", "object": "gripper", "trial": 2, "seed": 7,
                           "object_pose": [0.5, 0.0, 0.0], "status": "failed",
                           "error": "RuntimeError: boom"}}
    row = episode_row(failed)
    assert row["status"] == "failed" and row["error"] == "RuntimeError: boom"
    assert all(math.isnan(row[k]) for k in ("n_poses", "iou", "est_L", "wall_seconds"))
    metrics = synthetic_metrics("nbv", "horizontal_box", 0)
    metrics |= {"box_found": False, "estimated_dims": [None] * 3, "iou": 0.0}
    row = episode_row({**failed, "metrics": metrics, "campaign": failed["campaign"] | {
        "status": "ok", "error": ""}})
    assert math.isnan(row["est_L"]) and row["iou"] == 0.0 and row["true_L"] == 0.30


# ---------------------------------------------------------------- failures and resuming


def test_a_failing_episode_is_recorded_and_retried_on_rerun(tmp_path):
    config = _config(tmp_path, names=("horizontal_box",), trials=3)
    first = _fake(config, fail=("horizontal_box", 1))
    records = run_campaign(config, first, progress=False)
    assert len(first.calls) == 9
    status = {r["campaign"]["planner"] + str(r["campaign"]["trial"]): r["campaign"]["status"]
              for r in records}
    assert [k for k, s in status.items() if s == "failed"] == ["lrnbv1", "nbv1", "heu1"]
    record = json.loads((config.out_dir / "episodes" / "nbv__horizontal_box__1.json").read_text())
    assert record["campaign"]["error"] == ("RuntimeError: simulated crash on horizontal_box "
                                           "trial 1")
    assert "Traceback" in record["campaign"]["traceback"]
    assert "simulated crash" in record["campaign"]["traceback"]
    rows = _csv(config.out_dir / "results.csv")
    assert [r["status"] for r in rows].count("ok") == 6
    summary = (config.out_dir / "summary.md").read_text()
    assert "## Failed episodes" in summary and "| nbv__horizontal_box__1 | RuntimeError" in summary
    assert "| poses | 6 [5.5, 6.5] (n=2) |" in summary  # trials 0 and 2 only: 5 and 7 poses

    second = _fake(config)
    records = run_campaign(config, second, progress=False)
    assert sorted(second.calls) == sorted([(p, "horizontal_box", 1) for p in ALL_PLANNERS])
    assert all(r["campaign"]["status"] == "ok" for r in records)
    assert "## Failed episodes" not in (config.out_dir / "summary.md").read_text()

    third = _fake(config)
    run_campaign(config, third, progress=False)
    assert third.calls == []


def test_resume_extends_a_campaign_and_refuses_other_settings(tmp_path):
    config = _config(tmp_path, planners=("heu",), names=("horizontal_box",), trials=2)
    run_campaign(config, _fake(config), progress=False)
    # Adding planners and trials runs only the new episodes.
    bigger = dc.replace(config, planners=ALL_PLANNERS, trials=3)
    fake = _fake(bigger)
    run_campaign(bigger, fake, progress=False)
    assert len(fake.calls) == 3 * 3 - 2 and ("heu", "horizontal_box", 2) in fake.calls
    # Another base seed into the same folder would mix two campaigns.
    with pytest.raises(CampaignError, match="other settings"):
        run_campaign(dc.replace(config, seed=5), _fake(config), progress=False)


# ---------------------------------------------------------------- command line and objects


def test_command_line_defaults_and_errors(tmp_path, capsys):
    args = _parse(["--out", str(tmp_path)])
    assert args.planners == SIMULATION_PLANNERS and args.trials == 5 and args.objects == "paper"
    assert args.backend == "local" and not args.replay and not args.random_placement
    config = config_from_args(_parse(["--out", str(tmp_path), "--random-placement",
                                      "--x-range", "0.4,0.5", "--seed", "3"]))
    assert config.placement == PlacementRange(x=(0.4, 0.5))
    assert config.seed == 3 and [o.label for o in config.objects] == list(objects.PAPER_OBJECTS)
    for bad in (["--planners", "nope"], ["--trials", "0"], ["--x-range", "0.5,0.4"],
                ["--backend", "dask"]):
        with pytest.raises(SystemExit):
            _parse(["--out", str(tmp_path), *bad])
    assert run_benchmark(_parse(["--out", str(tmp_path), "--objects", "nope"])) == 2
    assert "unknown object 'nope'" in capsys.readouterr().err
    # A range without --random-placement would be ignored: refused instead.
    assert run_benchmark(_parse(["--out", str(tmp_path), "--yaw-range", "10,20"])) == 2
    assert "--yaw-range set the random placement's ranges" in capsys.readouterr().err
    (tmp_path / "broken.stl").write_text("not a mesh")
    assert run_benchmark(_parse(["--out", str(tmp_path), "--objects",
                                 str(tmp_path / "broken.stl")])) == 2
    assert "broken.stl" in capsys.readouterr().err
    (tmp_path / "bad.yaml").write_text("object: {scale: fast}\n")
    assert run_benchmark(_parse(["--out", str(tmp_path), "--scenario",
                                 str(tmp_path / "bad.yaml")])) == 2
    assert "object.scale" in capsys.readouterr().err
    assert not (tmp_path / "episodes").exists()


def test_object_sets(tmp_path):
    assert [o.label for o in resolve_objects("paper")] == list(objects.PAPER_OBJECTS)
    assert [o.label for o in resolve_objects("all")] == [*objects.PAPER_OBJECTS,
                                                          *objects.FAMILY_OBJECTS]
    folder = tmp_path / "meshes"
    folder.mkdir()
    with pytest.raises(CampaignError, match="holds no"):
        resolve_objects(str(folder))
    source = objects.BUILTIN_OBJECTS["gripper"].path
    (folder / "b_part.OBJ").write_text(source.read_text())
    (folder / "a_part.obj").write_text(source.read_text())
    (folder / "notes.txt").write_text("not a mesh")
    found = resolve_objects(str(folder))
    assert [o.label for o in found] == ["a_part", "b_part"]
    assert all(Path(o.source).is_absolute() and Path(o.source).is_file() for o in found)
    mixed = resolve_objects(f"flange, {folder / 'a_part.obj'}")
    assert [o.label for o in mixed] == ["flange", "a_part"]
    (folder / "a_part.stl").write_text("solid x\nendsolid x\n")
    with pytest.raises(CampaignError, match="share a name"):
        resolve_objects(str(folder))
    for bad in ("nope", "flange,part.step", ","):
        with pytest.raises(CampaignError, match="expected paper, family, held_out, all"):
            resolve_objects(bad)


# ---------------------------------------------------------------- Ray


def test_local_processes_share_the_cores_among_their_numba_threads(tmp_path):
    config = _config(tmp_path, names=("vertical_box",), trials=1, jobs=2)
    records = run_campaign(config, _fake(config), progress=False)
    assert [r["campaign"]["status"] for r in records] == ["ok"] * 3
    assert all(r["pid"] != os.getpid() for r in records)
    # numba's own count: the CPUs this process may run on, or NUMBA_NUM_THREADS
    assert {r["numba_threads"] for r in records} == {max(1, numba.config.NUMBA_NUM_THREADS // 2)}


def test_ray_backend_runs_the_same_episodes(tmp_path):
    ray = pytest.importorskip("ray", reason="the 'ray' extra is not installed")
    # Ray's workers cannot import this test module: send the fake by value.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ray.init(num_cpus=2, include_dashboard=False, logging_level="ERROR")
    try:
        config = _config(tmp_path, names=("vertical_box",), trials=2, backend="ray", jobs=2)
        records = run_campaign(config, _fake(config), progress=False)
    finally:
        ray.shutdown()
        ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    assert [r["campaign"]["episode"] for r in records] == [
        f"{p}__vertical_box__{t}" for t in range(2) for p in ALL_PLANNERS]
    assert [r["campaign"]["status"] for r in records] == ["ok"] * 6
    assert all(r["pid"] != os.getpid() for r in records)  # they ran in Ray's workers
    assert all(r["numba_threads"] == 1 for r in records)  # a task holds one CPU
    assert [r["metrics"] for r in records] == [  # rounded as report.json is
        rounded(synthetic_metrics(p, "vertical_box", t)) for t in range(2) for p in ALL_PLANNERS]
    rows = _csv(config.out_dir / "results.csv")
    assert [r["seed"] for r in rows] == [str(r["seed"]) for r in records]


def test_the_index_page_escapes_what_a_row_holds_and_leaves_a_failed_row_blank(tmp_path):
    """An object label comes from a mesh's file name; a failed episode has NaN figures."""
    nan = float("nan")
    row = {"object": "<b>part</b>", "planner": "lrnbv", "trial": 0, "n_poses": nan,
           "abs_err_L": nan, "abs_err_W": nan, "abs_err_H": nan, "iou": nan,
           "container": None, "cycle_s": nan, "status": "failed"}
    page = index_page(tmp_path, [{"campaign": {"run_dir": "runs/x"}}], [row])
    assert "<b>part</b>" not in page and "&lt;b&gt;part&lt;/b&gt;" in page
    assert "nan" not in page and "None" not in page
