"""The simulated VL53L8CX: renders a depth image through SceneGraph and reduces it to the frame
the device would report.

The reduction (nearest sizeable surface per zone, noise, status) lives in the Drake-free
`lrnbv_drake.core.sensor`; this module only produces its input, a (res, res, k, k) grid of
perpendicular depths sampled evenly in angle over each zone's footprint, from one
`QueryObject.RenderDepthImage` call (docs/sensor-model.md).

How a closed loop gets frames: `ToFSensor` captures every `period` (15 Hz, the device's 8x8
maximum) on its own, like the real board streaming, and stamps each frame with a sequence number
and the simulation time. A driver that waits for the arm to settle keeps the frames whose
timestamp is at least one period after the stop, exactly as it does with the serial stream
(notes 2.2). A driver that wants a frame now, outside the periodic schedule, calls
`ToFSensor.CaptureFrame(context)`, which renders from the context's current poses and returns the
frame without touching state.
"""

from __future__ import annotations

import numpy as np
from pydrake.common.value import AbstractValue
from pydrake.geometry import (
    ClippingRange,
    DepthRange,
    DepthRenderCamera,
    FrameId,
    MakeRenderEngineVtk,
    QueryObject,
    RenderCameraCore,
    RenderEngineVtkParams,
    SceneGraph,
)
from pydrake.math import RigidTransform
from pydrake.systems.framework import Context, InputPort, LeafSystem, OutputPort, State
from pydrake.systems.sensors import CameraInfo

from lrnbv_drake.core.sensor import SensorModelParams, ToFFrame, frame_rng, zone_readings

#: Near clipping plane and minimum depth, metres: geometry closer than 5 mm to the sensor is not
#: rendered. The device's own 20 mm minimum is applied by the sensor model, not here.
_NEAR_M = 0.005


def add_tof_renderer(scene_graph: SceneGraph, name: str = "vtk") -> None:
    """Adds a headless VTK renderer (EGL on Linux) under `name` unless one already exists.

    Call before building the diagram. Geometry is rendered only if it has the perception role,
    which URDF/SDF visuals and `MultibodyPlant.RegisterVisualGeometry` assign by default.
    """
    if not scene_graph.HasRenderer(name):
        scene_graph.AddRenderer(name, MakeRenderEngineVtk(RenderEngineVtkParams()))


def tof_depth_camera(params: SensorModelParams, renderer_name: str = "vtk") -> DepthRenderCamera:
    """The square pinhole camera the sensor renders with: the zone field of view, z-depth, kTooFar
    (inf) beyond the device's maximum range.

    Pinhole pixels are uniform in tan while zones are uniform in angle, so the image is finer
    than the sub-sample grid: its pixel pitch in angle, coarsest at the centre, is at most half
    a sub-sample pitch. `sample_zone_depths` then takes for every sub-sample the pixel nearest
    its direction, which lies inside the sub-sample's own angular cell (and hence inside its
    zone) even with a half-pixel error in the pixel-centre convention.
    """
    geometry = params.geometry
    half_fov = np.deg2rad(geometry.fov_deg) / 2
    sample_pitch = np.deg2rad(geometry.zone_deg) / params.subsamples
    size = int(np.ceil(4 * np.tan(half_fov) / sample_pitch))
    focal = size / 2 / np.tan(half_fov)
    # Principal point at the image's geometric centre: VTK samples pixel u at u + 0.5 - c
    # (measured; pinned by tests/test_tof_sensor_system.py).
    intrinsics = CameraInfo(size, size, focal, focal, size / 2, size / 2)
    max_m = params.max_range_mm / 1000.0
    core = RenderCameraCore(
        renderer_name, intrinsics, ClippingRange(_NEAR_M, max_m), RigidTransform()
    )
    return DepthRenderCamera(core, DepthRange(_NEAR_M, max_m))


def sample_zone_depths(
    depth_image: np.ndarray, camera: DepthRenderCamera, params: SensorModelParams
) -> np.ndarray:
    """Samples a (height, width) depth image rendered with `camera` at the zone sub-sample
    directions (`ZoneGeometry.sub_directions`), taking the pixel whose centre is nearest each.

    Returns:
        (res, res, k, k) depths in row-major zone order.
    """
    geometry, k = params.geometry, params.subsamples
    tan = np.tan(geometry.sub_angles_rad(k))
    info = camera.core().intrinsics()
    # VTK samples pixel u at tan = (u + 0.5 - center) / focal.
    cols = np.rint(info.center_x() + info.focal_x() * tan - 0.5).astype(np.intp)
    rows = np.rint(info.center_y() + info.focal_y() * tan - 0.5).astype(np.intp)
    depth = depth_image[np.ix_(rows, cols)]
    res = geometry.resolution
    return depth.reshape(res, k, res, k).transpose(0, 2, 1, 3)


def render_zone_depths(
    query_object: QueryObject,
    camera: DepthRenderCamera,
    parent_frame_id: FrameId,
    X_PS: RigidTransform,
    params: SensorModelParams,
) -> np.ndarray:
    """Renders the sensor's view and samples it at the zone sub-sample directions.

    Args:
        query_object: SceneGraph's query (poses of the current context).
        camera: from `tof_depth_camera(params, renderer_name)`.
        parent_frame_id: the SceneGraph frame the sensor is fixed to.
        X_PS: pose of the sensor frame (z optical axis, x right, y down) in that frame.
        params: sensor model.

    Returns:
        (res, res, k, k) perpendicular depths, metres, row-major zones; inf where nothing lies
        within the device's maximum range. Geometry nearer than 5 mm is clipped, i.e. unseen.
    """
    image = query_object.RenderDepthImage(camera, parent_frame_id, X_PS)
    return sample_zone_depths(np.asarray(image.data)[:, :, 0], camera, params)


class ToFSensor(LeafSystem):
    """Simulated VL53L8CX fixed to a SceneGraph frame.

    @system
    name: ToFSensor
    input_ports:
    - geometry_query
    output_ports:
    - tof_frame
    @endsystem

    `geometry_query` connects to `scene_graph.get_query_output_port()`; the SceneGraph needs the
    renderer named `renderer_name` (`add_tof_renderer`). `tof_frame` is the last captured
    `ToFFrame`, in the geometry's raw zone order. Until the first capture (the periodic event
    at t = 0) it is an empty frame with sequence 0: consumers must skip sequence 0.

    Frame n (sequence n) draws its noise from `frame_rng(seed, n)`, so a seed and a scene
    reproduce the same frames whatever else the diagram does.
    """

    def __init__(
        self,
        parent_frame_id: FrameId,
        X_PS: RigidTransform,
        params: SensorModelParams | None = None,
        *,
        renderer_name: str = "vtk",
        seed: int = 0,
        period: float = 1 / 15,
    ) -> None:
        """
        Args:
            parent_frame_id: SceneGraph frame of the body carrying the sensor (e.g.
                `plant.GetBodyFrameIdOrThrow(body.index())`, or `scene_graph.world_frame_id()`).
            X_PS: pose of the sensor frame `tof` (z optical axis, x right, y down) in it.
            params: sensor model (defaults: `SensorModelParams()`).
            renderer_name: SceneGraph renderer to use.
            seed: noise seed, >= 0.
            period: capture period, seconds (1/15: 8x8 mode at its maximum rate).
        """
        super().__init__()
        if seed < 0:
            raise ValueError(f"seed must be >= 0; got {seed}")
        self._parent_frame_id = parent_frame_id
        self._X_PS = RigidTransform(X_PS)
        self._params = params if params is not None else SensorModelParams()
        self._seed = seed
        self._camera = tof_depth_camera(self._params, renderer_name)

        self._query_port = self.DeclareAbstractInputPort(
            "geometry_query", AbstractValue.Make(QueryObject())
        )
        empty = ToFFrame.empty(self._params.geometry.resolution)
        self._frame_index = self.DeclareAbstractState(AbstractValue.Make(empty))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period, 0.0, self._Capture)
        self._frame_port = self.DeclareStateOutputPort("tof_frame", self._frame_index)

    @property
    def params(self) -> SensorModelParams:
        """The sensor model this sensor simulates."""
        return self._params

    @property
    def camera(self) -> DepthRenderCamera:
        """The depth camera it renders with (`tof_depth_camera`)."""
        return self._camera

    def get_geometry_query_input_port(self) -> InputPort:
        return self._query_port

    def get_tof_frame_output_port(self) -> OutputPort:
        return self._frame_port

    def CaptureFrame(self, context: Context, sequence: int | None = None) -> ToFFrame:
        """Captures a frame from the poses in `context` without changing its state.

        Args:
            context: this system's context.
            sequence: number to stamp and seed the noise with; by default the one after the
                frame in state, i.e. what the next periodic capture would produce.
        """
        if sequence is None:
            sequence = self._frame_port.Eval(context).sequence + 1
        sub_depth_m = render_zone_depths(
            self._query_port.Eval(context),
            self._camera,
            self._parent_frame_id,
            self._X_PS,
            self._params,
        )
        return zone_readings(
            sub_depth_m,
            self._params,
            frame_rng(self._seed, sequence),
            sequence=sequence,
            timestamp_us=round(context.get_time() * 1e6),
        )

    def _Capture(self, context: Context, state: State) -> None:
        state.get_mutable_abstract_state(self._frame_index).set_value(self.CaptureFrame(context))
