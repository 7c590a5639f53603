"""`lrnbv results`: run the campaigns docs/results.md cites (benchmarks/campaigns/*.yaml),
write their pooled tables into the page and their tables per object beside it
(docs/results/NAME.md; `lrnbv_drake.experiments.campaign.results_page`).

Each campaign runs into OUT/NAME and resumes there, as `lrnbv benchmark` does, but only on the
source that began it (OUT/NAME/source.txt: the package's and the models' git trees):
episodes of other code are not mixed into one table; `--restart` runs such a campaign again
from nothing. A manifest's file paths (`--scenario`) are from the repository's root, where the
campaigns run.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import shutil
import subprocess
import sys
from pathlib import Path

from lrnbv_drake.cli.arg_types import positive_int
from lrnbv_drake.cli.benchmark import add_benchmark_command, config_from_args
from lrnbv_drake.cli.out_dir import OutDirError
from lrnbv_drake.cli.run import EXIT_BAD_INPUT
from lrnbv_drake.experiments.campaign.plan import CampaignError
from lrnbv_drake.experiments.campaign.results_page import (
    MANIFEST_DIR,
    Manifest,
    ManifestError,
    campaign_block,
    detail_page,
    detail_path,
    manifests,
    splice,
)
from lrnbv_drake.experiments.campaign.run import run_campaign
from lrnbv_drake.station.scenario import ScenarioError

REPO = MANIFEST_DIR.parents[1]
#: The folders whose content decides the episodes.
SOURCE = ("lrnbv_drake", "models")


def add_results_command(subparsers: argparse._SubParsersAction) -> argparse.ArgumentParser:
    """Adds `results` to the `lrnbv` command's subparsers."""
    parser = subparsers.add_parser(
        "results", help="run the campaigns docs/results.md cites and rewrite its tables",
        description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", metavar="NAME",
                        help="manifests to run, by file stem (default: every one in "
                             "benchmarks/campaigns/)")
    parser.add_argument("--out", default="out/results",
                        help="folder of the campaigns, one per manifest (default out/results)")
    parser.add_argument("--page", default=str(REPO / "docs" / "results.md"),
                        help="the page whose tables are rewritten (default docs/results.md)")
    parser.add_argument("--jobs", type=positive_int, default=os.cpu_count() or 1,
                        help="episodes run at once (default: the CPU count)")
    parser.add_argument("--manifests", default=str(MANIFEST_DIR),
                        help="folder of the manifests (default benchmarks/campaigns)")
    parser.add_argument("--restart", action="store_true",
                        help="run a campaign begun on other source again from nothing")
    return parser


def _git(*args: str) -> str:
    return subprocess.run(["git", "-C", str(REPO), *args], capture_output=True, text=True,
                          timeout=10, check=True).stdout.strip()


def source_version() -> tuple[str, str]:
    """(the source's version, the commit to name): the git trees of the package and its
    models, `+` marking uncommitted changes there, and HEAD; ('unknown', 'unknown') outside
    a git checkout. Commits that change neither (docs, tests) keep a campaign's episodes."""
    try:
        trees = "-".join(_git("rev-parse", "--short", f"HEAD:{d}") for d in SOURCE)
        dirty = _git("status", "--porcelain", "--untracked-files=no", "--", *SOURCE)
        head = _git("rev-parse", "--short", "HEAD")
    except (OSError, subprocess.SubprocessError):
        return "unknown", "unknown"
    return trees + ("+" if dirty else ""), head + ("+" if dirty else "")


def _campaign_folder(out: Path, manifest: Manifest, restart: bool) -> tuple[Path, str]:
    """The manifest's campaign folder, and the commit its episodes ran on."""
    folder = out / manifest.name
    stamp = folder / "source.txt"
    here, head = source_version()
    began = stamp.read_text().split() if stamp.is_file() else None
    if began is not None and all(p == stamp for p in folder.iterdir()):
        began = None  # refused before its first episode (bad input): nothing to keep
    if began is not None and began[0] != here:
        if not restart:
            raise ManifestError(f"'{folder}' holds campaign '{manifest.name}' begun on other "
                                f"source (commit {began[1]}, now {head}): add --restart to "
                                "run it again")
        if not (folder / "campaign.json").is_file():
            raise ManifestError(f"'{folder}' holds no campaign (no campaign.json); not deleting")
        shutil.rmtree(folder)
        began = None
    folder.mkdir(parents=True, exist_ok=True)
    if began is None:
        stamp.write_text(f"{here} {head}\n")
        return folder, head
    return folder, began[1]


def run_results(args: argparse.Namespace) -> int:
    """`lrnbv results`: 0 when every campaign finished, 1 when an episode failed (its table
    is written all the same, counting it), 2 on bad input."""
    parser = add_benchmark_command(argparse.ArgumentParser().add_subparsers())
    page, out = Path(args.page).resolve(), Path(args.out).resolve()
    status = 0
    try:
        chosen = manifests(args.names, Path(args.manifests))
        text = page.read_text()
        for manifest in chosen:
            folder, here = _campaign_folder(out, manifest, args.restart)
            print(f"lrnbv results: {manifest.name}: {manifest.command}")
            with contextlib.chdir(REPO):  # where a manifest's paths start
                config = config_from_args(parser.parse_args(
                    [*manifest.args, "--out", str(folder), "--jobs", str(args.jobs)]))
                records = run_campaign(config)
            status |= any(r["campaign"]["status"] != "ok" for r in records)
            text = splice(text, manifest, campaign_block(manifest, config, records, here))
            page.write_text(text)
            detail = detail_path(page, manifest)
            detail.parent.mkdir(exist_ok=True)
            detail.write_text(detail_page(manifest, config, records, here))
    except (ManifestError, CampaignError, ScenarioError, OutDirError, OSError) as e:
        print(f"lrnbv results: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"wrote the tables of {', '.join(m.name for m in chosen)} into {page}")
    return status
