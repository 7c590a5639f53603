"""`lrnbv refit`: a recorded episode's box estimated again from its frames.npz and report.json,
under its own scenario or another one."""

import json
import shutil

import numpy as np
import pytest

from lrnbv_drake.cli.main import main


def _refit(tmp_path, *args):
    out = tmp_path / "refit.json"
    code = main(["refit", *map(str, args), "--out", str(out)])
    return code, (json.loads(out.read_text()) if out.exists() else None)


def test_its_own_scenario_gives_back_the_reported_box_and_changes_no_file(heu_run, tmp_path):
    before = {name: (heu_run / name).read_bytes() for name in ("report.json", "frames.npz")}
    code, (result,) = _refit(tmp_path, heu_run)
    report = json.loads(before["report.json"])
    assert code == 0
    assert result["estimated_box"] == report["estimated_box"]
    assert result["container"] == report["container"]
    assert result["dim_errors_mm"] == report["metrics"]["dim_errors_mm"]
    assert result["truth_in_interval"] == report["metrics"]["truth_in_interval"]
    assert {name: (heu_run / name).read_bytes() for name in before} == before


def test_the_cell_estimator_gives_the_recorded_cell_box(heu_run, tmp_path):
    code, (result,) = _refit(tmp_path, heu_run, "--scenario-text",
                             "{extraction: {estimator: cells}}")
    report = json.loads((heu_run / "report.json").read_text())
    assert code == 0
    np.testing.assert_allclose(result["estimated_box"]["dims"], report["cell_box"]["dims"],
                               atol=1e-9)
    assert "dims_lower" not in result["estimated_box"]  # the cell box has no interval


def test_a_model_that_calls_the_sensor_noisier_widens_the_interval(heu_run, tmp_path):
    """The interval is where the fit's cost rises by a fixed amount in units of the model's
    sigma: a model that trusts each reading less bounds the box more loosely (in sum: a
    dimension at the resolution floor, half the sub-ray pitch a side widened by the
    misfit's square root where it exceeds 1, may narrow, as the noisier model calls the
    same readings explained). `estimation:` settings reach the estimate the same way: a
    higher level bounds no dimension more tightly. The episode's first four poses: the
    property holds at any number."""
    first = ("--poses", "4")
    _, (own,) = _refit(tmp_path, heu_run, *first)
    code, (noisy,) = _refit(tmp_path, heu_run, *first, "--scenario-text",
                            "{sensor: {sigma0_mm: 40.0}}")
    assert code == 0
    width = [np.subtract(r["estimated_box"]["dims_upper"], r["estimated_box"]["dims_lower"])
             for r in (own, noisy)]
    assert width[1].sum() > width[0].sum()
    code, (wider,) = _refit(tmp_path, heu_run, *first, "--scenario-text",
                            "{estimation: {interval_level: 20.0}}")
    assert code == 0
    width.append(np.subtract(wider["estimated_box"]["dims_upper"],
                             wider["estimated_box"]["dims_lower"]))
    assert np.all(width[2] >= width[0] - 1e-9) and width[2].sum() > width[0].sum()


def test_frames_that_do_not_match_the_report_are_refused_and_nothing_is_written(
        heu_run, tmp_path, capsys):
    folder = tmp_path / "cut"
    shutil.copytree(heu_run, folder)
    with np.load(folder / "frames.npz") as data:
        arrays = {key: data[key][:3] for key in data.files}
    np.savez(folder / "frames.npz", **arrays)
    code, written = _refit(tmp_path, heu_run, folder)  # the good one first: nothing either
    assert code == 2 and written is None
    assert f"{folder / 'frames.npz'}: 3 frames, but" in capsys.readouterr().err


def test_a_missing_file_is_named(tmp_path, capsys):
    (tmp_path / "report.json").write_text("{}")
    code, written = _refit(tmp_path, tmp_path)
    assert code == 2 and written is None
    assert f"{tmp_path / 'frames.npz'}: no such file" in capsys.readouterr().err


def test_an_episode_that_found_no_object_gives_no_box(heu_run, tmp_path, capsys):
    """The episode's map is rebuilt from its frames with its own extraction: looked for
    where nothing stands, it finds no object, so no box either."""
    folder = tmp_path / "none"
    shutil.copytree(heu_run, folder)
    report = json.loads((folder / "report.json").read_text())
    report["scenario"] = report["scenario"].replace("center: [0.5, 0.0]", "center: [0.0, 0.5]")
    (folder / "report.json").write_text(json.dumps(report))
    code, (result,) = _refit(tmp_path, folder)
    assert code == 1 and result["estimated_box"] is None and result["container"] is None
    assert "no object found" in capsys.readouterr().out


def test_extraction_settings_given_to_the_refit_rebuild_the_cell_boxes(heu_run, tmp_path,
                                                                      capsys):
    """The same search as above, given on the command line instead of in the episode's
    scenario: the cell boxes are the map's under the refit's settings, so no object is found."""
    code, (result,) = _refit(tmp_path, heu_run, "--scenario-text",
                             "{extraction: {center: [0.0, 0.5]}}")
    assert code == 1 and result["estimated_box"] is None and result["container"] is None
    assert "no object found" in capsys.readouterr().out


@pytest.mark.parametrize("n", [2, 7, 12])
def test_the_first_poses_give_what_the_episode_had_after_them(heu_run, tmp_path, n):
    """The first n frames, their map rebuilt offline, give the estimate the episode had
    after its n-th pose: the one its poses-to-accuracy metric recorded."""
    code, (result,) = _refit(tmp_path, heu_run, "--poses", n)
    report = json.loads((heu_run / "report.json").read_text())
    assert report["n_poses"] > n
    assert code == 0 and result["n_poses"] == n
    assert result["dim_errors_mm"] == report["metrics"]["dim_errors_after_each_pose_mm"][n - 1]
    assert result["reported_box"] is None  # the episode reported its whole box, not this one


def test_more_poses_than_the_episode_has_are_refused_and_nothing_is_written(
        heu_run, tmp_path, capsys):
    n = json.loads((heu_run / "report.json").read_text())["n_poses"]
    code, written = _refit(tmp_path, heu_run, "--poses", n + 1)
    assert code == 2 and written is None
    assert f"{heu_run}: cannot take its first {n + 1} poses, it has {n}" in \
        capsys.readouterr().err


def test_a_commissioned_mount_moves_every_recorded_pose_to_it(heu_run, tmp_path):
    from lrnbv_drake.core.robot.poses import offset_transform
    from lrnbv_drake.experiments.refit import load_episode, remounted
    from lrnbv_drake.station.scenario import MountOffset

    readings = load_episode(heu_run).readings
    cad, turned = MountOffset(), MountOffset(xyz_mm=[0.0, 0.0, 10.0], rpy_deg=[0.0, 0.0, 90.0])
    moved = remounted(readings, cad, turned)
    # Hand-worked: 10 mm out along the optical axis and a quarter turn about it.
    for (frame, X), (same, Y) in zip(readings, moved, strict=True):
        assert same is frame
        np.testing.assert_allclose(Y[:3, 3], X[:3, 3] + 0.01 * X[:3, 2], atol=1e-12)
        np.testing.assert_allclose(Y[:3, :3], X[:3, :3] @ offset_transform([0, 0, 0],
                                                                           [0, 0, 90])[:3, :3])
    back = remounted(moved, turned, cad)
    np.testing.assert_allclose([X for _, X in back], [X for _, X in readings], atol=1e-12)
    # refit takes it: the episode's first four readings under a mount 3 degrees off fit
    # worse (four: a mount the readings reject sends every pose's estimate into a cold search).
    _, (own,) = _refit(tmp_path, heu_run, "--poses", 4)
    _, (tilted,) = _refit(tmp_path, heu_run, "--poses", 4, "--scenario-text",
                          "{sensor: {mount: {rpy_deg: [3.0, 0.0, 0.0]}}}")
    assert max(map(abs, tilted["dim_errors_mm"])) > max(map(abs, own["dim_errors_mm"])) + 2
