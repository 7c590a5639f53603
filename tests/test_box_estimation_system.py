"""`BoxEstimation` alone (systems/box_estimation.py): it folds in an acquisition once the
loop has logged the extraction after it, and gives the same track however often asked."""

import numpy as np
from rendered_views import render

from lrnbv_drake.core.acquisition import Acquisition, EpisodeLog
from lrnbv_drake.core.estimation.estimator import ShapeEstimator
from lrnbv_drake.core.estimation.track import EpisodeEstimator
from lrnbv_drake.core.mapping.extraction import ExtractionResult, ExtractionStatus
from lrnbv_drake.station.parts import sensor_behaviour
from lrnbv_drake.station.scenario import Scenario
from lrnbv_drake.systems.box_estimation import BoxEstimation


def _found(box) -> ExtractionResult:
    return ExtractionResult(ExtractionStatus.FOUND, "found", np.zeros(0, int), 1,
                            oriented_box=box)


def test_it_estimates_each_acquisition_once_its_extraction_is_logged():
    frames, truth, model = render("{object: {name: vertical_box}}")
    scenario = Scenario()
    dut = BoxEstimation(EpisodeEstimator(ShapeEstimator(
        model, sensor_behaviour(scenario), 0.0, tuple(scenario.cell.table_extent))))
    context = dut.CreateDefaultContext()
    log = EpisodeLog()
    port = dut.get_input_port(0)
    start = _found(type(truth)(truth.center, truth.dims + 0.02, truth.yaw))
    for i, (frame, X_WS) in enumerate(frames[:4]):
        log.acquisitions.append(Acquisition(i, float(i), np.zeros(6), X_WS, frame))
        port.FixValue(context, log)
        # Not before the loop has logged the extraction after it.
        assert len(dut.GetOutputPort("box_estimate").Eval(context).estimates) == i
        log.extractions.append(start)
        port.FixValue(context, log)
        track = dut.GetOutputPort("box_estimate").Eval(context)
        assert len(track.estimates) == i + 1 and len(track.seconds) == i + 1
    # Asked again, nothing new is folded in: the very same estimates come back.
    again = dut.GetOutputPort("box_estimate").Eval(context)
    assert all(a is b for a, b in zip(again.estimates, track.estimates, strict=True))
    errors = np.abs(track.latest.box.dims - truth.dims)
    assert np.all(errors < 0.005), errors


def test_the_final_track_folds_in_what_came_after_the_last_extraction():
    frames, truth, _ = render("{object: {name: vertical_box}}")
    dut = BoxEstimation(EpisodeEstimator(None))  # the cell boxes themselves
    context = dut.CreateDefaultContext()
    log = EpisodeLog(acquisitions=[Acquisition(i, float(i), np.zeros(6), X, f)
                                   for i, (f, X) in enumerate(frames[:3])],
                     extractions=[_found(truth)])
    dut.get_input_port(0).FixValue(context, log)
    assert len(dut.made.estimates) == 0  # nothing made until asked
    assert len(dut.GetOutputPort("box_estimate").Eval(context).estimates) == 1
    assert len(dut.made.estimates) == 1
    final = dut.final_track(context)
    assert len(final.estimates) == 3 and dut.made == final
    assert all(e.box is truth and e.widths is None for e in final.estimates)
