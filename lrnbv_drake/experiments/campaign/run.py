"""Running a campaign into its folder DIR, resumably, and summarising it.

What DIR holds:

- `campaign.json`: the settings every episode in DIR shares (base seed, placement, scenario);
- `episodes/<planner>__<object>__<trial>.json`: each finished episode's report.json plus a
  `campaign` entry (seed, placement, status, error and traceback), written as soon as it ends;
- `runs/<planner>__<object>__<trial>/`: that episode's own files (frames.npz, report.json,
  replay.html with `--replay`);
- `results.csv` (one row per episode), `summary.md` (medians, IQRs, Mann-Whitney U tests),
  `figure.png` (the paper's Fig. 3 layout) and `coverage_curves.png`, rewritten after every run
  from every episode in DIR, also those an earlier command ran with more planners, objects or
  trials than this one.

Rerunning the same campaign resumes: an episode whose JSON says "ok" is skipped (after checking
that it was run with the same scenario, seed and placement), a failed or missing one runs again.
Adding planners, objects or trials runs only the new episodes; other settings are refused.
Ctrl-C stops the running episodes at once, writes the outputs of those finished and raises
`CampaignInterrupted`.
"""

from __future__ import annotations

import contextlib
import dataclasses as dc
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from pydrake.common.yaml import yaml_dump_typed
from tqdm import tqdm

from lrnbv_drake.experiments.campaign.backends import (
    INTERRUPTS,
    EpisodeFn,
    backend,
    signals_ignored,
    simulate,
)
from lrnbv_drake.experiments.campaign.plan import (
    CampaignConfig,
    CampaignError,
    CampaignObject,
    Episode,
    plan_episodes,
)
from lrnbv_drake.experiments.campaign.summary import write_outputs
from lrnbv_drake.experiments.episode import SIMULATION_PLANNERS
from lrnbv_drake.experiments.recording import write_atomically

log = logging.getLogger(__name__)

CAMPAIGN_FILE = "campaign.json"


class CampaignInterrupted(KeyboardInterrupt):
    """Ctrl-C stopped the campaign; DIR's outputs cover the episodes finished before it."""

    def __init__(self, finished: int, total: int) -> None:
        super().__init__(f"{finished} of {total} episodes finished")
        self.finished, self.total = finished, total


def _settings(config: CampaignConfig) -> dict[str, Any]:
    """What every episode of a folder shares: all but the planners, objects and trials."""
    scenario = dc.replace(config.scenario,
                          object=dc.replace(config.scenario.object, name="(each object)"))
    placement = None if config.placement is None else dc.asdict(config.placement)
    return {"seed": config.seed, "placement": json.loads(json.dumps(placement)),
            "scenario": yaml_dump_typed(scenario)}


def _check_settings(path: Path, config: CampaignConfig) -> None:
    """Refuses settings other than those recorded at `path` (campaign.json), if any."""
    if not path.exists():
        return
    recorded, settings = json.loads(path.read_text()), _settings(config)
    differ = [k for k in settings if recorded.get(k) != settings[k]]
    if differ:
        raise CampaignError(
            f"{path.parent} holds a campaign run with other settings ({', '.join(differ)}; "
            f"see {path}) than this command gives: use another --out, or the same settings "
            "to resume it (planners, objects and trials may change)")


def _read_record(path: Path) -> dict[str, Any] | None:
    """An episode record, or None (with a warning) when the file cannot be read."""
    try:
        record = json.loads(path.read_text())
        missing = [k for k in ("episode", "planner", "object", "trial", "status")
                   if k not in record["campaign"]]
        if missing:
            raise KeyError(", ".join(missing))
    except FileNotFoundError:
        return None
    except (OSError, ValueError, KeyError, TypeError) as e:
        log.warning("%s is unreadable (%s): treated as not run", path, e)
        return None
    return record


def _finished_record(path: Path, episode: Episode) -> dict[str, Any] | None:
    """The record at `path` if it is a finished ("ok") run of `episode`, else None."""
    record = _read_record(path)
    if record is None or record["campaign"]["status"] != "ok":
        return None
    if record["campaign"].get("fingerprint") != episode.fingerprint:
        raise CampaignError(
            f"{path} was run with other settings (scenario, seed or placement) than this "
            f"command gives {episode.key}: use another --out, or delete the file to rerun it")
    return record


def _whole_folder(config: CampaignConfig, episodes: Sequence[Episode],
                  records: dict[str, dict[str, Any]]
                  ) -> tuple[CampaignConfig, list[dict[str, Any]]]:
    """The config and records that the outputs summarise: this command's episodes and every
    other one in DIR, ordered by object, trial and planner."""
    planned = {ep.key for ep in episodes}
    every = [records[ep.key] for ep in episodes if ep.key in records]
    for path in sorted((config.out_dir / "episodes").glob("*.json")):
        if path.stem not in planned and (record := _read_record(path)) is not None:
            every.append(record)
    fields = [r["campaign"] for r in every]
    found = {f["planner"] for f in fields}
    planners = (*(p for p in SIMULATION_PLANNERS if p in found),
                *sorted(found - set(SIMULATION_PLANNERS)))
    objects = list(config.objects)
    for f in fields:
        if f["object"] not in {o.label for o in objects}:
            objects.append(CampaignObject(f["object"], f.get("object_source", f["object"])))
    trials = max((f["trial"] + 1 for f in fields), default=config.trials)
    order = {o.label: i for i, o in enumerate(objects)}
    every.sort(key=lambda r: (order[r["campaign"]["object"]], r["campaign"]["trial"],
                              planners.index(r["campaign"]["planner"])))
    whole = dc.replace(config, planners=planners or config.planners, objects=tuple(objects),
                       trials=trials)
    return whole, every


def run_campaign(config: CampaignConfig, episode_fn: EpisodeFn = simulate,
                 progress: bool = True) -> list[dict[str, Any]]:
    """Runs every episode not yet finished in config.out_dir, writes each record as it ends,
    then results.csv, summary.md and the figures of every episode in the folder; returns
    this command's records in plan order.

    Raises:
        CampaignError: DIR holds a campaign with other settings.
        CampaignInterrupted: Ctrl-C, after the outputs are written.
    """
    out_dir = config.out_dir.resolve()
    config = dc.replace(config, out_dir=out_dir)
    (out_dir / "episodes").mkdir(parents=True, exist_ok=True)
    settings = out_dir / CAMPAIGN_FILE
    _check_settings(settings, config)
    episodes = plan_episodes(config)
    records: dict[str, dict[str, Any]] = {}
    for ep in episodes:
        done = _finished_record(out_dir / "episodes" / f"{ep.key}.json", ep)
        if done is not None:
            records[ep.key] = done
    if not settings.exists():
        write_atomically(settings, json.dumps(_settings(config), indent=1))
    todo = [ep for ep in episodes if ep.key not in records]
    failed, interrupted = 0, False
    try:
        with contextlib.closing(backend(config)(todo, out_dir, episode_fn, config)) as ends, \
                tqdm(total=len(episodes), initial=len(records), unit="episode",
                     desc="benchmark", disable=not progress, dynamic_ncols=True) as bar:
            for record in ends:
                fields = record["campaign"]
                key = fields["episode"]
                # Atomic, so an interrupted run never leaves half a record.
                write_atomically(out_dir / "episodes" / f"{key}.json",
                                 json.dumps(record, indent=1))
                records[key] = record
                if fields["status"] != "ok":
                    failed += 1
                    bar.write(f"{key} failed: {fields['error']}")
                bar.set_postfix(failed=failed, refresh=False)
                bar.update()
    except KeyboardInterrupt:
        interrupted = True
    # After Ctrl-C (or SIGTERM), a second one must not leave the outputs half written.
    with signals_ignored(*INTERRUPTS) if interrupted else contextlib.nullcontext():
        write_outputs(*_whole_folder(config, episodes, records))
    if interrupted:
        finished = sum(records[ep.key]["campaign"]["status"] == "ok"
                       for ep in episodes if ep.key in records)
        raise CampaignInterrupted(finished, len(episodes))
    return [records[ep.key] for ep in episodes]
