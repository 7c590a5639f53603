"""A campaign folder as a new user meets it (issue 14): its summary covers every result in it,
however the command that last ran it was narrowed; it holds one campaign's settings; Ctrl-C
keeps what finished; and summary.md reads as people read numbers."""

from __future__ import annotations

import csv
import dataclasses as dc
import json

import numpy as np
import pytest

from lrnbv_drake.core.evaluation.metrics import (
    BoxMetrics,
    EpisodeMetrics,
    coverage_auc,
    useless_poses,
)
from lrnbv_drake.experiments.campaign.plan import CampaignConfig, CampaignError, CampaignObject
from lrnbv_drake.experiments.campaign.run import CampaignInterrupted, run_campaign

TRUE = {"horizontal_box": (0.30, 0.20, 0.12), "vertical_box": (0.12, 0.10, 0.25)}
#: Each planner's length error, m; the width's is 0.1 + 0.2 - 0.3, float noise about 0.
L_ERROR = {"lrnbv": 0.002, "nbv": 0.010, "heu": 0.020}


@dc.dataclass
class Episodes:
    """A stand-in for the simulated episode: an instant report with real `metrics`; raises
    KeyboardInterrupt (as Ctrl-C would) on call number `interrupt_at`."""

    interrupt_at: int | None = None
    calls: list[str] = dc.field(default_factory=list)

    def __call__(self, scenario, planner, out_dir, replay):
        self.calls.append(f"{planner}__{scenario.object.name}")
        if len(self.calls) == self.interrupt_at:
            raise KeyboardInterrupt
        true = np.array(TRUE[scenario.object.name])
        errors = np.array([L_ERROR[planner], 0.1 + 0.2 - 0.3, 0.0])
        curve = np.array([0.5, 0.8])
        metrics = EpisodeMetrics(
            box=BoxMetrics(True, true + errors, true, errors, np.abs(errors), 0.9),
            primary_threshold=0.01, coverage={0.01: 0.8, 0.02: 0.9},
            coverage_curve={0.01: curve, 0.02: curve + 0.1},
            auc={0.01: coverage_auc(curve), 0.02: coverage_auc(curve + 0.1)},
            useless=useless_poses(curve)).to_dict()
        return {"planner": planner, "object": scenario.object.name, "seed": scenario.seed,
                "n_poses": 2, "termination": "synthetic", "metrics": metrics,
                "timing": {"wall_seconds": 1.0}}


def _config(tmp_path, planners=("lrnbv", "nbv", "heu"), names=("horizontal_box",), trials=2,
            **kw) -> CampaignConfig:
    return CampaignConfig(out_dir=tmp_path / "campaign", planners=planners,
                          objects=tuple(CampaignObject(n, n) for n in names), trials=trials,
                          **kw)


def _rows(config: CampaignConfig) -> list[tuple[str, str, str]]:
    with (config.out_dir / "results.csv").open() as f:
        return [(r["planner"], r["object"], r["trial"]) for r in csv.DictReader(f)]


def test_the_summary_covers_every_episode_in_the_folder(tmp_path):
    full = _config(tmp_path)
    run_campaign(full, Episodes(), progress=False)
    # Rerun with one planner and one trial: nothing runs, and nothing is left out.
    narrow = dc.replace(full, planners=("heu",), trials=1)
    fake = Episodes()
    records = run_campaign(narrow, fake, progress=False)
    assert fake.calls == [] and [r["campaign"]["episode"] for r in records] == [
        "heu__horizontal_box__0"]
    every = [(p, "horizontal_box", str(t)) for t in range(2) for p in ("lrnbv", "nbv", "heu")]
    assert _rows(narrow) == every
    summary = (narrow.out_dir / "summary.md").read_text()
    assert "- planners: LR-NBV, NBV, HEU" in summary
    assert "- trials: 2 per planner and object" in summary
    assert "- episodes: 6, finished 6, failed 0" in summary
    # Another object with one planner joins the same folder and summary.
    run_campaign(dc.replace(full, planners=("heu",), objects=(
        CampaignObject("vertical_box", "vertical_box"),)), Episodes(), progress=False)
    # This command's objects first, then the others in the folder.
    assert _rows(full) == [("heu", "vertical_box", "0"), ("heu", "vertical_box", "1"), *every]
    assert "### vertical_box" in (full.out_dir / "summary.md").read_text()


def test_a_folder_holds_one_campaign_s_settings(tmp_path):
    config = _config(tmp_path, planners=("heu",), trials=1)
    run_campaign(config, Episodes(), progress=False)
    recorded = json.loads((config.out_dir / "campaign.json").read_text())
    assert recorded["seed"] == 0 and recorded["placement"] is None
    # Another base seed on other objects would never meet an episode already run, and would
    # still mix two campaigns in one summary.
    other = dc.replace(config, seed=5, objects=(CampaignObject("vertical_box", "vertical_box"),))
    with pytest.raises(CampaignError, match=r"other settings \(seed; see .*campaign\.json\)"):
        run_campaign(other, Episodes(), progress=False)
    assert not (config.out_dir / "episodes" / "heu__vertical_box__0.json").exists()


def test_one_trial_says_it_cannot_be_tested(tmp_path):
    config = _config(tmp_path, trials=1)
    run_campaign(config, Episodes(), progress=False)
    summary = (config.out_dir / "summary.md").read_text()
    tests = summary.split("## Mann-Whitney U tests")[1]
    assert "n/a: with one trial per planner and object (n = 1)" in tests
    assert "|" not in tests  # no table of meaningless tests
    assert "| poses | 2 (n=1) | 2 (n=1) | 2 (n=1) |" in summary  # and no quartiles of one value


def test_summary_numbers_read_as_people_read_them(tmp_path):
    config = _config(tmp_path)
    run_campaign(config, Episodes(), progress=False)
    summary = (config.out_dir / "summary.md").read_text()
    # |0.1 + 0.2 - 0.3| = 5.55e-17 m is no error; 2 mm is 0.002.
    assert "| abs. W error (m) | 0 [0, 0] (n=2) | 0 [0, 0] (n=2) | 0 [0, 0] (n=2) |" in summary
    assert "| abs. L error (m) | 0.002 [0.002, 0.002] (n=2) |" in summary
    assert "e-1" not in summary


def test_ctrl_c_keeps_the_finished_episodes_and_the_rerun_resumes(tmp_path):
    config = _config(tmp_path)
    with pytest.raises(CampaignInterrupted) as interrupted:
        run_campaign(config, Episodes(interrupt_at=3), progress=False)
    assert (interrupted.value.finished, interrupted.value.total) == (2, 6)
    assert str(interrupted.value) == "2 of 6 episodes finished"
    summary = (config.out_dir / "summary.md").read_text()
    assert "- episodes: 2, finished 2, failed 0" in summary
    assert _rows(config) == [("lrnbv", "horizontal_box", "0"), ("nbv", "horizontal_box", "0")]
    fake = Episodes()
    assert len(run_campaign(config, fake, progress=False)) == 6
    assert len(fake.calls) == 4
