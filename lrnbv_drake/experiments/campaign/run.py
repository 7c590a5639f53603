"""Running a campaign into its folder DIR, resumably, and summarising it.

What DIR holds:

- `episodes/<planner>__<object>__<trial>.json`: each finished episode's report.json plus a
  `campaign` entry (seed, placement, status, error and traceback), written as soon as it ends;
- `runs/<planner>__<object>__<trial>/`: that episode's own files (frames.npz, report.json,
  replay.html with `--replay`);
- `results.csv` (one row per episode), `summary.md` (medians, IQRs, Mann-Whitney U tests),
  `figure.png` (the paper's Fig. 3 layout) and `coverage_curves.png`, rewritten after every run.

Rerunning the same campaign resumes: an episode whose JSON says "ok" is skipped (after checking
that it was run with the same scenario, seed and placement), a failed or missing one runs again.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from tqdm import tqdm

from lrnbv_drake.experiments.campaign.backends import EpisodeFn, backend, simulate
from lrnbv_drake.experiments.campaign.plan import (
    CampaignConfig,
    CampaignError,
    Episode,
    plan_episodes,
)
from lrnbv_drake.experiments.campaign.summary import write_outputs
from lrnbv_drake.experiments.recording import write_atomically

log = logging.getLogger(__name__)


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
        for record in backend(config)(todo, out_dir, episode_fn, config):
            fields = record["campaign"]
            key = fields["episode"]
            # Atomic, so an interrupted run never leaves half a record.
            write_atomically(out_dir / "episodes" / f"{key}.json", json.dumps(record, indent=1))
            records[key] = record
            if fields["status"] != "ok":
                failed += 1
                bar.write(f"{key} failed: {fields['error']}")
            bar.set_postfix(failed=failed, refresh=False)
            bar.update()
    ordered = [records[ep.key] for ep in episodes]
    write_outputs(config, ordered)
    return ordered
