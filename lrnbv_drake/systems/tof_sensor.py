"""The simulated VL53L8CX: renders a depth image through SceneGraph and reduces it to the frame
the device would report.

The reduction (nearest sizeable surface per zone, noise, status) lives in the Drake-free
`lrnbv_drake.core.sensing.sensor`; this module only produces its input, a (res, res, k, k) grid of
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

from collections.abc import Callable

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

from lrnbv_drake.core.sensing.sensor import SensorModelParams, ToFFrame, frame_rng
from lrnbv_drake.core.sensing.tof_device import (
    DeviceBehaviour,
    device_readings,
    illumination_weight,
)
from lrnbv_drake.core.sensing.zone_order import (
    check_zone_order,
    reorder_frame,
    restore_frame,
)

#: Relative depth spread over a sample's four pixels above which they straddle an edge: a plane
#: seen 70 degrees from its normal spreads 1.7 % over a pixel of the 8x8 image's centre (0.35
#: degrees), so planes are interpolated up to about 73 degrees.
_SMOOTH_STEP = 0.02
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
    half_fov = geometry.max_angle_rad()
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
    directions (`ZoneGeometry.sub_directions`).

    Each sample interpolates the four pixels around its direction bilinearly in inverse
    depth, which is exact on any plane (a plane's inverse depth is linear in the image), so a
    tilted surface reads its true depth rather than a neighbouring pixel's (up to 1.3 mm off at
    60 degrees of tilt). Where those four pixels straddle a depth step of more than
    `_SMOOTH_STEP`, or one sees nothing, the sample takes the pixel nearest its direction,
    which lies inside its own sub-sample cell: an edge is never blended into a depth no
    surface has.

    Returns:
        (res, res, k, k) depths in row-major zone order.
    """
    tan = np.tan(params.geometry.sub_angles_xy_rad(params.subsamples))
    info = camera.core().intrinsics()
    # VTK samples pixel u at tan = (u + 0.5 - center) / focal.
    u = info.center_x() + info.focal_x() * tan[..., 0] - 0.5
    v = info.center_y() + info.focal_y() * tan[..., 1] - 0.5
    nearest = depth_image[np.rint(v).astype(np.intp), np.rint(u).astype(np.intp)]
    u0 = np.clip(np.floor(u).astype(np.intp), 0, depth_image.shape[1] - 2)
    v0 = np.clip(np.floor(v).astype(np.intp), 0, depth_image.shape[0] - 2)
    fu, fv = u - u0, v - v0
    four = np.stack([depth_image[v0, u0], depth_image[v0, u0 + 1],
                     depth_image[v0 + 1, u0], depth_image[v0 + 1, u0 + 1]])
    with np.errstate(divide="ignore", invalid="ignore"):
        smooth = (np.isfinite(four).all(axis=0) & (four.min(axis=0) > 0)
                  & (four.max(axis=0) <= four.min(axis=0) * (1 + _SMOOTH_STEP)))
        inverse = ((1 - fu) * (1 - fv) / four[0] + fu * (1 - fv) / four[1]
                   + (1 - fu) * fv / four[2] + fu * fv / four[3])
        return np.where(smooth, 1 / inverse, nearest)


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
    `ToFFrame`, in the board's zone order (`zone_order`; by default the model's raw order).
    Until the first capture (the periodic event at t = 0) it is an empty frame with sequence 0:
    consumers must skip sequence 0.

    Frame n (sequence n) draws its noise from `frame_rng(seed, n)`, so a seed and a scene
    reproduce the same frames whatever else the diagram does.

    With `integration_steps` n > 1 the sensor renders n times per frame period and a frame
    reduces the last n renders together, as the device integrates over its whole frame in
    continuous mode: a frame taken while the sensor moves mixes the poses it passed. The first
    frame then comes at (n - 1) / n periods.
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
        behaviour: DeviceBehaviour | None = None,
        reflectance: Callable[[np.ndarray], np.ndarray] | None = None,
        integration_steps: int = 1,
        zone_order: tuple[int, str] = (0, "none"),
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
            behaviour: the device's departures from the model (`core.sensing.tof_device`); the
                default is the ideal device.
            reflectance: reflectance of the surface at world points (n, 3); 0.5 everywhere
                if not given. Only a `behaviour` with `reflectance` uses it.
            integration_steps: renders per frame period that a frame integrates, >= 1.
            zone_order: (rotate, flip) of the board's zone order against the model's
                (`core.sensing.zone_order`); the default reports the model's order.
        """
        super().__init__()
        if seed < 0:
            raise ValueError(f"seed must be >= 0; got {seed}")
        if integration_steps < 1:
            raise ValueError(f"integration_steps must be >= 1; got {integration_steps}")
        self._parent_frame_id = parent_frame_id
        self._X_PS = RigidTransform(X_PS)
        self._params = params if params is not None else SensorModelParams()
        self._behaviour = behaviour if behaviour is not None else DeviceBehaviour()
        self._reflectance = reflectance
        self._steps = integration_steps
        check_zone_order(*zone_order)
        self._zone_order = zone_order
        self._seed = seed
        self._camera = tof_depth_camera(self._params, renderer_name)
        k = self._params.subsamples
        self._directions = self._params.geometry.sub_directions(k)
        angles = self._params.geometry.sub_angles_xy_rad(k)
        self._weight = (illumination_weight(angles[..., 0], angles[..., 1])
                        if self._behaviour.illumination else None)

        self._query_port = self.DeclareAbstractInputPort(
            "geometry_query", AbstractValue.Make(QueryObject())
        )
        empty = ToFFrame.empty(self._params.geometry.resolution)
        self._frame_index = self.DeclareAbstractState(AbstractValue.Make(empty))
        self._renders_index = self.DeclareAbstractState(AbstractValue.Make(()))
        self.DeclarePeriodicUnrestrictedUpdateEvent(period / integration_steps, 0.0,
                                                    self._Capture)
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

    def CaptureFrame(self, context: Context, sequence: int | None = None,
                     previous: ToFFrame | None = None) -> ToFFrame:
        """Captures a frame from the poses in `context` (one render, as if at rest) without
        changing its state.

        Args:
            context: this system's context.
            sequence: number to stamp and seed the noise with; by default the one after the
                frame in state, i.e. what the next periodic capture would produce.
            previous: the frame captured before this one (the device's start-up statuses
                depend on it); by default the frame in state.
        """
        return self._Reduce(context, [self._Render(context)], sequence, previous)

    def _Render(self, context: Context) -> tuple[np.ndarray, np.ndarray | None]:
        """One render: the zone depths and, for a device whose surfaces reflect unalike,
        each sample's reflectance."""
        query = self._query_port.Eval(context)
        depth = render_zone_depths(query, self._camera, self._parent_frame_id, self._X_PS,
                                   self._params)
        if not self._behaviour.reflectance or self._reflectance is None:
            return depth, None
        X_WS = query.GetPoseInWorld(self._parent_frame_id) @ self._X_PS
        with np.errstate(invalid="ignore"):
            p_S = (self._directions * np.where(np.isfinite(depth), depth, 0.0)[..., None])
        p_W = X_WS.multiply(p_S.reshape(-1, 3).T).T
        return depth, np.asarray(self._reflectance(p_W), float).reshape(depth.shape)

    def _Reduce(self, context: Context, renders: list, sequence: int | None,
                previous: ToFFrame | None = None) -> ToFFrame:
        if previous is None:
            previous = self._frame_port.Eval(context)
        if sequence is None:
            sequence = previous.sequence + 1
        res = self._params.geometry.resolution
        depth = (renders[0][0] if len(renders) == 1 else
                 np.concatenate([d.reshape(res, res, -1) for d, _ in renders], axis=-1))
        rho = (None if renders[0][1] is None else
               np.concatenate([r.reshape(res, res, -1) for _, r in renders], axis=-1))
        weight = (None if self._weight is None else
                  np.concatenate([self._weight.reshape(res, res, -1)] * len(renders), axis=-1))
        frame = device_readings(
            depth, self._params, self._behaviour, frame_rng(self._seed, sequence),
            reflectance=rho, weight=weight,
            previous=(restore_frame(previous, *self._zone_order) if previous.sequence > 0
                      else None),
            sequence=sequence, timestamp_us=round(context.get_time() * 1e6))
        return reorder_frame(frame, *self._zone_order)

    def _Capture(self, context: Context, state: State) -> None:
        renders = [*context.get_abstract_state(self._renders_index).get_value(),
                   self._Render(context)]
        if len(renders) < self._steps:
            state.get_mutable_abstract_state(self._renders_index).set_value(tuple(renders))
            return
        state.get_mutable_abstract_state(self._renders_index).set_value(())
        state.get_mutable_abstract_state(self._frame_index).set_value(
            self._Reduce(context, renders, None))
