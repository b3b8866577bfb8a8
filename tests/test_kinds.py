"""Surfaces and overlaps per kind of scan (core.panorama, core.unstructured, core.surface, core.frustum, core.cut):
the spherical image of a panorama, the tangent planes of an unstructured cloud, each kind's overlap, and
registration on a simulated spinning scan, on the shared LiDAR pair and on unstructured clouds."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from rangereg.core.config import Config
from rangereg.core.cut import overlap_cut
from rangereg.core.errors import InputError
from rangereg.core.frustum import frustum_of
from rangereg.core.panorama import build_image, image_of
from rangereg.core.register import register
from rangereg.core.scan import Scan, ScanKind
from rangereg.core.surface import Surface, surface_of, triangulate
from rangereg.core.transforms import invert
from rangereg.core.unstructured import PATCH_SPACINGS, TangentPlanes
from scipy.spatial.transform import Rotation

# ../shared beside the checkout (a worktree one level deeper: ../../shared)
LIDAR = next((p / "shared" / "data" / "lidar" for p in Path(__file__).resolve().parents[2:4]
              if (p / "shared" / "data" / "lidar").exists()), Path("absent"))


# ---- a spinning scanner in a furnished room (metres) --------------------------------------------------------
def room_mesh() -> tuple[np.ndarray, np.ndarray]:
    """A closed 8 x 6 x 3 m room with a table, a cabinet and a pillar (none symmetric): vertices (V, 3), faces."""
    import open3d as o3d

    mesh = o3d.geometry.TriangleMesh()
    for size, at in (((8.0, 6.0, 3.0), (-4.0, -3.0, 0.0)),  # the room's shell
                     ((1.6, 0.9, 0.75), (1.2, -2.0, 0.0)),  # a table
                     ((0.6, 1.8, 2.0), (-3.6, 0.8, 0.0)),  # a cabinet against a wall
                     ((0.4, 0.4, 3.0), (2.2, 1.4, 0.0))):  # a pillar
        mesh += o3d.geometry.TriangleMesh.create_box(*size).translate(at)
    return np.asarray(mesh.vertices), np.asarray(mesh.triangles)


def spin_scan(mesh, T_world_sensor: np.ndarray, rng: np.random.Generator, rings: int = 32, cols: int = 720,
              fov=(-30.0, 30.0), noise: float = 0.005, name: str = "spin", laser_offset: float = 0.0) -> Scan:
    """A spinning LiDAR's scan of ``mesh`` from ``T_world_sensor``: ``rings`` lasers over ``fov`` degrees of
    elevation, ``cols`` firings per turn (each firing's azimuth jittered by 5 % of a step), Gaussian range
    noise (metres); points in the sensor frame, about its origin (each laser ``laser_offset`` metres above or
    below it, alternately, as real heads mount them)."""
    import open3d as o3d

    el = np.radians(np.linspace(*fov, rings))
    az = 2 * np.pi * (np.arange(cols) + rng.uniform(-0.05, 0.05, cols)) / cols - np.pi
    E, A = np.meshgrid(el, az, indexing="ij")
    dirs = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], -1).reshape(-1, 3)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh[0].astype(np.float32)), o3d.core.Tensor(mesh[1].astype(np.uint32)))
    lift = np.zeros((len(dirs), 3))
    lift[:, 2] = np.repeat(laser_offset * (-1.0) ** np.arange(rings), cols)
    world = dirs @ T_world_sensor[:3, :3].T
    rays = np.hstack([T_world_sensor[:3, 3] + lift @ T_world_sensor[:3, :3].T, world]).astype(np.float32)
    hit = scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy().astype(np.float64)
    ok = np.isfinite(hit)
    points = lift[ok] + dirs[ok] * (hit[ok] + rng.normal(0.0, noise, ok.sum()))[:, None]
    return Scan(points=points, viewpoint=np.zeros(3), name=name, units="m", pose=T_world_sensor,
                kind=ScanKind.PANORAMA)


def pose(xyz, yaw_deg: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix()
    T[:3, 3] = xyz
    return T


@pytest.fixture(scope="module")
def room_pair() -> tuple[Scan, Scan, np.ndarray]:
    """(source, target, T_target_source): two spins 0.35 m and 4 degrees apart."""
    mesh, rng = room_mesh(), np.random.default_rng(3)
    target = spin_scan(mesh, pose((0.3, 0.2, 1.2), 10.0), rng, name="room-a")
    source = spin_scan(mesh, pose((0.6, 0.0, 1.25), 14.0), rng, name="room-b")
    return source, target, invert(target.pose) @ source.pose


def angle_and_shift(T: np.ndarray, T_true: np.ndarray) -> tuple[float, float]:
    d = invert(T_true) @ T
    return float(np.degrees(Rotation.from_matrix(d[:3, :3]).magnitude())), float(np.linalg.norm(T[:3, 3] - T_true[:3, 3]))


# ---- the spherical image ---------------------------------------------------------------------------------------
def test_a_ring_scanner_gives_one_row_per_ring_and_every_point_a_cell(room_pair):
    scan = room_pair[1]
    image = image_of(scan)
    assert image.rings and image.shape == (32, 720)
    held = image.index[image.index >= 0]
    assert len(held) == len(scan.points)  # one firing per cell, the jittered ones moved beside
    assert len(np.unique(held)) == len(held)


def test_rings_are_found_when_the_lasers_sit_off_the_origin():
    # 1.5 cm up and down (an Ouster's beam origins lie 1.5-2.7 cm off its axis): a return 1.5 m away is seen
    # 0.6 deg off its laser's elevation, so neighbouring rings (1.9 deg apart) come 1.1 deg closer. (From 2 cm
    # in this room the rings' elevations overlap and are no longer told apart: the image falls back to bins.)
    scan = spin_scan(room_mesh(), pose((0.3, 0.2, 1.2), 10.0), np.random.default_rng(8), laser_offset=0.015)
    image = image_of(scan)
    assert image.rings and image.shape[0] == 32
    _, d2 = surface_of(scan).closest(scan.points)
    assert np.mean(np.sqrt(d2) < 1e-5) > 0.98


def test_a_point_maps_to_its_cell_and_back(room_pair):
    scan = room_pair[1]
    image = image_of(scan)
    rows, cols = np.nonzero(image.index >= 0)
    pts = scan.points[image.index[rows, cols]]
    r, c, rng, ok = image.cells(pts)
    assert ok.all()
    assert np.array_equal(r, rows)
    # a firing moved beside its own cell sits at most one column off
    assert np.all(np.minimum((c - cols) % image.cols, (cols - c) % image.cols) <= 1)
    assert np.mean(c == cols) > 0.95
    # back: the cell's centre direction times the range is the point, within a cell's angle
    back = image.directions(rows, cols) * rng[:, None]
    angle = np.linalg.norm(back - pts, axis=1) / rng
    assert np.all(angle <= 1.5 * max(image.az_step, np.diff(image.row_edges).max()))
    assert np.allclose(image.ranges[rows, cols], rng)


def test_directions_without_rings_are_binned_square():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(20000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pts = d * rng.uniform(2.0, 5.0, (len(d), 1))
    image = build_image(pts, np.zeros(3))
    assert not image.rings
    r, c, _, ok = image.cells(pts)
    assert ok.all()
    step = np.diff(image.row_edges)
    assert np.allclose(step, step[0]) and abs(step[0] - image.az_step) < 0.5 * image.az_step


def test_a_room_scanned_from_inside_gives_a_closed_mesh_on_its_own_points(room_pair):
    scan = room_pair[1]
    surface = surface_of(scan)
    rows, cols = image_of(scan).shape
    assert surface.n_triangles > 0.85 * 2 * (rows - 1) * cols  # two per cell, the image meshed round (depth jumps cut)
    _, d2 = surface.closest(scan.points)
    # every point is a vertex of a triangle kept, but for strips one ring high (the table's rim seen edge-on)
    assert np.mean(np.sqrt(d2) < 1e-5) > 0.998
    # closed: rays from the sensor within the scanned elevations hit the mesh (the room's shell) nearly always
    rng = np.random.default_rng(1)
    el = np.radians(rng.uniform(-29.0, 29.0, 2000))
    az = rng.uniform(-np.pi, np.pi, 2000)
    rays = np.c_[np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)]
    hit = surface.first_hit(np.zeros((2000, 3)), rays)
    assert np.isfinite(hit).mean() > 0.98
    # and the faces face the sensor
    f = surface.faces
    p0 = scan.points[f[:, 0]]
    n = np.cross(scan.points[f[:, 1]] - p0, scan.points[f[:, 2]] - p0)
    assert np.all(np.einsum("ij,ij->i", n, -p0) >= 0)


def test_a_depth_jump_is_not_bridged(room_pair):
    # the pillar stands in front of the wall: no triangle joins the two (no closest point in the gap between)
    scan = room_pair[1]
    surface = surface_of(scan)
    T_world = scan.pose
    pillar_front = np.array([2.2, 1.4, 1.0]) - np.array([0.05, 0.05, 0.0])  # just outside the pillar's corner
    local = invert(T_world)[:3, :3] @ pillar_front + invert(T_world)[:3, 3]
    lengths = np.linalg.norm(scan.points[surface.faces[:, 0]] - scan.points[surface.faces[:, 1]], axis=1)
    assert lengths.max() < 2.0  # the room is 8 m wide: a bridge across the pillar's shadow would be metres long
    assert surface.closest(local[None])[1][0] > 0.0


def test_triangulate_follows_the_kind(room_pair):
    scan = room_pair[1]
    assert np.array_equal(triangulate(scan), surface_of(scan).faces)
    with pytest.raises(InputError, match="unstructured"):
        triangulate(replace(scan, kind=ScanKind.UNSTRUCTURED))


# ---- tangent planes ------------------------------------------------------------------------------------------------
def brute_force_plane_projection(points, normals, patch, queries):
    d = np.linalg.norm(queries[:, None] - points[None], axis=2)
    j = np.argmin(d, axis=1)
    out = np.empty_like(queries)
    for k, q in enumerate(queries):
        p, n = points[j[k]], normals[j[k]]
        t = (q - p) - np.dot(q - p, n) * n
        if np.linalg.norm(t) > patch[j[k]]:
            t *= patch[j[k]] / np.linalg.norm(t)
        out[k] = p + t
    return out


def test_the_closest_point_on_tangent_planes_is_the_projection_onto_the_nearest_points_plane():
    rng = np.random.default_rng(5)
    xy = rng.uniform(-1, 1, (400, 2))
    pts = np.c_[xy, 0.2 * np.sin(2 * xy[:, 0]) + 0.1 * xy[:, 1] ** 2 + rng.normal(0, 0.003, 400)]
    scan = Scan(points=pts, viewpoint=np.array([0.0, 0.0, 5.0]), units="m", kind=ScanKind.UNSTRUCTURED)
    surface = surface_of(scan)
    assert isinstance(surface, TangentPlanes) and surface.n_triangles == 0
    assert np.allclose(np.linalg.norm(surface.normals, axis=1), 1.0)
    queries = np.r_[pts[:50] + rng.normal(0, 0.02, (50, 3)), rng.uniform(-1.5, 1.5, (50, 3))]
    c, d2, n = surface.closest_with_normals(queries)
    expected = brute_force_plane_projection(pts, surface.normals, surface.patch, queries)
    assert np.allclose(c, expected, atol=1e-12)
    assert np.allclose(d2, np.sum((queries - expected) ** 2, axis=1))
    # every closest point stays on its patch, and the patches are PATCH_SPACINGS local spacings wide
    assert np.all(np.linalg.norm(c - pts[surface.tree.query(queries)[1]], axis=1) <= surface.patch.max() + 1e-12)
    assert np.median(surface.patch) == pytest.approx(PATCH_SPACINGS * np.median(
        surface.tree.query(pts, 5)[0][:, 1:].mean(1)))
    # the bound used to skip far queries agrees with the exact distances
    within = surface.squared_distances_within(queries, 0.05)
    near = d2 <= 0.05 ** 2
    assert np.allclose(within[near], d2[near]) and np.all(within[~near] > 0.05 ** 2)


def test_a_large_batch_far_from_the_cloud_finds_the_same_nearest_points_as_one_near_it():
    # far queries go to a BVH of tiny triangles (core.unstructured.FAR_SPACINGS), near ones to the k-d tree: the
    # closest points agree with the tree's everywhere, to float32's rounding of which point is nearest
    from rangereg.core.surface import PARALLEL_QUERY
    from rangereg.core.unstructured import FAR_SPACINGS

    rng = np.random.default_rng(6)
    xy = rng.uniform(-2, 2, (20000, 2))
    pts = np.c_[xy, 0.3 * np.sin(xy[:, 0]) * np.cos(xy[:, 1])]
    surface = surface_of(Scan(points=pts, viewpoint=np.zeros(3), units="m", kind=ScanKind.UNSTRUCTURED))
    n = PARALLEL_QUERY + 5000
    near = pts[rng.integers(0, len(pts), n // 2)] + rng.normal(0, 0.002, (n // 2, 3))
    far = rng.uniform(-6, 6, (n - n // 2, 3)) + [0.0, 0.0, 8.0]
    q = np.r_[near, far]
    assert np.mean(surface.tree.query(far)[0] > FAR_SPACINGS * surface.spacing) > 0.95
    c, d2, _ = surface.closest_with_normals(q)
    c_one, d2_one = zip(*(surface.closest_with_normals(q[k:k + 1000])[:2] for k in range(0, n, 1000)))  # small batches:
    c_one, d2_one = np.concatenate(c_one), np.concatenate(d2_one)  # the tree alone
    assert np.array_equal(c[: n // 2], c_one[: n // 2])  # near the cloud: the tree's answer, bit for bit
    assert np.mean(np.all(c == c_one, axis=1)) > 0.99  # the rest: another of near-equally near points, its plane's
    assert np.max(np.abs(np.sqrt(d2) - np.sqrt(d2_one))) <= surface.patch.max()  # projection within a patch


def test_rays_hit_tangent_planes_where_the_surface_is():
    rng = np.random.default_rng(4)
    xy = rng.uniform(-1, 1, (2000, 2))
    pts = np.c_[xy, np.zeros(2000)]
    surface = surface_of(Scan(points=pts, viewpoint=np.zeros(3), kind=ScanKind.UNSTRUCTURED))
    origins = np.c_[rng.uniform(-0.8, 0.8, (50, 2)), np.full(50, 2.0)]
    down = np.tile([0.0, 0.0, -1.0], (50, 1))
    assert np.allclose(surface.first_hit(origins, down), 2.0, atol=1e-5)
    assert np.all(np.isinf(surface.first_hit(origins + [5.0, 0.0, 0.0], down)))  # beside the cloud: no patch


def test_normals_of_tangent_planes_follow_the_surface():
    rng = np.random.default_rng(2)
    xy = rng.uniform(-1, 1, (3000, 2))
    pts = np.c_[xy, 0.3 * xy[:, 0]]  # a tilted plane
    surface = TangentPlanes.from_scan(Scan(points=pts, viewpoint=np.zeros(3), kind=ScanKind.UNSTRUCTURED))
    true = np.array([-0.3, 0.0, 1.0]) / np.linalg.norm([-0.3, 0.0, 1.0])
    assert np.all(np.abs(surface.normals @ true) > 0.999)


def test_tangent_planes_on_rings_reach_past_each_ring_to_the_surface():
    # a spinning LiDAR's rings on a tilted plane: points 1 cm apart along each ring, rings 25 cm apart; the
    # neighbours within 5 spacings lie on the ring alone, a line with no plane. They reach past it to the next rings.
    x, y = np.meshgrid(np.arange(-2, 2, 0.01), np.arange(-1, 1.01, 0.25))
    pts = np.c_[x.ravel(), y.ravel(), 0.3 * y.ravel()]
    surface = TangentPlanes.from_scan(Scan(points=pts, viewpoint=np.zeros(3), kind=ScanKind.UNSTRUCTURED))
    true = np.array([0.0, -0.3, 1.0]) / np.linalg.norm([0.0, -0.3, 1.0])
    assert np.all(np.abs(surface.normals @ true) > 0.999)


@pytest.mark.skipif(not LIDAR.exists(), reason="the shared LiDAR data is absent")
def test_the_shared_lidar_pair_read_as_unstructured_is_not_trusted_wrong():
    # its rings read as an unstructured cloud (--scan-kind): each plane was fitted to one ring's points, a line,
    # and the identity was trusted 0.67 deg / 50 cm off the truth
    from rangereg.core.guess import Guess
    from rangereg.core.io import load_pair
    from rangereg.core.transforms import pose_error

    s, t = load_pair(LIDAR / "251371071.pcd", LIDAR / "251370668.pcd", kind="unstructured")
    res = register(s, t, Guess.none(), Config(method="global"))
    rot, move = pose_error(res.transform, np.loadtxt(LIDAR / "relative.txt"))
    assert (rot < 1.0 and move < 0.05) or not res.trusted, (rot, move)


# ---- overlap per kind ---------------------------------------------------------------------------------------------
def _kinds(room_pair):
    from rangereg.core.simulate import make_scene

    single = make_scene("corner", 0)[0]
    pano = room_pair[1]
    return {"single view": single, "panorama": pano, "unstructured": replace(pano, kind=ScanKind.UNSTRUCTURED)}


@pytest.mark.parametrize("kind", ["single view", "panorama", "unstructured"])
def test_a_scan_overlaps_itself_under_the_identity_and_not_under_a_far_pose(room_pair, kind):
    scan = _kinds(room_pair)[kind]
    surface = Surface.from_scan(scan)
    rot, trans = np.radians(2.0), 0.01 * scan.size
    cut = overlap_cut(scan, scan, surface, np.eye(4), "convex", True, rot, trans)
    assert cut is not None and cut.name == "frustum" and cut.used.mean() > 0.9
    assert cut.overlap.source_fraction > 0.95 and cut.overlap.target_fraction > 0.95
    far = np.eye(4)
    far[:3, 3] = 10 * scan.size
    assert overlap_cut(scan, scan, surface, far, "convex", True, rot, trans) is None
    view = frustum_of(scan)
    assert view.contains(scan.points).mean() > 0.95
    assert view.contains(scan.points + far[:3, 3]).mean() < 0.05 or kind == "panorama"


@pytest.mark.parametrize("kind", ["panorama", "unstructured"])
def test_a_view_widens_with_the_angle(room_pair, kind):
    scan = _kinds(room_pair)[kind]
    view = frustum_of(scan)
    moved = scan.points @ Rotation.from_euler("x", 40, degrees=True).as_matrix().T + [0.0, 0.0, 1.5]
    masks = [view.widened(moved, np.radians(a)) for a in (0.0, 2.0, 10.0, 30.0, 90.0)]
    assert np.array_equal(masks[0], view.contains(moved))
    for a, b in zip(masks, masks[1:]):
        assert np.all(b[a])  # opening never drops a point
    assert masks[-1].all() and masks[-2].sum() > masks[0].sum()


def test_a_cloud_view_says_which_points_lie_within_a_distance_as_brute_force_does():
    # the coarse subset (core.unstructured.COARSE_CELL_NEARS) only decides which points the whole tree is asked about
    from scipy.spatial.distance import cdist

    rng = np.random.default_rng(11)
    xy = rng.uniform(-2, 2, (6000, 2))
    pts = np.r_[np.c_[xy, 0.3 * np.sin(xy[:, 0]) * np.cos(xy[:, 1])], rng.uniform(2.5, 3.0, (20, 3))]  # and a speck
    view = frustum_of(Scan(points=pts, viewpoint=np.zeros(3), units="m", kind=ScanKind.UNSTRUCTURED))
    q = np.r_[rng.uniform(-4, 4, (3000, 3)), pts[rng.integers(0, len(pts), 500)] + rng.normal(0, 0.05, (500, 3))]
    nearest = cdist(q, pts).min(axis=1)
    for distance in (view.near, 2 * view.near, 10 * view.near, 0.5, 1.5):
        clear = np.abs(nearest - distance) > 1e-9  # no tie at the bound
        got = view.contains(q) if distance == view.near else view.guessed(None, q, np.zeros(len(q), bool),
                                                                           distance - view.near)
        assert np.array_equal(got[clear], (nearest < distance)[clear])
        assert 0 < got.sum() < len(q)


def test_a_cloud_view_settles_the_shell_and_the_ties_at_its_bound_as_its_whole_tree_does():
    # a grid 1 apart (near 3, cubes of 9): the first point of each cube stands for it; a query within the distance of
    # a point its cube's first point is far from is inside, one exactly at the distance of a point is not (the whole
    # tree's strict bound)
    xy = np.stack(np.meshgrid(np.arange(20.0), np.arange(20.0), indexing="ij"), axis=-1).reshape(-1, 2)
    view = frustum_of(Scan(points=np.c_[xy, np.zeros(len(xy))], viewpoint=np.zeros(3), units="m",
                           kind=ScanKind.UNSTRUCTURED))
    assert view.near == 3.0
    q = np.array([[8.0, 8.0, 4.99], [9.0, 9.0, 5.0], [4.0, 4.0, 5.01]])
    got = view.guessed(None, q, np.zeros(len(q), bool), 2.0)
    assert got.tolist() == [True, False, False]


def test_a_panorama_hides_what_lies_behind_its_surface(room_pair):
    scan = room_pair[1]
    view = frustum_of(scan)
    behind = scan.points * 1.5  # out through the walls
    reach = np.linalg.norm(behind, axis=1) <= view.far
    assert reach.mean() > 0.5 and view.contains(behind)[reach].mean() > 0.9  # seen directions within reach
    assert view.visible(None, behind, 0.1).mean() < 0.05
    assert view.visible(None, scan.points, 0.1).mean() > 0.99
    assert view.wireframe().shape == (0, 2, 3)


# ---- registration ------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("method", ["icp", "hybrid"])
def test_a_simulated_panorama_pair_is_registered_from_the_identity(room_pair, method):
    source, target, T_true = room_pair
    res = register(source, target, np.eye(4), Config(method=method, threshold=1e-4))
    deg, shift = angle_and_shift(res.transform, T_true)
    assert deg < 0.5 and shift < 0.02, (deg, shift)


def test_unstructured_clouds_are_registered_from_the_identity(room_pair):
    source, target, T_true = room_pair
    src, tgt = (replace(s, kind=ScanKind.UNSTRUCTURED, viewpoint=np.array([50.0, 0.0, 0.0])) for s in (source, target))
    res = register(src, tgt, np.eye(4), Config(method="icp"))
    deg, shift = angle_and_shift(res.transform, T_true)
    assert deg < 0.5 and shift < 0.02, (deg, shift)


def _lidar(name: str) -> Scan:
    import open3d as o3d

    p = np.asarray(o3d.io.read_point_cloud(str(LIDAR / name)).points, dtype=np.float64)
    p = p[np.linalg.norm(p, axis=1) > 0]  # the frames hold the returns that came back as (0, 0, 0)
    return Scan(points=p, viewpoint=np.zeros(3), units="m", kind=ScanKind.PANORAMA, name=name)


@pytest.mark.skipif(not (LIDAR / "relative.txt").exists(), reason="shared LiDAR data absent")
def test_the_shared_lidar_pair_is_registered_from_the_identity():
    # relative.txt is T_target_source for target 251370668, source 251371071 (the source 0.49 m further along):
    # under it the source lies 2 cm from the target's surface (median), under its inverse 13 cm
    target, source = _lidar("251370668.pcd"), _lidar("251371071.pcd")
    T_true = np.loadtxt(LIDAR / "relative.txt")
    res = register(source, target, np.eye(4), Config(method="icp"))
    deg, shift = angle_and_shift(res.transform, T_true)
    assert deg < 1.0 and shift < 0.05, (deg, shift)
