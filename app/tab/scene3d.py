"""The tab's 3-D scene: typed handles of every node, and the drawing of a pair, its overlap and the path.

The target sits still; the source is one frame node (``/source``) whose pose is the registration's:
a run moves it by that node's pose, never by re-sending points. Each cloud is drawn twice: all its
points, and a fixed subset shown while a run moves the scan (the page redraws on every pose push;
software WebGL draws ~0.4 M points/s on 2 cores: RUN_POINTS). The frustum wireframes and the surfaces are in the
scene only while shown: a hidden node still cost the software-rendered page (bunny pair, Chromium with
software WebGL, load ~9 on 2 cores: 350-500 ms of CPU a frame with them hidden in the scene, 110-180
ms with them removed).
"""

from __future__ import annotations

import threading
from dataclasses import dataclass, field

import numpy as np
import viser
from rangereg.app.figures import (
    MINIMUM_RGB,
    MODEL_RGB,
    SOURCE_OVERLAP_RGB,
    SOURCE_RGB,
    TARGET_OVERLAP_RGB,
    TARGET_RGB,
    faded,
)
from rangereg.app.tab.state import TabState
from rangereg.app.views import Display
from rangereg.core.scan import ScanKind

RUN_POINTS = 1500  # while a run moves the scan, each cloud is drawn with at most this many points: software
# WebGL pays per point, hardly per pixel of a point (bunny pair, 1400 x 900 page, no run: 11-14 frames a second
# with 2 x 6,000 points, 16-18 with 2 x 2,000, 19-21 with none; points drawn 2 x larger: no change). During a
# run the page has one core: benchmarks/workbench_rate.py, docked panel: 2 x 2,000: 9.2-10.8 updates a second,
# 2 x 1,500: 9.6-11.2 (median 11.2, three runs each, load 2-4)
DRAW_POINTS = 100_000  # at rest each cloud is drawn with at most this many points (a seeded subset; registration,
# picks and exports use every point): an object scan (the bunny's ~40k) is drawn whole, a Kinect frame (~250k) or a
# fused fragment (~300k) is not sent and drawn whole in a browser without a GPU
SENSOR_AXES = 0.04  # page units (the target's size is 1): a panorama's sensor marker, its frame's axes
LIGHT_SIZE_MAX = 3.0  # the subset's points are drawn sqrt(N / RUN_POINTS) times larger (its spacing), at most this
# (chosen by eye on screenshots of the bunny page: 2.5-3 x reads as the surface, larger as blobs; size costs nothing)
AMBIENT = 1.0  # the ambient light's intensity, in place of the environment map's fill (set_lights; chosen by eye on
# the terrain, the residual colours and the merged model: no face goes black)
MARKER = 0.02  # page units (the target's size is 1): the local minima's markers, the same on every scene (a point's
# spacing made them vanish on the bunny and blot the corner)
VIEW_DIRECTION = (0.55, 0.45, 1.0)  # Fit view looks from here (normalised) when the camera has no direction yet
FIT_MARGIN = 1.1  # Fit view leaves this much room round what it frames
FRUSTUM_THICKNESS = 1.0  # screen pixels, in a pale version of the scan's colour (figures.faded): a frustum is
# context, the scans are content; drawn 1.5 px in the scan's own colour, the bunny's two frustums (hundreds of
# lines each, reaching far beyond the scans) were most of what the default view showed
DEFAULT_FOV, DEFAULT_ASPECT = np.radians(75.0), 1.1  # the opening camera's (viser's default vertical field of view,
# three.js's, as the browser reports it; framed for 50 degrees, the opening views drew the scans 1.6 times smaller than
# meant; the canvas beside the docked panel: 1116 x 1000 px at a 1600 x 1000 page)
GIZMO_SHARE = 0.15  # the gizmo's size, a share of the diagonal of the scans' box: its handles reach a sixth of the way
# across the scans the opening view frames (a fixed 0.3 page units, 0.29 of the bunny pair's diagonal, drew handles
# half the bunny's height across from the closer opening view); still a 40-80 px handle to grab at 1280 x 720
VIEW_ELEVATION = np.radians(20.0)  # the opening view looks down on the scans this much
EMPTY_SEGMENTS = np.zeros((0, 2, 3), np.float32)
EMPTY_POINTS = np.zeros((0, 3), np.float32)


@dataclass(eq=False)
class CloudNodes:
    """One scan's nodes: all points, the light subset drawn during a run (with its indices), the viewpoint; and
    the frustum (segments (S, 2, 3)) and the surface (vertices, faces), whose nodes exist only while shown."""

    root: str
    colour: tuple[int, int, int]
    points: viser.PointCloudHandle
    light: viser.PointCloudHandle | None
    light_index: np.ndarray | None
    viewpoint: viser.IcosphereHandle
    frustum_segments: np.ndarray
    surface_mesh: tuple[np.ndarray, np.ndarray]
    drawn_index: np.ndarray | None = None  # the points drawn at rest (None: all; DRAW_POINTS)
    frustum: viser.LineSegmentsHandle | None = None
    surface: viser.MeshHandle | None = None

    def show_frustum(self, scene, shown: bool) -> None:
        if shown and self.frustum is None:
            self.frustum = scene.add_line_segments(f"{self.root}/frustum", self.frustum_segments, faded(self.colour),
                                                   thickness=FRUSTUM_THICKNESS, thickness_units="screen")
        elif not shown and self.frustum is not None:
            self.frustum.remove()
            self.frustum = None

    def show_surface(self, scene, shown: bool) -> None:
        if shown and self.surface is None:
            self.surface = scene.add_mesh_simple(f"{self.root}/surface", *self.surface_mesh, color=self.colour,
                                                 opacity=0.6, side="double", cast_shadow=False, receive_shadow=False)
        elif not shown and self.surface is not None:
            self.surface.remove()
            self.surface = None


@dataclass(eq=False)
class SceneNodes:
    source_frame: viser.FrameHandle
    source: CloudNodes
    target: CloudNodes
    gizmo: viser.TransformControlsHandle
    path: viser.LineSegmentsHandle
    minima: viser.PointCloudHandle
    model: viser.MeshHandle | None = None
    model_corners: np.ndarray | None = None  # (8, 3) page points: the drawn model's box (what Fit view frames)
    drawn: int = 0  # models and pick markers drawn so far: each gets a name of its own (see pair_root)
    shown_lock: threading.Lock = field(default_factory=threading.Lock)  # adds/removes frustums and surfaces (the
    # refresher and callback threads both set what is shown)

    def remove(self) -> None:
        for node in (self.source_frame, self.gizmo, self.path, self.minima, self.model, self.target.points,
                     self.target.light, self.target.frustum, self.target.surface, self.target.viewpoint):
            if node is not None:
                node.remove()  # the source's own nodes go with their frame


@dataclass(frozen=True)
class Visibility:
    frustums: bool
    overlap: bool
    surfaces: bool
    path: bool
    model: bool
    gizmo: bool = True  # False while a run holds the scans, the model is shown or point pairs are picked


def colours(state: TabState, which: str, overlap: bool) -> np.ndarray:
    """(N, 3) uint8 per-point colours of the source or target: the overlap points highlighted when shown."""
    src = which == "source"
    if src and state.residual_rgb is not None:
        return state.residual_rgb
    scan = state.source if src else state.target
    rgb = np.empty((len(scan.points), 3), np.uint8)
    rgb[:] = SOURCE_RGB if src else TARGET_RGB
    p = state.problem
    if p is not None and overlap and p.source is state.source and p.target is state.target:
        rgb[p.used if src else p.overlap.target_mask] = SOURCE_OVERLAP_RGB if src else TARGET_OVERLAP_RGB
    return rgb


def _cloud(scene, state: TabState, which: str, pts: np.ndarray, size: float, frustum_kind: str,
           overlap: bool) -> CloudNodes:
    d = state.display
    src = which == "source"
    root, rgb, base = f"{pair_root(state)}/{which}", colours(state, which, overlap), SOURCE_RGB if src else TARGET_RGB
    to_page = d.source_local if src else d.points
    drawn = None
    if len(pts) > DRAW_POINTS:
        drawn = np.sort(np.random.default_rng(1).choice(len(pts), DRAW_POINTS, replace=False))
    points = scene.add_point_cloud(f"{root}/points", pts if drawn is None else pts[drawn],
                                   rgb if drawn is None else rgb[drawn], point_size=size, precision="float32")
    light = index = None
    if len(pts) > RUN_POINTS:
        index = np.sort(np.random.default_rng(0).choice(len(pts), RUN_POINTS, replace=False))
        # drawn as large as the subset's spacing (up to LIGHT_SIZE_MAX x), so it still reads as a surface
        grow = min(LIGHT_SIZE_MAX, float(np.sqrt(len(pts) / RUN_POINTS)))
        light = scene.add_point_cloud(f"{root}/points_run", pts[index], rgb[index], point_size=grow * size,
                                      precision="float32", point_shading="flat", visible=False)
    f = state.frusta[frustum_kind][0 if src else 1]
    scan, surface = (state.source, state.surfaces[0]) if src else (state.target, state.surfaces[1])
    vp = scene.add_icosphere(f"{root}/viewpoint", radius=0.015, color=base, position=to_page(scan.viewpoint))
    if scan.kind is ScanKind.PANORAMA:  # no frustum to show where it stood: the sensor's own axes, named
        scene.add_frame(f"{root}/viewpoint/axes", axes_length=SENSOR_AXES, axes_radius=SENSOR_AXES / 12,
                        origin_radius=0.0)
        scene.add_label(f"{root}/viewpoint/label", f"{which} sensor", position=(0.0, 0.0, 1.5 * SENSOR_AXES),
                        anchor="bottom-center")
    cloud = CloudNodes(root, base, points, light, index, vp, to_page(f.wireframe().reshape(-1, 3)).reshape(-1, 2, 3),
                       (to_page(scan.points), surface.faces), drawn_index=drawn)
    cloud.show_frustum(scene, True)
    return cloud


def set_lights(scene) -> None:
    """The scene's lights: viser's two directional lights without shadow maps (they shade nothing a point cloud
    shows, and each frame drew three of them in software WebGL), no environment map (its image lighting of every
    lit pixel, the terrain, surfaces and model, held a software-rendered page with the 3-D terrain shown to ~6.6
    updates a second, 8.7 without: bunny SA run, alternating, load 3-4; and it washed out the terrain's colour
    scale), and an ambient light for the fill the map gave."""
    scene.configure_default_lights(True, cast_shadow=False)
    scene.configure_environment_map(hdri=None)
    scene.add_light_ambient("/ambient", intensity=AMBIENT)


def pair_root(state: TabState) -> str:
    """The scene path every node of the open pair hangs under, new for each pair: viser coalesces a Remove and a
    Create of one name in one message batch into the Create alone, and a browser that still held the old node kept
    its pose (a second pair opened on a tab was drawn at the first pair's source pose, off its picks)."""
    return f"/pair{state.pair}"


def draw_pair(client: viser.ClientHandle, state: TabState, frustum_kind: str, overlap: bool) -> SceneNodes:
    """Every node of the pair in ``state`` (call inside ``client.atomic()``), under :func:`pair_root`."""
    d, src, tgt, scene = state.display, state.source, state.target, client.scene
    size = 0.8 * min(src.spacing, tgt.spacing) / d.size
    scene.set_up_direction("+y")
    set_lights(scene)
    wxyz, pos = d.node_pose(state.T)
    root = pair_root(state)
    frame = scene.add_frame(f"{root}/source", show_axes=False, wxyz=wxyz, position=pos)
    target = _cloud(scene, state, "target", d.points(tgt.points), size, frustum_kind, overlap)
    source = _cloud(scene, state, "source", d.source_local(src.points), size, frustum_kind, overlap)
    gizmo = scene.add_transform_controls(f"{root}/gizmo", scale=gizmo_scale(d, tgt, src, state.T), wxyz=wxyz,
                                         position=pos, depth_test=False, translation_limits=((-1e6, 1e6),) * 3)
    path = scene.add_line_segments(f"{root}/path", EMPTY_SEGMENTS, (0, 0, 0), thickness=3.0, thickness_units="screen")
    minima = scene.add_point_cloud(f"{root}/minima", EMPTY_POINTS, MINIMUM_RGB, point_size=MARKER, precision="float32",
                                   point_shape="circle")
    eye, look_at = default_view(d, tgt, src, state.T, state.frusta[frustum_kind])
    client.camera.position = tuple(eye)
    client.camera.look_at = tuple(look_at)
    # the up direction last: set before the position and look-at, the browser kept the camera's up it had (+x, from
    # viser's opening pose), and the page showed the scans on their side
    client.camera.up_direction = UP
    return SceneNodes(frame, source, target, gizmo, path, minima)


def gizmo_scale(d: Display, target, source, T: np.ndarray) -> float:
    """The gizmo's size (page units): GIZMO_SHARE of the diagonal of the scans' box at pose ``T``."""
    extent = pair_extent(d, target, source, T)
    return GIZMO_SHARE * float(np.linalg.norm(extent.max(0) - extent.min(0)))


def redraw_frustums(scene, nodes: SceneNodes, state: TabState, kind: str) -> None:
    d = state.display
    for cloud, f, to_page in ((nodes.source, state.frusta[kind][0], d.source_local),
                              (nodes.target, state.frusta[kind][1], d.points)):
        segments = to_page(f.wireframe().reshape(-1, 3)).reshape(-1, 2, 3)
        with nodes.shown_lock:
            cloud.frustum_segments = segments
            if cloud.frustum is not None:
                cloud.frustum.points = segments


def recolour(nodes: SceneNodes, state: TabState, overlap: bool) -> None:
    """New colours only: the points stay where they are on the page."""
    for which, cloud in (("target", nodes.target), ("source", nodes.source)):
        rgb = colours(state, which, overlap)
        cloud.points.colors = rgb if cloud.drawn_index is None else rgb[cloud.drawn_index]
        if cloud.light is not None:
            cloud.light.colors = rgb[cloud.light_index]


def model_on_page(vertices: np.ndarray, display: Display | None) -> np.ndarray:
    """(V, 3) float32 page points of a model's vertices (V, 3). ``display``: the pair's, for a model in the target's
    frame (the pair fused at the shown pose); None for a model in a frame of its own (a campaign's, in its reference
    scan's frame and units, which need not be the open pair's): it is drawn the way a pair is, its box centred on the
    page's origin and its diagonal 1."""
    v = np.asarray(vertices, np.float64)
    if display is not None:
        return display.points(v)
    lo, hi = v.min(0), v.max(0)
    return ((v - 0.5 * (lo + hi)) / max(float(np.linalg.norm(hi - lo)), 1e-12)).astype(np.float32)


def show_model(scene, nodes: SceneNodes, vertices: np.ndarray, faces: np.ndarray) -> None:
    """Draw the model: ``vertices`` (V, 3) page points (:func:`model_on_page`), ``faces`` (F, 3)."""
    nodes.drawn += 1  # a new name for each model drawn (see pair_root)
    if nodes.model is not None:
        nodes.model.remove()
    nodes.model = scene.add_mesh_simple(f"{nodes.target.root.rsplit('/', 1)[0]}/model{nodes.drawn}", vertices, faces,
                                        color=MODEL_RGB, side="double")
    nodes.model_corners = _corners(vertices.min(0), vertices.max(0))


def apply_visibility(scene, nodes: SceneNodes, show: Visibility, run_drawing: bool) -> None:
    """Which nodes are drawn; ``run_drawing``: a run moves the scan (light clouds, no frustums)."""
    model = show.model and nodes.model is not None
    nodes.gizmo.visible = show.gizmo and not model
    for cloud in (nodes.source, nodes.target):
        with nodes.shown_lock:
            # frustum wireframes cost a software-rendered page half its frame rate: off while a run draws
            cloud.show_frustum(scene, show.frustums and not model and not run_drawing)
            cloud.show_surface(scene, show.surfaces and not model)
        light = run_drawing and cloud.light is not None
        cloud.points.visible = not model and not light
        cloud.viewpoint.visible = not model
        if cloud.light is not None:
            cloud.light.visible = not model and light
    nodes.path.visible = nodes.minima.visible = show.path
    if nodes.model is not None:
        nodes.model.visible = model


def move_source(nodes: SceneNodes, state: TabState, T: np.ndarray, gizmo: bool = True) -> None:
    wxyz, pos = state.display.node_pose(T)
    nodes.source_frame.wxyz, nodes.source_frame.position = wxyz, pos
    if gizmo:
        nodes.gizmo.wxyz, nodes.gizmo.position = wxyz, pos


def draw_path(nodes: SceneNodes, segments: tuple[np.ndarray, np.ndarray], minima: np.ndarray) -> None:
    """The path's segments and colours ((S, 2, 3) each, from Trail.segments) and its minima ((M, 3), Trail.minima)."""
    nodes.path.points, nodes.path.colors = segments
    nodes.minima.points = minima


def _corners(lo, hi) -> np.ndarray:
    """(8, 3) the corners of the box from ``lo`` (3,) to ``hi`` (3,)."""
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])], np.float64)


def shown_extent(state: TabState, nodes: SceneNodes | None = None) -> np.ndarray:
    """(K, 3) page points that Fit view frames: the model's box while the model is shown (``nodes``), else
    :func:`pair_extent` at the shown pose."""
    if nodes is not None and nodes.model is not None and nodes.model.visible and nodes.model_corners is not None:
        return nodes.model_corners
    return pair_extent(state.display, state.target, state.source, state.T)


def pair_extent(d: Display, target, source, T: np.ndarray) -> np.ndarray:
    """(16, 3) page points: the corners of the target's box and of the source's box at pose ``T`` (the frustums reach
    far beyond the scans and are left out)."""
    tgt, src = target.points, source.points
    lo_t, hi_t = np.percentile(tgt, 1, axis=0), np.percentile(tgt, 99, axis=0)  # spurious returns left out
    lo_s, hi_s = np.percentile(src, 1, axis=0), np.percentile(src, 99, axis=0)
    moved = _corners(lo_s, hi_s) @ T[:3, :3].T + T[:3, 3]
    return np.r_[d.points(_corners(lo_t, hi_t)), d.points(moved)].astype(np.float64)


def fit_distance(points: np.ndarray, way: np.ndarray, fov: float, aspect: float) -> tuple[np.ndarray, float]:
    """(centre (3,), distance): looking along -``way`` (3,) (unit, from the eye's side), the nearest distance from the
    centre of the (K, 3) ``points``' box at which all lie inside the vertical field of view ``fov`` (radians) and the
    horizontal one (``aspect`` times wider), with FIT_MARGIN to spare."""
    centre = 0.5 * (points.min(0) + points.max(0))
    up = np.array([0.0, 1.0, 0.0])
    right = np.cross(up, way)
    if np.linalg.norm(right) < 1e-9:  # looking straight down or up
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    up = np.cross(way, right)
    rel = points - centre
    x, y, toward = np.abs(rel @ right), np.abs(rel @ up), rel @ way
    tan_v = np.tan(fov / 2) / FIT_MARGIN
    tan_h = tan_v * aspect
    return centre, max(float(np.max(toward + np.maximum(x / tan_h, y / tan_v))), 1e-3)


def default_view(d: Display, target, source, T: np.ndarray, frusta, extra: np.ndarray | None = None,
                 aspect: float = DEFAULT_ASPECT) -> tuple[np.ndarray, np.ndarray]:
    """(eye, look_at) page points of the opening view: the scans framed (and the (K, 3) page points ``extra``) in a
    canvas ``aspect`` times as wide as high, from outside both drawn frustums (``frusta``: (source's, target's)),
    looking down VIEW_ELEVATION and from as near the target sensor's side (where its scanned surface faces) as that
    allows."""
    points = pair_extent(d, target, source, T)
    if extra is not None:
        points = np.r_[points, extra]
    sensor = d.points(target.viewpoint).astype(np.float64) - 0.5 * (points.min(0) + points.max(0))
    sensor[1] = 0.0
    sensor = sensor / np.linalg.norm(sensor) if np.linalg.norm(sensor) > 1e-9 else np.array([0.0, 0.0, 1.0])
    best = None
    for turn in np.radians([35, -35, 55, -55, 75, -75, 95, -95, 20, -20, 0, 120, -120, 150, -150, 180]):
        c, s_ = np.cos(turn), np.sin(turn)
        flat = np.array([c * sensor[0] + s_ * sensor[2], 0.0, -s_ * sensor[0] + c * sensor[2]])
        way = np.cos(VIEW_ELEVATION) * flat + np.array([0.0, np.sin(VIEW_ELEVATION), 0.0])
        centre, distance = fit_distance(points, way, DEFAULT_FOV, aspect)
        eye = centre + distance * way
        if not _inside_frusta(eye, d, T, frusta):
            return eye, centre
        best = best or (eye, centre)
    return best  # inside a frustum from every side (a panorama's): the first of them


def _inside_frusta(eye: np.ndarray, d: Display, T: np.ndarray, frusta) -> bool:
    """Whether the page point ``eye`` (3,) lies in the drawn part (up to ``far``) of the source's or target's
    frustum."""
    in_target = eye * d.size + d.centre
    in_source = (in_target - T[:3, 3]) @ T[:3, :3]  # T^-1: the source's frame
    for f, p in zip(frusta, (in_source, in_target)):
        if not hasattr(f, "project"):  # a panorama's or a cloud's view: all round the sensor, no frustum to avoid
            continue
        _, depth = f.project(p[None])
        if 0 < depth[0] <= f.far and bool(f.contains(p[None])[0]):
            return True
    return False


UP = (0.0, 1.0, 0.0)  # the page's up: the target's +y (the scans' frame)


class CameraKeeper:
    """Sends the page's camera pose again where the browser read it in another up direction.

    viser's browser reads a camera pose in the world up it holds when the pose arrives; the first pair is drawn as the
    browser connects, while it may still hold viser's +z up, and was then seen from a rotated eye, on its side (the
    browser reported +x up). The orbit controls keep the up they are given, so a reported up other than :data:`UP`
    is that misreading, never the user's doing: the pose the page last set (:meth:`keep`) is sent again, a few times
    at most.
    """

    TRIES = 5

    def __init__(self, client: viser.ClientHandle):
        self.client = client
        self.pose: tuple[tuple, tuple] | None = None  # (position, look_at) the page last set
        self.tries = 0
        client.camera.on_update(self._reported)

    def keep(self) -> None:
        """Remember the camera pose the page has just set (position, look-at; up :data:`UP`)."""
        cam = self.client.camera
        self.pose, self.tries = (tuple(cam.position), tuple(cam.look_at)), 0

    def _reported(self, cam) -> None:
        if self.pose is None or np.allclose(cam.up_direction, UP, atol=1e-3) or self.tries >= self.TRIES:
            return
        self.tries += 1
        cam.position = self.pose[0]  # first: a new position moves the look-at point along with it
        cam.look_at = self.pose[1]
        cam.up_direction = UP


def fit_camera(client: viser.ClientHandle, points: np.ndarray) -> None:
    """Point the camera at (K, 3) page points so that all fit the view, looking the way it looks now: the nearest
    distance at which every point lies inside both the vertical and the horizontal field of view."""
    cam = client.camera
    try:  # the camera as the browser last reported it
        way = np.asarray(cam.position, np.float64) - np.asarray(cam.look_at, np.float64)
        fov, aspect = float(cam.fov), float(cam.aspect)  # fov: vertical, radians
    except (AssertionError, ZeroDivisionError):  # nothing reported yet
        way, fov, aspect = np.zeros(3), DEFAULT_FOV, 1.0
    if not np.linalg.norm(way) > 1e-9:
        way = np.asarray(VIEW_DIRECTION, np.float64)
    centre, distance = fit_distance(points, way / np.linalg.norm(way), fov, aspect)
    cam.position = tuple(centre + distance * way / np.linalg.norm(way))  # first: a new position moves the look-at
    cam.look_at = tuple(centre)  # point along with it


def clear_path(nodes: SceneNodes) -> None:
    nodes.path.points = EMPTY_SEGMENTS
    nodes.minima.points = EMPTY_POINTS
