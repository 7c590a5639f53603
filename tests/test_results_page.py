"""`lrnbv results`: the campaigns docs/results.md cites, from committed manifests, written
into the page between their markers; the same manifest on the same commit gives the same
tables, also when run again from nothing."""

import csv

import pytest

from lrnbv_drake.cli.main import main
from lrnbv_drake.experiments.campaign.results_page import (
    Manifest,
    ManifestError,
    load_manifest,
    manifests,
    splice,
)


def test_every_committed_manifest_loads_and_names_a_campaign_benchmark_accepts(
        tmp_path, monkeypatch):
    from lrnbv_drake.cli.benchmark import add_benchmark_command, config_from_args
    from lrnbv_drake.cli.results import REPO

    monkeypatch.chdir(REPO)  # where a manifest's paths start, as `lrnbv results` runs them

    found = manifests()
    assert {m.name for m in found} >= {"family", "paper", "paper_preset", "datasheet",
                                        "off_model"}
    parser = add_benchmark_command(__import__("argparse").ArgumentParser().add_subparsers())
    for m in found:
        config = config_from_args(parser.parse_args(
            [*m.args, "--out", str(tmp_path / m.name)]))
        assert config.trials >= 2 and config.objects


@pytest.mark.parametrize("text, expected", [
    ("title: x\n", "exactly the keys 'title' and 'args'"),
    ("title: x\nargs: --trials 2\nseeds: 3\n", "exactly the keys"),
    ("title: x\nargs: --trials 2 --out elsewhere\n", "may not set ['--out']"),
    ("title: ''\nargs: --trials 2\n", "non-empty text"),
    ("title: x\ntitle: y\nargs: a\n", "expected each key once"),
])
def test_a_bad_manifest_is_refused_naming_the_file_and_what_was_expected(tmp_path, text,
                                                                           expected):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(ManifestError, match=r"bad\.yaml") as e:
        load_manifest(path)
    assert expected in str(e.value)


def test_splice_replaces_only_the_block_between_its_markers_and_appends_a_new_one():
    m = Manifest("a", "Campaign A", ("--trials", "2"))
    page = "# Results\n\nprose before\n<!-- results: a -->\nold\n<!-- end results: a -->\nafter\n"
    assert splice(page, m, "new\n") == page.replace("old\n", "new\n")
    fresh = splice("# Results\n", m, "t\n")
    assert fresh == ("# Results\n\n## Campaign A\n\n<!-- results: a -->\nt\n"
                     "<!-- end results: a -->\n")
    assert splice(fresh, m, "u\n") == fresh.replace("\nt\n", "\nu\n")
    with pytest.raises(ManifestError, match="without the other"):
        splice("<!-- results: a -->\n", m, "t\n")


def test_results_runs_the_manifest_writes_its_tables_and_regenerates_them_identically(
        tmp_path):
    folder = tmp_path / "campaigns"
    folder.mkdir()
    (folder / "tiny.yaml").write_text(
        "title: Tiny\nargs: --planners heu --objects horizontal_box --trials 1 --seed 3\n")
    page = tmp_path / "results.md"
    page.write_text("# Results\n\nHand-written prose.\n\n<!-- results: tiny -->\n"
                    "<!-- end results: tiny -->\n\nMore prose.\n")
    argv = ["results", "tiny", "--manifests", str(folder), "--out", str(tmp_path / "out"),
            "--page", str(page), "--jobs", "1"]
    assert main(argv) == 0
    first = page.read_text()
    assert first.startswith("# Results\n\nHand-written prose.\n\n<!-- results: tiny -->\n")
    assert first.endswith("<!-- end results: tiny -->\n\nMore prose.\n")
    assert "`lrnbv benchmark --planners heu --objects horizontal_box --trials 1 --seed 3`" in first
    with (tmp_path / "out" / "tiny" / "results.csv").open() as f:
        (row,) = list(csv.DictReader(f))
    worst, poses = f"{1000 * float(row['worst_err']):.1f}", f"{float(row['n_poses']):g}"
    # The page's pooled table: one episode, so its median, p95 and max are the episode's.
    pooled = next(s for s in first.splitlines() if s.startswith("| HEU |")).split(" | ")
    assert pooled[1:4] == [worst] * 3
    assert "[results/tiny.md](results/tiny.md)" in first
    # The page per object, beside it: the episode's worst error and poses, in millimetres.
    detail = tmp_path / "results" / "tiny.md"
    first_detail = detail.read_text()
    assert first_detail.startswith("# Tiny: per object\n")
    line = next(s for s in first_detail.splitlines() if s.startswith("| horizontal_box |"))
    assert line.split(" | ")[1] == worst
    assert line.rstrip(" |").split(" | ")[-1] == poses
    # Again: resumed, the same tables.
    assert main(argv) == 0 and page.read_text() == first and detail.read_text() == first_detail
    # Begun on another commit: refused, then run again from nothing, the same tables.
    stamp = tmp_path / "out" / "tiny" / "source.txt"
    here = stamp.read_text()
    stamp.write_text("0000000-0000000 0000000\n")
    assert main(argv) == 2 and page.read_text() == first
    assert main([*argv, "--restart"]) == 0
    assert page.read_text() == first and detail.read_text() == first_detail
    assert stamp.read_text() == here


def test_a_campaign_refused_before_its_first_episode_is_begun_again_on_new_source(tmp_path):
    """A campaign refused for bad input leaves only its stamp: on other source it begins
    again without --restart. A folder with more in it but no campaign.json is not deleted."""
    from lrnbv_drake.cli.results import _campaign_folder, source_version
    manifest = Manifest("tiny", "Tiny", ("--planners", "heu"))
    stamp = tmp_path / "tiny" / "source.txt"
    stamp.parent.mkdir()
    stamp.write_text("0000000-0000000 0000000\n")
    here, head = source_version()
    assert _campaign_folder(tmp_path, manifest, restart=False) == (stamp.parent, head)
    assert stamp.read_text() == f"{here} {head}\n"
    stamp.write_text("0000000-0000000 0000000\n")
    (stamp.parent / "episodes").mkdir()
    with pytest.raises(ManifestError, match="holds no campaign"):
        _campaign_folder(tmp_path, manifest, restart=True)
    assert (stamp.parent / "episodes").is_dir()


def test_the_tests_table_gives_each_planners_median_and_scipys_exact_p_per_object():
    from types import SimpleNamespace

    from scipy.stats import mannwhitneyu

    from lrnbv_drake.experiments.campaign.results_page import tests_table

    def row(planner, trial, poses, worst):
        return {"planner": planner, "object": "box", "trial": trial, "status": "ok",
                "n_poses": poses, "n_useless_poses": 0.0, "iou": 0.5, "coverage_1cm": 0.5,
                "worst_err": worst}
    lrnbv = [row("lrnbv", t, p, w) for t, (p, w) in enumerate(
        [(5, 0.001), (6, 0.002), (7, 0.003), (8, 0.004)])]
    nbv = [row("nbv", t, p, w) for t, (p, w) in enumerate(
        [(9, 0.0025), (10, 0.0035), (11, 0.0015), (12, 0.0045)])]
    config = SimpleNamespace(planners=("lrnbv", "nbv"), objects=(SimpleNamespace(label="box"),),
                             trials=4)
    lines = tests_table(config, lrnbv + nbv)
    (line,) = [s for s in lines if s.startswith("| box |")]
    cells = line.strip("| ").split(" | ")
    p_poses = mannwhitneyu([5, 6, 7, 8], [9, 10, 11, 12], method="exact").pvalue
    p_worst = mannwhitneyu([1, 2, 3, 4], [2.5, 3.5, 1.5, 4.5], method="exact").pvalue
    assert p_poses < 0.05 < p_worst
    assert cells[1] == "NBV"
    assert cells[2] == f"6.5 vs 10.5, p **{p_poses:.2g}**"
    assert cells[3] == "0 vs 0, p 1"  # equal samples: nothing tells them apart
    assert cells[6] == f"2.5 vs 3.0, p {p_worst:.2g}"
    assert tests_table(SimpleNamespace(planners=("lrnbv",), objects=config.objects, trials=4),
                       lrnbv) == []
    # Three trials a planner: no p can fall below 0.05 (least exact p 0.1), so no table.
    assert tests_table(SimpleNamespace(planners=config.planners, objects=config.objects,
                                       trials=3), lrnbv[:3] + nbv[:3]) == []
