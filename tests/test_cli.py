"""`lrnbv` end to end: a whole simulated HEU episode and its outputs."""

import json

import numpy as np
import pytest
import trimesh

from lrnbv_drake.cli.main import main
from lrnbv_drake.core.evaluation import objects
from lrnbv_drake.core.sensing.sensor import ToFFrame, ZoneGeometry
from lrnbv_drake.station.cell_models import place_object
from lrnbv_drake.station.scenario import Scenario


def _world_points(frames):
    geometry = ZoneGeometry()
    points = []
    for d, s, g, X in zip(frames["distance_mm"], frames["status"], frames["sigma_mm"],
                          frames["X_WS"], strict=True):
        p, valid = geometry.points(ToFFrame(d, s, g))
        points.append(p[valid] @ X[:3, :3].T + X[:3, 3])
    return np.concatenate(points)


def _distance_to_box_surface(points, lower, upper):
    center, half = (lower + upper) / 2, (upper - lower) / 2
    q = np.abs(points - center) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(np.max(q, axis=1), 0.0)
    return np.abs(outside + inside)


def test_run_writes_thirteen_frames_that_agree_with_the_scene(heu_run):
    frames = np.load(heu_run / "frames.npz")
    report = json.loads((heu_run / "report.json").read_text())
    assert report["n_poses"] == 13 == len(frames["X_WS"])
    assert report["termination"] == "visited the 13 ellipse poses"
    # report.json may round to 1 nm: frames.npz keeps the poses exactly.
    np.testing.assert_allclose(frames["X_WS"], [p["X_WS"] for p in report["poses"]], atol=1e-9)
    # Each pose looks at the object's centre from the ellipse.
    center = place_object(Scenario()).mesh.bounds.mean(axis=0)
    for X in frames["X_WS"]:
        to_center = (center - X[:3, 3]) / np.linalg.norm(center - X[:3, 3])
        np.testing.assert_allclose(X[:3, 2], to_center, atol=1e-6)
    # A zone that sees one surface puts its point on it, within noise and the footprint's
    # spread; one that sees the box's edge and the table reads their merged depth, so its
    # point lies between the two, never below the table nor above the box.
    points = _world_points(frames)
    assert len(points) > 13 * 48
    lower, upper = place_object(Scenario()).mesh.bounds  # the box lies axis-aligned
    to_object = _distance_to_box_surface(points, lower, upper)
    to_surface = np.minimum(np.abs(points[:, 2]), to_object)
    assert np.mean(to_surface < 0.02) > 0.8
    assert np.all((points[:, 2] > -0.02) & (points[:, 2] < upper[2] + 0.02))
    assert np.mean(to_object < 0.02) > 0.3  # and a good share of them are on the object


def test_replay_is_a_self_contained_page(heu_run):
    html = (heu_run / "replay.html").read_text()
    assert "<html" in html[:1000].lower()
    assert "data:application/octet-binary;base64" in html  # the recorded animation is inlined
    assert len(html) > 500_000  # the robot, scene and 13 frames' rays and points


def test_same_seed_same_run_other_seed_other_noise(heu_run, tmp_path):
    assert main(["run", "--planner", "heu", "--object", "horizontal_box", "--seed", "3",
                 "--out", str(tmp_path / "a")]) == 0
    # The other seed's first three poses are enough to tell its noise from the same poses.
    assert main(["run", "--planner", "heu", "--object", "horizontal_box", "--seed", "4",
                 "--scenario-text", "{max_poses: 3}", "--out", str(tmp_path / "b")]) == 0
    ref, same, other = (np.load(p / "frames.npz") for p in (heu_run, tmp_path / "a",
                                                             tmp_path / "b"))
    for key in ref.files:
        np.testing.assert_array_equal(ref[key], same[key])
    assert len(other["X_WS"]) == 3
    assert not np.array_equal(ref["distance_mm"][:3], other["distance_mm"])
    np.testing.assert_allclose(ref["X_WS"][:3], other["X_WS"])  # the poses do not depend on noise


def test_objects_lists_the_paper_objects(capsys):
    assert main(["objects"]) == 0
    out = capsys.readouterr().out
    for name in objects.PAPER_OBJECTS:
        assert name in out


def test_bad_inputs_fail_with_a_named_reason(tmp_path, capsys):
    assert main(["run", "--object", "teapot", "--out", str(tmp_path)]) == 2
    assert "unknown object 'teapot'" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text("sensor: {subsamples: many}\n")
    assert main(["run", "--scenario", str(bad), "--out", str(tmp_path)]) == 2
    assert "'sensor.subsamples'" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["run", "--object-pose", "1,2", "--out", str(tmp_path)])
    assert "expected x,y,yaw" in capsys.readouterr().err


def test_user_mesh_with_scale_and_pose(tmp_path):
    mesh = trimesh.creation.box(extents=(100.0, 60.0, 40.0))  # millimetres
    path = tmp_path / "part.stl"
    mesh.export(path)
    out = tmp_path / "run"
    assert main(["run", "--planner", "heu", "--object", str(path), "--object-scale", "0.001",
                 "--object-pose", "0.48,0.05,30", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["object"] == str(path)
    assert report["object_pose"] == [0.48, 0.05, 30.0]
    points = _world_points(np.load(out / "frames.npz"))
    on_part = points[points[:, 2] > 0.02]
    assert len(on_part) > 0
    assert np.all(on_part[:, 2] < 0.04 + 0.02)  # nothing measured above the 4 cm part


def test_compare_reads_two_campaign_folders_and_refuses_a_folder_without_results(
        tmp_path, capsys):
    """The same episode 3.0 mm off before, 1.0 mm after: one pair, lower by 2 mm."""
    for name, error in (("before", "0.003"), ("after", "0.001")):
        (tmp_path / name).mkdir()
        (tmp_path / name / "results.csv").write_text(
            f"planner,object,trial,worst_err\nlrnbv,can,0,{error}\n")
    assert main(["compare", str(tmp_path / "before"), str(tmp_path / "after"),
                 "--metrics", "worst_err"]) == 0
    assert "| lrnbv | worst_err (mm) | 1 | 3.0 -> 1.0 |" in capsys.readouterr().out
    assert main(["compare", str(tmp_path / "before"), str(tmp_path)]) == 2
    assert f"{tmp_path / 'results.csv'}: cannot read it" in capsys.readouterr().err

