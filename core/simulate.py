"""A simulated range scanner and the paper's test scenes (corner, wing, bowl), and the lesson's ribbed corner,
in millimetres.

The scanner casts a (rows x cols) grid of rays from its pose over a field of view onto a scene
mesh (Open3D raycasting), jitters the ray directions (non-uniform spacing), adds Gaussian range
noise (optionally quantised to a range step) and replaces a fraction of the returns with spurious points on no
surface. The sensor frame
is an OpenGL camera's: x right, y up, looking along -z, so its range grid follows Stanford's
convention (see :class:`core.scan.RangeGrid`). Points are written in the sensor frame; the scan's
``pose`` is the true ``T_world_sensor``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scan import RangeGrid, Scan
from .transforms import apply, from_params, invert, random_perturbation

FOOT = 304.8  # mm


@dataclass(frozen=True)
class Scanner:
    """fov_deg: (horizontal, vertical) degrees; noise: range sigma (mm); outliers: fraction of returns;
    quantum: the range step the scanner reports in (mm; 0: none)."""

    rows: int = 80
    cols: int = 80
    fov_deg: tuple[float, float] = (40.0, 40.0)
    noise: float = 0.8
    outliers: float = 0.03
    jitter: float = 0.35  # ray direction jitter, in cells
    quantum: float = 0.0


def look_at(eye, target, up=(0.0, 0.0, 1.0)) -> np.ndarray:
    """T_world_sensor of a sensor at ``eye`` looking at ``target`` (OpenGL camera axes)."""
    eye, target, up = (np.asarray(a, dtype=np.float64) for a in (eye, target, up))
    back = eye - target
    back /= np.linalg.norm(back)
    right = np.cross(up, back)
    right /= np.linalg.norm(right)
    T = np.eye(4)
    T[:3, :3] = np.stack([right, np.cross(back, right), back], axis=1)
    T[:3, 3] = eye
    return T


def scan_mesh(vertices: np.ndarray, faces: np.ndarray, T_world_sensor: np.ndarray, scanner: Scanner,
              rng: np.random.Generator, name: str = "scan") -> Scan:
    """Simulate one scan of the mesh (vertices (V, 3) mm, faces (F, 3)) from ``T_world_sensor``."""
    import open3d as o3d

    r, c = np.meshgrid(np.arange(scanner.rows), np.arange(scanner.cols), indexing="ij")
    jr = rng.uniform(-scanner.jitter, scanner.jitter, r.shape)
    jc = rng.uniform(-scanner.jitter, scanner.jitter, c.shape)
    tx, ty = np.tan(np.radians(scanner.fov_deg[0]) / 2), np.tan(np.radians(scanner.fov_deg[1]) / 2)
    dirs = np.stack([tx * (2 * (c + 0.5 + jc) / scanner.cols - 1),
                     ty * (2 * (r + 0.5 + jr) / scanner.rows - 1), -np.ones(r.shape)], axis=-1).reshape(-1, 3)
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    world_dirs = dirs @ T_world_sensor[:3, :3].T
    origin = np.broadcast_to(T_world_sensor[:3, 3], world_dirs.shape)
    scene = o3d.t.geometry.RaycastingScene()
    mesh = o3d.t.geometry.TriangleMesh()
    mesh.vertex.positions = o3d.core.Tensor(vertices.astype(np.float32))
    mesh.triangle.indices = o3d.core.Tensor(faces.astype(np.int32))
    scene.add_triangles(mesh)
    hit = scene.cast_rays(o3d.core.Tensor(np.hstack([origin, world_dirs]).astype(np.float32)))["t_hit"].numpy()
    hit = hit.astype(np.float64)
    ok = np.isfinite(hit)
    rng_ = hit + rng.normal(0.0, scanner.noise, hit.shape)
    if scanner.quantum > 0:
        rng_ = np.round(rng_ / scanner.quantum) * scanner.quantum
    spurious = ok & (rng.random(hit.shape) < scanner.outliers)
    rng_[spurious] = hit[spurious] * rng.uniform(0.6, 0.95, spurious.sum())
    points = dirs[ok] * rng_[ok, None]
    index = np.full(hit.shape, -1, dtype=np.int64)
    index[ok] = np.arange(ok.sum())
    return Scan(points=points, viewpoint=np.zeros(3), name=name, units="mm", grid=RangeGrid(index.reshape(r.shape)),
                pose=T_world_sensor.copy())


def height_field(fn, half: float, n: int, radius: float | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Triangulate z = fn(x, y) over [-half, half]^2 (optionally a disc) on an n x n grid."""
    xs = np.linspace(-half, half, n)
    x, y = np.meshgrid(xs, xs, indexing="ij")
    verts = np.stack([x, y, fn(x, y)], axis=-1).reshape(-1, 3)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    faces = np.concatenate([np.c_[a.ravel(), b.ravel(), c.ravel()], np.c_[b.ravel(), d.ravel(), c.ravel()]])
    if radius is not None:
        inside = np.hypot(verts[:, 0], verts[:, 1]) <= radius
        faces = faces[np.all(inside[faces], axis=1)]
    return verts, faces


def corner_mesh(size: float = 4 * FOOT) -> tuple[np.ndarray, np.ndarray]:
    """Three orthogonal square planes meeting at the origin (the inside of a room corner)."""
    L = size
    verts = np.array([[0, 0, 0], [L, 0, 0], [L, L, 0], [0, L, 0],  # floor z = 0
                      [0, 0, L], [L, 0, L], [0, L, L]], dtype=np.float64)
    faces = np.array([[0, 1, 2], [0, 2, 3],          # z = 0
                      [0, 4, 5], [0, 5, 1],          # y = 0
                      [0, 3, 6], [0, 6, 4]])         # x = 0
    return verts, faces


def folded_profile(amplitude: float, pitch: tuple[float, float], length: float):
    """h(u): a triangle wave (folds) of ``amplitude`` (mm) whose pitch grows linearly from ``pitch[0]`` at u = 0
    to ``pitch[1]`` at u = ``length`` (its phase is the integral of 1 / pitch), so no shift lines every fold up
    with another."""
    p0, p1 = pitch
    k = (p1 - p0) / length

    def h(u):
        phase = np.log((p0 + k * u) / p0) / k if k else u / p0
        return amplitude * (2 / np.pi) * np.arcsin(np.sin(2 * np.pi * phase))

    return h


def ribbed_corner_mesh(size: float = 4 * FOOT, amplitude: float = 30.0, pitch: tuple[float, float] = (80.0, 160.0),
                       n: int = 241) -> tuple[np.ndarray, np.ndarray]:
    """The corner of :func:`corner_mesh` with each face folded into ribs (:func:`folded_profile` across the
    face, along its first in-plane axis: upright ribs on the walls, ribs along y on the floor), the lesson's
    scene: its folds give E the small minima round the truth that the plain corner lacks (README, Lesson)."""
    h = folded_profile(amplitude, pitch, size)
    u = np.linspace(0.0, size, n)
    U, V = np.meshgrid(u, u, indexing="ij")
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[:-1, 1:], idx[1:, 1:]
    grid = np.concatenate([np.c_[a.ravel(), b.ravel(), c.ravel()], np.c_[b.ravel(), d.ravel(), c.ravel()]])
    verts, faces = [], []
    for axis in range(3):  # the face normal to this axis, folded along it; its two other coordinates are (U, V)
        P = np.zeros((n * n, 3))
        others = [k for k in range(3) if k != axis]
        P[:, others[0]], P[:, others[1]], P[:, axis] = U.ravel(), V.ravel(), h(U).ravel()
        verts.append(P)
        faces.append(grid + axis * n * n)
    return np.concatenate(verts), np.concatenate(faces)


def wing_mesh(size: float = 3 * FOOT) -> tuple[np.ndarray, np.ndarray]:
    """A gently curved panel with a wing-like (non-circular) profile across x and almost no
    curvature along y: its overlap is ambiguous along y (paper Fig. 8)."""
    h = size / 2
    return height_field(lambda x, y: 110.0 * (x / h) ** 2 - 45.0 * (x / h) ** 3 - (y * y) / (2 * 40000.0), h, 121)


def bowl_mesh(radius: float = 300.0, seed: int = 7) -> tuple[np.ndarray, np.ndarray]:
    """A bowl (paper Fig. 11) whose wall carries many small dimples."""
    rng = np.random.default_rng(seed)
    n_dimples = 90
    rr = radius * np.sqrt(rng.uniform(0.05, 0.95, n_dimples))
    th = rng.uniform(0, 2 * np.pi, n_dimples)
    cx, cy = rr * np.cos(th), rr * np.sin(th)

    def z(x, y):
        h = (x * x + y * y) / (2 * radius)
        for px, py in zip(cx, cy):
            h = h - 6.0 * np.exp(-((x - px) ** 2 + (y - py) ** 2) / (2 * 14.0 ** 2))
        return h

    return height_field(z, radius, 241, radius=radius)


@dataclass(frozen=True)
class SceneSpec:
    mesh: object
    eyes: tuple
    targets: tuple
    scanner: Scanner
    spread_deg: float  # the paper's starting spread: 5 deg and 250 mm for the 4 ft corner,
    spread: float      # scaled to the scene's size
    size: float


def _specs() -> dict[str, SceneSpec]:
    corner = 4 * FOOT
    return {
        "corner": SceneSpec(corner_mesh, ((1750, 1150, 1350), (1150, 1750, 1300)),
                            ((250, 520, 420), (520, 250, 420)), Scanner(rows=85, cols=85, fov_deg=(52, 52)),
                            5.0, 250.0, corner),
        "wing": SceneSpec(wing_mesh, ((-180, -120, 1500), (180, 120, 1450)), ((-110, -80, -40), (110, 80, -40)),
                          Scanner(rows=60, cols=60, fov_deg=(26, 26), noise=0.8), 5.0, 250.0 * 3 / 4, 3 * FOOT),
        "bowl": SceneSpec(bowl_mesh, ((-150, -60, 900), (150, 60, 880)), ((-60, 0, 60), (60, 0, 60)),
                          Scanner(rows=75, cols=75, fov_deg=(36, 36), noise=0.5), 5.0, 250.0 * 600 / corner, 600.0),
        # the lesson (app/lesson.py): the corner's views, denser, of the ribbed corner (folds +-30 mm)
        "ribbed": SceneSpec(ribbed_corner_mesh, ((1750, 1150, 1350), (1150, 1750, 1300)),
                            ((250, 520, 420), (520, 250, 420)), Scanner(rows=120, cols=120, fov_deg=(52, 52)),
                            5.0, 250.0, corner),
    }


SCENES = tuple(_specs())


def make_scene(name: str, seed: int = 0) -> tuple[Scan, Scan]:
    """The two scans (target scan1, source scan2) of a named scene, each with its true ``pose`` and a
    rough ``guess`` (scan1's exact, scan2's perturbed by the paper's spread, scaled to the scene)."""
    specs = _specs()
    if name not in specs:
        from .errors import InputError

        raise InputError(f"unknown scene {name!r}; choose one of {', '.join(SCENES)}")
    spec = specs[name]
    rng = np.random.default_rng(seed)
    verts, faces = spec.mesh()
    scans = []
    for i, (eye, target) in enumerate(zip(spec.eyes, spec.targets), 1):
        scans.append(scan_mesh(verts, faces, look_at(eye, target), spec.scanner, rng, name=f"{name}-scan{i}"))
    a, b = scans
    t, r = random_perturbation(rng, spec.spread_deg, spec.spread)
    center = apply(b.pose, b.points.mean(0)[None])[0]
    D = from_params(np.r_[t, 0, 0, 0]) @ _rotate_about(r, center)
    from dataclasses import replace

    a = replace(a, guess=a.pose.copy())
    b = replace(b, guess=D @ b.pose)
    return a, b


def _rotate_about(rotvec, center):
    R = from_params(np.r_[0, 0, 0, rotvec])
    return from_params(np.r_[center, 0, 0, 0]) @ R @ from_params(np.r_[-center, 0, 0, 0])


def true_transform(source: Scan, target: Scan) -> np.ndarray:
    """T_target_source from the scans' ground-truth poses."""
    return invert(target.pose) @ source.pose


def terrain_mesh(half: float = 1000.0, n: int = 601, seed: int = 11) -> tuple[np.ndarray, np.ndarray]:
    """An asymmetric landscape of random bumps and pits (mm) over [-half, half]^2, for large scans."""
    rng = np.random.default_rng(seed)
    k = 400
    cx, cy = rng.uniform(-half, half, (2, k))
    amp = rng.uniform(-50.0, 60.0, k)
    sig = rng.uniform(15.0, 90.0, k)

    def z(x, y):
        h = 0.04 * x - 0.02 * y
        for px, py, a, s in zip(cx, cy, amp, sig):
            h = h + a * np.exp(-((x - px) ** 2 + (y - py) ** 2) / (2 * s * s))
        return h

    return height_field(z, half, n)


def make_large_pair(n_points: int = 2_000_000, seed: int = 0, spread_deg: float = 5.0,
                    spread: float = 60.0, mesh_n: int = 601) -> tuple[Scan, Scan]:
    """Two dense scans (target, source) of :func:`terrain_mesh` from above, about ``n_points`` each
    (a square grid of rays, every one hitting), ~70 % overlap, with true ``pose`` and a rough
    ``guess`` for the source (perturbed by ``spread_deg`` and ``spread`` mm): the large-input benchmark.
    ``mesh_n``: the terrain's vertices per side (a few thousand points need far fewer than 601)."""
    rng = np.random.default_rng(seed)
    rows = max(2, int(round(np.sqrt(n_points))))
    cols = max(2, int(np.ceil(n_points / rows)))
    scanner = Scanner(rows=rows, cols=cols, fov_deg=(30.0, 30.0), noise=0.3, outliers=0.01)
    verts, faces = terrain_mesh(n=mesh_n)
    eyes, targets = ((-150.0, -60.0, 1500.0), (150.0, 60.0, 1480.0)), ((-100.0, 0.0, 0.0), (100.0, 20.0, 0.0))
    a, b = (scan_mesh(verts, faces, look_at(eye, tgt, up=(0.0, 1.0, 0.0)), scanner, rng, name=f"large-scan{i}")
            for i, (eye, tgt) in enumerate(zip(eyes, targets), 1))
    t, r = random_perturbation(rng, spread_deg, spread)
    center = apply(b.pose, b.points.mean(0)[None])[0]
    D = from_params(np.r_[t, 0, 0, 0]) @ _rotate_about(r, center)
    from dataclasses import replace

    return replace(a, guess=a.pose.copy()), replace(b, guess=D @ b.pose)
