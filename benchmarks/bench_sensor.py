"""Milliseconds per simulated VL53L8CX frame: render + reduction, and each alone; and the
`datasheet` device's reduction (core/sensing/tof_device.py) against the ideal one in the same run.

The scene is a tabletop one as the NBV loop sees it: a table, a box on it 0.3-0.5 m from the
sensor, and a wall behind, viewed from 0.4 m above the table looking down 45 degrees. Target:
under 15 ms per frame on 2 cores.

    .venv/bin/python benchmarks/bench_sensor.py [--frames 200] [--subsamples 8]
"""

from __future__ import annotations

import argparse
import os
import shlex
import sys
import time
from collections.abc import Callable

import numpy as np
from pydrake.geometry import Box
from pydrake.math import RigidTransform, RollPitchYaw
from pydrake.multibody.plant import AddMultibodyPlantSceneGraph
from pydrake.systems.analysis import Simulator
from pydrake.systems.framework import DiagramBuilder

from lrnbv_drake.core.sensing.sensor import SensorModelParams, frame_rng, zone_readings
from lrnbv_drake.core.sensing.tof_device import PROFILES, device_readings, illumination_weight
from lrnbv_drake.systems.tof_sensor import ToFSensor, add_tof_renderer, sample_zone_depths

# Sensor 0.4 m above the table top, optical axis pitched 45 degrees down towards +x.
X_WS = RigidTransform(RollPitchYaw(-np.pi / 2 - np.pi / 4, 0.0, -np.pi / 2), [0.0, 0.0, 0.4])
# (size, centre) in the world frame: table (top at z = 0), a box on it, a wall behind.
SCENE = [
    ((1.2, 0.8, 0.05), (0.4, 0.0, -0.025)),
    ((0.15, 0.10, 0.12), (0.35, 0.02, 0.06)),
    ((0.05, 2.0, 1.5), (1.1, 0.0, 0.75)),
]


def _median_ms(fn: Callable[[int], object], frames: int) -> float:
    times = []
    for n in range(frames):
        start = time.perf_counter()
        fn(n + 1)
        times.append(time.perf_counter() - start)
    return 1e3 * float(np.median(times))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", type=int, default=200)
    parser.add_argument("--subsamples", type=int, default=8, help="sub-samples per zone side")
    args = parser.parse_args()

    params = SensorModelParams(subsamples=args.subsamples)
    builder = DiagramBuilder()
    plant, scene_graph = AddMultibodyPlantSceneGraph(builder, time_step=0.0)
    for i, (size, centre) in enumerate(SCENE):
        plant.RegisterVisualGeometry(
            plant.world_body(), RigidTransform(centre), Box(*size), f"box{i}", [0.8, 0.8, 0.8, 1]
        )
    plant.Finalize()
    add_tof_renderer(scene_graph)
    dut = builder.AddSystem(ToFSensor(scene_graph.world_frame_id(), X_WS, params))
    builder.Connect(scene_graph.get_query_output_port(), dut.get_geometry_query_input_port())
    diagram = builder.Build()
    simulator = Simulator(diagram)
    context = dut.GetMyContextFromRoot(simulator.get_mutable_context())

    query_object = dut.get_geometry_query_input_port().Eval(context)
    camera, world = dut.camera, scene_graph.world_frame_id()
    image = np.asarray(query_object.RenderDepthImage(camera, world, X_WS).data)[:, :, 0]

    def reduce(n: int) -> None:
        sub_depth_m = sample_zone_depths(image, camera, params)
        zone_readings(sub_depth_m, params, frame_rng(0, n), n)

    datasheet = PROFILES["datasheet"].behaviour
    angles = params.geometry.sub_angles_xy_rad(params.subsamples)
    weight = illumination_weight(angles[..., 0], angles[..., 1])
    rho = np.full(weight.shape, 0.5)

    def reduce_datasheet(n: int) -> None:
        sub_depth_m = sample_zone_depths(image, camera, params)
        device_readings(sub_depth_m, params, datasheet, frame_rng(0, n), reflectance=rho,
                        weight=weight, sequence=n)

    reduce_datasheet(1)  # compiles the numba kernel
    capture = _median_ms(lambda n: dut.CaptureFrame(context, n), args.frames)
    render = _median_ms(lambda n: query_object.RenderDepthImage(camera, world, X_WS), args.frames)
    reduction = _median_ms(reduce, args.frames)
    reduction_datasheet = _median_ms(reduce_datasheet, args.frames)

    period = 1 / 15
    start = time.perf_counter()
    simulator.AdvanceTo(period * (args.frames - 0.5))
    in_simulator = 1e3 * (time.perf_counter() - start) / args.frames

    frame = dut.get_tof_frame_output_port().Eval(context)
    size = camera.core().intrinsics().width()
    print(f"$ {shlex.join([os.path.relpath(sys.executable), *sys.argv])}")
    print(
        f"VL53L8CX sim, {params.geometry.resolution}x{params.geometry.resolution} zones x "
        f"{params.subsamples}x{params.subsamples} sub-samples, {size}x{size} depth render, "
        f"{os.cpu_count()} cores, median of {args.frames} frames"
    )
    print(f"  frame (render + reduction): {capture:6.2f} ms   target < 15 ms")
    print(f"    render:                   {render:6.2f} ms")
    print(f"    reduction:                {reduction:6.2f} ms")
    print(f"    datasheet reduction:      {reduction_datasheet:6.2f} ms   "
          f"({reduction_datasheet / reduction:.1f}x the ideal one)")
    print(f"  in a Simulator at 15 Hz:    {in_simulator:6.2f} ms per frame (mean)")
    print(
        f"  scene check: {int(frame.valid.sum())}/{frame.valid.size} zones valid, "
        f"{frame.distance_mm[frame.valid].min()}-{frame.distance_mm[frame.valid].max()} mm"
    )


if __name__ == "__main__":
    main()
