"""Simulated scans of scenes in metres, as LiDAR and RGB-D sensors take them: a spinning LiDAR's panorama
(rings x azimuth steps, Gaussian range noise) of a street or a room, and RGB-D fragments (several depth frames
of a moving camera, fused into one cloud with no single viewpoint).

Every scene is a triangle mesh in a world frame (x along the street / the room's length, z up); a scan holds
its points in the sensor's frame (a LiDAR: x forward, z up; a fragment: its first camera's frame) and its true
``pose`` T_world_scan. Every random choice takes a Generator.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .scan import Scan, ScanKind
from .simulate import look_at


# ---- meshes -------------------------------------------------------------------------------------------------
def box(lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """An axis-aligned box from corner ``lo`` to ``hi`` (3,) as 8 vertices and 12 outward triangles."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    v = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
    f = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, f


def quad(a, b, c, d) -> tuple[np.ndarray, np.ndarray]:
    """A planar quadrilateral a-b-c-d as two triangles."""
    return np.array([a, b, c, d], dtype=np.float64), np.array([[0, 1, 2], [0, 2, 3]])


def join(parts) -> tuple[np.ndarray, np.ndarray]:
    """One mesh of many (vertices, faces) parts."""
    verts, faces, n = [], [], 0
    for v, f in parts:
        verts.append(v)
        faces.append(f + n)
        n += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def street_mesh(length: float = 160.0, half_width: float = 8.0, seed: int = 3) -> tuple[np.ndarray, np.ndarray]:
    """A street along x: the road, facades on both sides broken into buildings of varied setback and height,
    parked cars and poles (what pins the motion along the road; a corridor of planes would not)."""
    rng = np.random.default_rng(seed)
    parts = [quad((-length / 2, -half_width - 6, 0), (length / 2, -half_width - 6, 0),
                  (length / 2, half_width + 6, 0), (-length / 2, half_width + 6, 0))]
    for side in (-1, 1):
        x = -length / 2
        while x < length / 2:
            w = rng.uniform(6.0, 18.0)
            setback = rng.uniform(0.0, 2.5)
            h = rng.uniform(5.0, 16.0)
            y0 = side * (half_width + setback)
            parts.append(box((x, min(y0, y0 + side * 6), 0), (x + w - rng.uniform(0.0, 1.5), max(y0, y0 + side * 6), h)))
            x += w
        for _ in range(int(length / 12)):  # parked cars along the kerb
            cx = rng.uniform(-length / 2, length / 2)
            cy = side * rng.uniform(half_width - 3.0, half_width - 2.0)
            parts.append(box((cx, cy - 0.9, 0), (cx + rng.uniform(3.8, 4.8), cy + 0.9, rng.uniform(1.4, 1.8))))
        for px in np.arange(-length / 2 + rng.uniform(0, 10), length / 2, rng.uniform(14, 22)):  # poles
            py = side * (half_width - 1.0)
            parts.append(box((px - 0.1, py - 0.1, 0), (px + 0.1, py + 0.1, rng.uniform(4.0, 7.0))))
    return join(parts)


def corridor_mesh(length: float = 160.0, half_width: float = 8.0, height: float = 10.0) -> tuple[np.ndarray, np.ndarray]:
    """A road between two plain walls along x: every surface is parallel to x, so nothing pins a motion along it."""
    L, w = length / 2, half_width
    return join([quad((-L, -w, 0), (L, -w, 0), (L, w, 0), (-L, w, 0)),
                 quad((-L, -w, 0), (-L, -w, height), (L, -w, height), (L, -w, 0)),
                 quad((-L, w, 0), (L, w, 0), (L, w, height), (-L, w, height))])


def room_mesh(size=(7.0, 5.0, 2.8), seed: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """A room (floor, walls, ceiling: an inside-out box) with furniture: a table, cabinets, shelves, a sofa."""
    rng = np.random.default_rng(seed)
    X, Y, Z = size
    parts = [box((0, 0, 0), (X, Y, Z))]
    parts.append(box((2.4, 1.6, 0.72), (4.0, 2.6, 0.78)))  # a table top on four legs
    for lx, ly in ((2.45, 1.65), (3.9, 1.65), (2.45, 2.5), (3.9, 2.5)):
        parts.append(box((lx, ly, 0), (lx + 0.05, ly + 0.05, 0.72)))
    parts.append(box((0, 3.2, 0), (0.6, 4.8, 2.0)))  # a tall cabinet against a wall
    parts.append(box((5.2, 0, 0), (6.8, 0.5, 0.9)))  # a low sideboard
    parts.append(box((X - 0.9, 2.0, 0), (X, 4.2, 0.45)))  # a sofa's seat ...
    parts.append(box((X - 0.3, 2.0, 0.45), (X, 4.2, 0.95)))  # ... and back
    for k in range(4):  # shelves on the far wall
        z = 0.5 + 0.4 * k
        parts.append(box((1.5, Y - 0.3, z), (3.0 + rng.uniform(-0.3, 0.3), Y, z + 0.03)))
    parts.append(box((4.5, 3.6, 0), (5.0, 4.1, rng.uniform(0.4, 0.6))))  # a box on the floor
    v, f = join(parts)
    f[:12] = f[:12][:, ::-1]  # the room's own box faces inwards
    return v, f


# ---- sensors ------------------------------------------------------------------------------------------------
def cast(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """(N,) distance along unit rays (N, 3) from (N, 3) origins to the first triangle hit (inf: none)."""
    import open3d as o3d

    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(faces.astype(np.int32))
    scene.add_triangles(mesh)
    rays = np.hstack([origins, dirs]).astype(np.float32)
    return scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)


@dataclass(frozen=True)
class Spinning:
    """A spinning LiDAR: ``rings`` beams spread over ``elevation_deg`` (low, high), ``steps`` azimuth steps a
    turn, range noise ``noise`` (m, sigma), returns between ``min_range`` and ``max_range`` (m).

    Per-laser calibration residuals (default none): each laser's range is off by a constant drawn with sigma
    ``laser_range_bias`` (m) and it fires at its nominal elevation plus a constant drawn with sigma
    ``laser_elevation_deg`` (degrees), while its points are written along the nominal elevation, as a sensor whose
    calibration table is slightly wrong writes them (real multi-laser scanners: a range correction in cm and a
    vertical angle per laser, benchmarks/lidar_floor.py). The constants are drawn from ``calibration_seed`` alone,
    so both scans of a pair come from one unit and the scan's own draws are the same with or without them."""

    rings: int = 32
    steps: int = 1024
    elevation_deg: tuple[float, float] = (-25.0, 15.0)
    noise: float = 0.02
    min_range: float = 0.8
    max_range: float = 60.0
    laser_range_bias: float = 0.0
    laser_elevation_deg: float = 0.0
    calibration_seed: int = 0

    def calibration(self) -> tuple[np.ndarray, np.ndarray]:
        """(rings,) range offsets (m) and (rings,) elevation errors (radians) of this unit's lasers."""
        rng = np.random.default_rng([self.calibration_seed, self.rings])
        bias = rng.normal(0.0, 1.0, self.rings) * self.laser_range_bias
        tilt = rng.normal(0.0, 1.0, self.rings) * np.radians(self.laser_elevation_deg)
        return bias, tilt


def spin_scan(mesh, T_world_sensor: np.ndarray, lidar: Spinning, rng: np.random.Generator,
              name: str = "lidar") -> Scan:
    """One turn of ``lidar`` at ``T_world_sensor`` (x forward, z up): a PANORAMA scan in metres, the sensor at
    its origin, with its true pose."""
    vertices, faces = mesh
    el = np.radians(np.linspace(*lidar.elevation_deg, lidar.rings))
    az = 2 * np.pi * (np.arange(lidar.steps) + rng.uniform(0, 1)) / lidar.steps
    E, A = np.meshgrid(el, az, indexing="ij")
    dirs = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1).reshape(-1, 3)
    fired = dirs
    bias, tilt = lidar.calibration()
    if lidar.laser_elevation_deg:  # the beams leave at the true elevations; the points are written at the nominal
        Et = E + tilt[:, None]
        fired = np.stack([np.cos(Et) * np.cos(A), np.cos(Et) * np.sin(A), np.sin(Et)], axis=-1).reshape(-1, 3)
    world = fired @ T_world_sensor[:3, :3].T
    hit = cast(vertices, faces, np.broadcast_to(T_world_sensor[:3, 3], world.shape), world)
    r = hit + rng.normal(0.0, lidar.noise, hit.shape)
    if lidar.laser_range_bias:
        r = r + np.repeat(bias, lidar.steps)  # rows of the (rings, steps) grid, ring-major as dirs
    ok = np.isfinite(hit) & (r >= lidar.min_range) & (r <= lidar.max_range)
    return Scan(points=dirs[ok] * r[ok, None], viewpoint=np.zeros(3), name=name, units="m",
                pose=T_world_sensor.copy(), kind=ScanKind.PANORAMA)


def pose_at(x: float, y: float, z: float, yaw_deg: float = 0.0) -> np.ndarray:
    """T_world_sensor of a sensor at (x, y, z) turned ``yaw_deg`` about world z (x forward, z up)."""
    c, s = np.cos(np.radians(yaw_deg)), np.sin(np.radians(yaw_deg))
    T = np.eye(4)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = (x, y, z)
    return T


def lidar_pair(scene: str, seed: int = 0, lidar: Spinning = Spinning()) -> tuple[Scan, Scan]:
    """(source, target) LiDAR scans of ``scene`` ("street", "corridor", "room") from two nearby poses (a
    vehicle's or a tripod's odometry step: 0.3-1 m, a few degrees of yaw), seeded."""
    rng = np.random.default_rng(seed)
    if scene in ("street", "corridor"):
        mesh = street_mesh() if scene == "street" else corridor_mesh()
        x0 = rng.uniform(-20, 20)
        T_t = pose_at(x0, rng.uniform(-1.5, 1.5), 1.8, rng.uniform(-3, 3))
        step = rng.uniform(0.5, 1.0)
        T_s = pose_at(x0 + step, T_t[1, 3] + rng.uniform(-0.1, 0.1), 1.8 + rng.normal(0, 0.01), rng.uniform(-3, 3))
        lid = lidar
    elif scene == "room":
        mesh = room_mesh()
        T_t = pose_at(rng.uniform(2.0, 3.0), rng.uniform(1.0, 1.4), 1.2, rng.uniform(-10, 10))
        T_s = pose_at(T_t[0, 3] + rng.uniform(0.3, 0.6), T_t[1, 3] + rng.uniform(-0.2, 0.2), 1.2,
                      rng.uniform(-10, 10))
        lid = replace(lidar, elevation_deg=(-30.0, 30.0), noise=min(lidar.noise, 0.01), min_range=0.3)
    else:
        from .errors import InputError

        raise InputError(f"unknown LiDAR scene {scene!r}; choose street, corridor or room")
    target = spin_scan(mesh, T_t, lid, rng, name=f"{scene}-{seed}-a")
    source = spin_scan(mesh, T_s, lid, rng, name=f"{scene}-{seed}-b")
    return source, target


@dataclass(frozen=True)
class DepthCamera:
    """A depth camera (x right, y down, looking along +z, as RGB-D frames are written): ``cols x rows`` pixels
    over ``fov_deg`` horizontally, depth noise sigma ``noise_at_1m`` x depth^2 (m; structured light's
    quadratic growth: 3 mm at 2 m, about what a fused fragment keeps after averaging), depths between ``near`` and ``far`` (m)."""

    cols: int = 160
    rows: int = 120
    fov_deg: float = 58.0
    noise_at_1m: float = 0.0008
    near: float = 0.4
    far: float = 5.0


def look_from(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_camera of a camera at ``eye`` looking at ``target`` (x right, y down, z forward): the OpenGL
    sensor of :func:`core.simulate.look_at` turned half a turn about its x axis."""
    return look_at(eye, target, up) @ np.diag([1.0, -1.0, -1.0, 1.0])


def _pixel_rays(cam: DepthCamera) -> np.ndarray:
    """(rows * cols, 3) each pixel's ray (x / z, y / z, 1) in the camera's frame, row-major."""
    f = cam.cols / 2 / np.tan(np.radians(cam.fov_deg) / 2)
    u, v = np.meshgrid(np.arange(cam.cols) + 0.5 - cam.cols / 2, np.arange(cam.rows) + 0.5 - cam.rows / 2)
    return np.stack([u / f, v / f, np.ones_like(u)], axis=-1).reshape(-1, 3)


def depth_image(mesh, T_world_camera: np.ndarray, cam: DepthCamera, rng: np.random.Generator) -> np.ndarray:
    """(rows, cols) depths (m, along the camera's z) of one frame, NaN where the camera measured none."""
    vertices, faces = mesh
    dirs = _pixel_rays(cam)
    unit = dirs / np.linalg.norm(dirs, axis=1, keepdims=True)
    hit = cast(vertices, faces, np.broadcast_to(T_world_camera[:3, 3], unit.shape), unit @ T_world_camera[:3, :3].T)
    depth = hit * unit[:, 2]
    depth = depth + rng.normal(0.0, 1.0, depth.shape) * cam.noise_at_1m * depth ** 2
    ok = np.isfinite(depth) & (depth >= cam.near) & (depth <= cam.far)
    return np.where(ok, depth, np.nan).reshape(cam.rows, cam.cols)


def depth_frame(mesh, T_world_camera: np.ndarray, cam: DepthCamera, rng: np.random.Generator) -> np.ndarray:
    """(N, 3) points of one depth frame in the camera's frame."""
    depth = depth_image(mesh, T_world_camera, cam, rng).ravel()
    ok = np.isfinite(depth)
    return _pixel_rays(cam)[ok] * depth[ok, None]


def fragment(mesh, cameras: list[np.ndarray], cam: DepthCamera, rng: np.random.Generator, voxel: float = 0.01,
             name: str = "fragment") -> Scan:
    """Depth frames from ``cameras`` (T_world_camera each) fused in the first camera's frame and thinned on a
    ``voxel`` grid (m): an UNSTRUCTURED scan, pose T_world_first-camera."""
    import open3d as o3d

    T0_inv = np.linalg.inv(cameras[0])
    clouds = []
    for T in cameras:
        p = depth_frame(mesh, T, cam, rng)
        M = T0_inv @ T
        clouds.append(p @ M[:3, :3].T + M[:3, 3])
    pcd = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(np.concatenate(clouds))).voxel_down_sample(voxel)
    return Scan(points=np.asarray(pcd.points).copy(), viewpoint=np.zeros(3), name=name, units="m",
                pose=cameras[0].copy(), kind=ScanKind.UNSTRUCTURED)


def fragment_pair(seed: int = 0, frames: int = 5, cam: DepthCamera = DepthCamera(), shared: int = 2
                  ) -> tuple[Scan, Scan]:
    """(source, target) RGB-D fragments of the room: a hand-held camera walked along an arc round the room's
    centre, 6 degrees a frame, ``frames`` frames a fragment, the second fragment's path starting ``shared``
    frames before the first's ends (they overlap, as consecutive fragments of a reconstruction do)."""
    rng = np.random.default_rng(seed)
    mesh = room_mesh()
    first, second = _arc_walk(rng, frames, shared)
    target = fragment(mesh, first, cam, rng, name=f"fragment-{seed}-a")
    source = fragment(mesh, second, cam, rng, name=f"fragment-{seed}-b")
    return source, target


def _arc_walk(rng: np.random.Generator, frames: int, shared: int) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Two fragments' cameras (T_world_camera each) along :func:`fragment_pair`'s arc round the room's centre."""
    centre = np.array([3.5, 2.5, 1.0])
    a0 = rng.uniform(0, 2 * np.pi)

    def path(a_start, n):
        out = []
        for k in range(n):
            a = a_start + k * np.radians(6.0)
            eye = centre + np.array([1.2 * np.cos(a), 0.9 * np.sin(a), rng.uniform(0.2, 0.5)])
            look = centre + np.array([-2.0 * np.cos(a + 0.3), -1.6 * np.sin(a + 0.3), rng.uniform(-0.6, -0.2)])
            out.append(look_from(eye, look))
        return out

    first = path(a0, frames)
    return first, path(a0 + np.radians(6.0) * (frames - shared), frames)


# ---- fragments as a reconstruction system makes them: depth frames fused into a TSDF -------------------------
# Open3D's reconstruction system integrates each fragment's frames into a TSDF volume at its odometry's poses and
# writes the surface's points (its default voxel 3/512 m). Its UniformTSDFVolume holds ~47 bytes a voxel and
# visits every voxel for every frame, so the room is fused tile by tile (at most TSDF_TILE voxels a side, each
# tile's own points kept); its ScalableTSDFVolume and the tensor VoxelBlockGrid extracted no point here.
TSDF_TILE = 256
TSDF_TRUNC_VOXELS = 3.4  # the truncation in voxels (Open3D's system: 0.04 m at 3/512 m: 6.8; halved, as at 1.5 cm)


def tsdf_fragment(mesh, cameras: list[np.ndarray], cam: DepthCamera, rng: np.random.Generator,
                  bounds: tuple[tuple[float, float, float], tuple[float, float, float]], voxel: float = 0.015,
                  drift_deg: float = 0.1, drift_m: float = 0.002, name: str = "fragment") -> Scan:
    """Depth frames from ``cameras`` (T_world_camera each) fused as a reconstruction system fuses them: each
    integrated into a TSDF (``voxel`` m, within ``bounds`` (low, high corners, m) of the world) at its pose moved
    by a random walk of ``drift_deg`` and ``drift_m`` (sigma) a frame after the first (the system's odometry
    error), and the surface's points extracted, in the first camera's frame: an UNSTRUCTURED scan, pose
    T_world_first-camera (the truth; the drift is the fragment's own distortion)."""
    import open3d as o3d

    from .transforms import from_params

    integration = o3d.pipelines.integration
    f = cam.cols / 2 / np.tan(np.radians(cam.fov_deg) / 2)
    intrinsic = o3d.camera.PinholeCameraIntrinsic(cam.cols, cam.rows, f, f, cam.cols / 2 - 0.5, cam.rows / 2 - 0.5)
    first_inv = np.linalg.inv(cameras[0])
    drift, frames = np.eye(4), []
    for k, T in enumerate(cameras):
        if k:
            drift = drift @ from_params(np.r_[rng.normal(0, drift_m, 3), rng.normal(0, np.radians(drift_deg), 3)])
        depth = np.nan_to_num(depth_image(mesh, T, cam, rng), nan=0.0).astype(np.float32)
        rgbd = o3d.geometry.RGBDImage.create_from_color_and_depth(
            o3d.geometry.Image(np.zeros((cam.rows, cam.cols, 3), np.uint8)), o3d.geometry.Image(depth),
            depth_scale=1.0, depth_trunc=cam.far, convert_rgb_to_intensity=False)
        frames.append((rgbd, np.linalg.inv(cameras[0] @ drift @ first_inv @ T)))  # T_camera_world as drifted
    low, high = np.asarray(bounds[0], dtype=np.float64), np.asarray(bounds[1], dtype=np.float64)
    margin = 4 * voxel
    resolution = min(TSDF_TILE, int(np.ceil(float(np.max(high - low)) / voxel)) + 8)  # no larger than the bounds ask
    side = resolution * voxel
    points = []
    for corner in np.stack(np.meshgrid(*[np.arange(lo, hi, side - 2 * margin) for lo, hi in zip(low, high)],
                                       indexing="ij"), -1).reshape(-1, 3):
        volume = integration.UniformTSDFVolume(length=side, resolution=resolution,
                                               sdf_trunc=TSDF_TRUNC_VOXELS * voxel,
                                               color_type=integration.TSDFVolumeColorType.RGB8,
                                               origin=corner - margin)
        for rgbd, extrinsic in frames:
            volume.integrate(rgbd, intrinsic, extrinsic)
        p = np.asarray(volume.extract_point_cloud().points)
        own = np.all((p >= corner) & (p < corner + side - 2 * margin), axis=1)  # each point in one tile only
        points.append(p[own])
    p = np.concatenate(points)
    return Scan(points=p @ first_inv[:3, :3].T + first_inv[:3, 3], viewpoint=np.zeros(3), name=name, units="m",
                pose=cameras[0].copy(), kind=ScanKind.UNSTRUCTURED)


def tsdf_fragment_pair(seed: int, frames: int = 20, shared: int = 5, cam: DepthCamera = DepthCamera(cols=320, rows=240),
                       voxel: float = 0.015) -> tuple[Scan, Scan]:
    """(source, target) fragments of a room furnished by ``seed`` (room_mesh's seed), walked as
    :func:`fragment_pair` walks, each fused by :func:`tsdf_fragment` with its own drift."""
    rng = np.random.default_rng(seed)
    size = (7.0, 5.0, 2.8)
    mesh = room_mesh(size, seed=seed)
    first, second = _arc_walk(rng, frames, shared)
    bounds = ((-0.05, -0.05, -0.05), tuple(x + 0.05 for x in size))
    target = tsdf_fragment(mesh, first, cam, rng, bounds, voxel, name=f"tsdf-{seed}-a")
    source = tsdf_fragment(mesh, second, cam, rng, bounds, voxel, name=f"tsdf-{seed}-b")
    return source, target
