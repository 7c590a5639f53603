"""report.html: every section, every image a PNG that decodes, nothing fetched from outside;
and, where Chromium is installed, a browser opens it offline."""

import base64
import io
import re
import shutil
import subprocess

import pytest
from PIL import Image

from lrnbv_drake.experiments.episode import make_meshcat, run_episode
from lrnbv_drake.experiments.report_page import SECTIONS, container_text
from lrnbv_drake.station.scenario import Scenario


@pytest.fixture(scope="module")
def page(tmp_path_factory):
    out = tmp_path_factory.mktemp("heu")
    run_episode(Scenario(seed=1), "heu", out)
    return out / "report.html"


def test_every_section_is_there_with_the_numbers(page):
    text = page.read_text()
    for section in SECTIONS:
        assert f"<h2>{section}</h2>" in text, section
    assert "heu on horizontal_box (seed 1)" in text
    assert "L 32x23x15" in text  # the container the horizontal box gets


def test_every_image_decodes_and_nothing_comes_from_outside(page):
    text = page.read_text()
    images = re.findall(r'<img alt="[^"]*" src="([^"]+)"', text)
    assert len(images) == 3
    for uri in images:
        assert uri.startswith("data:image/png;base64,")
        image = Image.open(io.BytesIO(base64.b64decode(uri.split(",", 1)[1])))
        image.verify()
        assert image.size[0] > 300
    assert not re.search(r"(src|href)=[\"'](https?:)?//", text)
    assert re.findall(r'href="([^"]+)"', text) in ([], ["replay.html"])


@pytest.mark.skipif(shutil.which("chromium") is None, reason="Chromium is not installed")
def test_a_headless_browser_renders_it_offline(page, tmp_path):
    shot = tmp_path / "page.png"
    subprocess.run(["chromium", "--headless", "--no-sandbox", "--disable-gpu",
                    "--disable-background-networking", "--no-first-run",
                    f"--user-data-dir={tmp_path / 'profile'}", f"--screenshot={shot}",
                    "--window-size=1200,2400", page.as_uri()],
                   check=True, timeout=60, capture_output=True)
    assert Image.open(shot).size == (1200, 2400)


def test_the_replay_shows_both_boxes_and_the_poses(tmp_path):
    meshcat = make_meshcat(live=False)
    report = run_episode(Scenario(seed=2), "heu", tmp_path, meshcat).report
    assert meshcat.HasPath("/results/estimated box (red)")
    assert meshcat.HasPath("/results/true box (green)")
    for pose in report["poses"]:
        assert meshcat.HasPath(f"/results/sensor poses (blue)/{pose['index']:03d}")
    assert not meshcat.HasPath(f"/results/sensor poses (blue)/{report['n_poses']:03d}")


def test_a_box_no_container_holds_is_said_in_words():
    report = {"container": {"name": None, "reason": "no container holds 0.9 x 0.2 x 0.1 m",
                            "margin_from": "the interval", "clearance": 0.005},
              "metrics": {"packing": {"fits": False, "right_size": False,
                                      "right_size_container": None}}}
    text = container_text(report)
    assert "None" not in text
    assert "<b>No container</b>: no container holds" in text
    assert "no container holds the true box either" in text
