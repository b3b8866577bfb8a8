"""Surfaces, closest points and frustums: property tests and brute force as the reference."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from rangereg.core.frustum import frustum_of, segment_overlap
from rangereg.core.scan import Scan
from rangereg.core.surface import EDGE_FACTOR, Surface, closest_on_triangles, edge_lengths, local_spacing, triangulate
from rangereg.core.transforms import apply, delta_between, from_params, invert, perturb, rotation_angle, rotation_matrix
from scipy.spatial import Delaunay

from tests.conftest import brute_closest

_vec = st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3).map(np.array)


@settings(max_examples=200, deadline=None)
@given(_vec, _vec, _vec)
def test_rotation_helpers_agree_with_scipy_and_perturb_inverts(rotvec, shift, center):
    from scipy.spatial.transform import Rotation

    R = rotation_matrix(rotvec)
    assert np.allclose(R, Rotation.from_rotvec(rotvec).as_matrix(), atol=1e-12)
    assert np.isclose(rotation_angle(R), Rotation.from_matrix(R).magnitude(), atol=1e-6)
    base = from_params(np.r_[shift * 100, shift[::-1]])
    delta = np.r_[shift * 10, rotvec * 0.3]  # rotations under pi: the rotation vector is unique
    again = perturb(base, delta_between(perturb(base, delta, center), base, center), center)
    assert np.allclose(again, perturb(base, delta, center), atol=1e-9)


def _edges_within_bound(points, faces):
    s = local_spacing(points)
    L = edge_lengths(points, faces)
    bound = EDGE_FACTOR * np.maximum(s[faces], s[np.roll(faces, -1, axis=1)])
    return np.all(L <= bound + 1e-12)


def test_neighbourhood_fits_in_parts_per_core_give_the_whole_arrays_bits():
    from rangereg.core.surface import PARALLEL_SPREADS, _spreads, spreads

    rng = np.random.default_rng(3)
    nb = rng.normal(size=(PARALLEL_SPREADS + 1001, 12, 3)) * [1.0, 0.5, 0.01]
    whole, parts = _spreads(nb), spreads(nb)
    assert np.array_equal(whole[0], parts[0]) and np.array_equal(whole[1], parts[1])
    view = nb[::-1]  # a view with negative strides: the parts are views too
    assert np.array_equal(_spreads(view)[0], spreads(view)[0])


def test_grid_surface_edges_respect_the_culling_bound(bunny):
    s = bunny("bun045")
    faces = triangulate(s)
    assert len(faces) > 70000
    assert _edges_within_bound(s.points, faces)


def test_a_scans_surface_shares_its_tree_and_measures_its_reach_as_afresh(bunny, scene):
    for s in (bunny("bun045"), scene("bowl")[0]):
        surface = Surface.from_scan(s)
        assert surface.tree is s.tree  # one k-d tree of the scan's points, not two
        afresh = Surface(surface.vertices, surface.faces)
        assert afresh.reach == float(edge_lengths(s.points, surface.faces).max()) == surface.reach
        q = s.points[::97] + 0.5 * s.spacing
        assert np.array_equal(surface.squared_distances_within(q, 2 * s.spacing),
                              afresh.squared_distances_within(q, 2 * s.spacing))


def test_a_surface_warmed_on_a_thread_answers_as_one_built_by_its_first_query(scene):
    from concurrent.futures import ThreadPoolExecutor

    s = scene("bowl")[0]
    q = s.points[::31] + np.random.default_rng(2).normal(0, 5.0, (len(s.points[::31]), 3))
    cold = Surface.from_scan(s).closest_with_normals(q)
    warm = Surface.from_scan(s).warm()
    with ThreadPoolExecutor(4) as pool:  # queries from several threads while it builds: one build, the same answers
        answers = list(pool.map(lambda _: warm.closest_with_normals(q), range(4)))
    for got in answers + [warm.closest_with_normals(q)]:
        assert all(np.array_equal(a, b) for a, b in zip(got, cold))


def test_delaunay_surface_never_bridges_a_depth_jump():
    rng = np.random.default_rng(1)
    near = np.c_[rng.uniform(-1, 0, (800, 2)), np.full(800, -5.0)]
    far = np.c_[rng.uniform(0, 1, (800, 2)), np.full(800, -9.0)]  # a 4-unit depth jump at x = 0
    pts = np.vstack([near, far]) + rng.normal(0, 0.002, (1600, 3))
    scan = Scan(points=pts, viewpoint=np.zeros(3))
    faces = triangulate(scan)
    assert _edges_within_bound(pts, faces)
    crosses = (pts[faces][:, :, 2] > -7).any(1) & (pts[faces][:, :, 2] < -7).any(1)
    assert not crosses.any()
    # faces are wound towards the sensor
    p = pts[faces]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    assert np.all(np.einsum("ij,ij->i", n, -p[:, 0]) > 0)


def test_closest_points_equal_brute_force(scene):
    a, _ = scene("bowl")
    surf = Surface.from_scan(a)
    rng = np.random.default_rng(0)
    q = a.points[rng.integers(0, len(a.points), 25)] + rng.normal(0, 8.0, (25, 3))
    _, d2 = surf.closest(q)
    tris = a.points[surf.faces]
    for qi, di in zip(q, d2):
        near = tris[np.min(np.linalg.norm(tris - qi, axis=2), axis=1) < np.sqrt(di) + 60]
        assert abs(brute_closest(qi, near) - di) < 1e-3 * max(di, 1.0)


@settings(max_examples=40, deadline=None)
@given(st.integers(0, 10_000))
def test_frustum_containment_matches_its_planes(seed):
    rng = np.random.default_rng(seed)
    n = int(rng.integers(20, 200))
    pts = np.c_[rng.uniform(-1, 1, (n, 2)), rng.uniform(-6, -4, n)]
    scan = Scan(points=pts, viewpoint=np.zeros(3))
    f = frustum_of(scan)
    # Every scan point is inside its own frustum.
    assert f.contains(pts).all()
    # Reference: a point is inside iff it is in front of the sensor and on the inner side of every
    # plane through the sensor and two consecutive outline corners.
    corners = f.outline_points(1.0)
    inner = corners.mean(0)
    q = rng.uniform(-3, 3, (300, 3)) + np.array([0, 0, -3])
    expect = np.ones(len(q), bool)
    for c0, c1 in zip(corners, np.roll(corners, -1, axis=0)):
        normal = np.cross(c0, c1)
        if normal @ inner < 0:
            normal = -normal
        expect &= q @ normal >= -1e-9
    expect &= q @ f.basis[2] > 0
    got = f.contains(q)
    margin = np.abs(q @ f.basis[2]) > 1e-6
    assert np.array_equal(got[margin], expect[margin])


def _all_facets(f, points, with_margin=False):
    """The frustum test as first written: every point against every hull facet ((N, K) floats).

    ``with_margin``: also the distance of each point's worst facet value from the 1e-12 tolerance;
    within a few 1e-16 of it, rounding (the order of a dot product's two terms) decides."""
    uv, depth = f.project(points)
    inside = np.zeros(len(points), bool)
    margin = np.full(len(points), np.inf)
    front = depth > 0
    worst = np.max(uv[front] @ f.equations[:, :2].T + f.equations[:, 2], axis=1)
    inside[front] = worst <= 1e-12
    margin[front] = np.abs(worst - 1e-12)
    return (inside, margin) if with_margin else inside


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 10_000), st.sampled_from(["disc", "square", "sliver", "few"]))
def test_frustum_wedge_search_equals_the_all_facets_test(seed, shape):
    rng = np.random.default_rng(seed)
    n = {"few": 4, "disc": 3000}.get(shape, 400)
    if shape == "disc":  # many outline corners, as a dense scan has
        r, th = np.sqrt(rng.random(n)), rng.uniform(0, 2 * np.pi, n)
        xy = np.c_[r * np.cos(th), r * np.sin(th)]
    elif shape == "sliver":
        xy = np.c_[rng.uniform(-1, 1, n), rng.uniform(-0.01, 0.01, n)]
    else:
        xy = rng.uniform(-1, 1, (n, 2))
    pts = np.c_[xy * rng.uniform(0.5, 3), rng.uniform(-6, -4, n)]
    scan = Scan(points=pts, viewpoint=rng.normal(0, 0.2, 3))
    f = frustum_of(scan)
    # random points around it, the scan's own points (its outline corners lie exactly on facets),
    # and points just either side of the outline edges
    corners = f.outline_points(5.0)
    k = rng.integers(0, len(corners), 500)
    edge = corners[k] + rng.random((500, 1)) * (np.roll(corners, -1, axis=0)[k] - corners[k])
    probes = [rng.normal(0, 3, (2000, 3)) + pts.mean(0), pts, f.outline_points(2.0),
              edge + rng.normal(0, 1e-9, edge.shape)]
    for q in probes:
        expect, margin = _all_facets(f, q, with_margin=True)
        decided = margin > 1e-15
        assert np.array_equal(f.contains(q)[decided], expect[decided])


def test_frustum_membership_on_the_bunny_pairs_equals_the_all_facets_test(bunny):
    names = ("bun000", "bun045", "bun090", "bun315")
    for a in names:
        for b in names:
            target, source = bunny(a), bunny(b)
            for kind in ("convex", "nonconvex"):
                f = frustum_of(target, kind)
                q = apply(invert(target.pose) @ source.pose, source.points)
                expect = _all_facets(f, q)
                if kind == "nonconvex":
                    uv, _ = f.project(q)
                    ij = np.floor((uv - f.mask_origin) / f.cell).astype(np.int64)
                    ok = np.all((ij >= 0) & (ij < f.mask.shape), axis=1)
                    ok[ok] = f.mask[ij[ok, 0], ij[ok, 1]]
                    expect &= ok
                assert np.array_equal(f.contains(q), expect), (a, b, kind)


def test_bunny_overlap_under_truth_and_90_degrees_off(bunny):
    src, tgt = bunny("bun045"), bunny("bun000")
    T = invert(tgt.pose) @ src.pose
    good = segment_overlap(src, tgt, T)
    assert good.source_fraction > 0.8 and good.target_fraction > 0.8
    # The scans are views around the vertical (y) axis; a guess a further 90 degrees around it:
    off = from_params([0, 0, 0, 0, np.pi / 2, 0]) @ T
    bad = segment_overlap(src, tgt, off)
    assert bad.source_fraction < good.source_fraction - 0.2


def test_nonconvex_frustum_drops_what_the_convex_one_keeps():
    # An L-shaped scan: the convex frustum covers the missing corner, the footprint does not.
    u, v = np.meshgrid(np.linspace(-1, 1, 60), np.linspace(-1, 1, 60))
    keep = ~((u > 0) & (v > 0))
    pts = np.c_[u[keep], v[keep], np.full(keep.sum(), -5.0)]
    scan = Scan(points=pts, viewpoint=np.zeros(3))
    probe = np.array([[0.3, 0.3, -5.0], [-0.5, -0.5, -5.0]])
    assert frustum_of(scan, "convex").contains(probe).tolist() == [True, True]
    assert frustum_of(scan, "nonconvex").contains(probe).tolist() == [False, True]


def test_distances_within_a_radius_are_exact_there_and_inf_only_beyond_it(scene):
    from rangereg.core.surface import Surface

    target, _ = scene("corner")
    surface = Surface.from_scan(target)
    rng = np.random.default_rng(3)
    on = target.points[rng.choice(len(target.points), 400)]
    query = on + rng.normal(size=on.shape) * rng.choice([0.1, 5.0, 50.0, 500.0], size=(len(on), 1))
    points, exact = surface.closest(query)
    for radius in (1.0, 20.0, 200.0):
        d2 = surface.squared_distances_within(query, radius)
        within = exact <= radius**2
        assert np.array_equal(d2[within], exact[within])  # exact (the same query) wherever it matters
        assert np.all(exact[np.isinf(d2)] > radius**2)  # inf only where the surface is surely farther
        assert np.all(np.isinf(d2) | (d2 == exact))
        near, d2_near = surface.closest_within(query, radius)  # and the points, where it gives them
        assert np.array_equal(d2_near, d2) and np.array_equal(np.isnan(near).any(axis=1), np.isinf(d2))
        assert np.array_equal(near[np.isfinite(d2)], points[np.isfinite(d2)])


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 10_000))
def test_the_closest_point_on_a_triangle_lies_on_it_and_no_point_of_it_is_nearer(seed):
    rng = np.random.default_rng(seed)
    a, b, c = (rng.normal(size=(200, 3)) for _ in range(3))
    p = 2 * rng.normal(size=(200, 3))
    got, normals = closest_on_triangles(p, a, b, c)
    # on the triangle: barycentric coordinates in [0, 1]
    m = np.stack([b - a, c - a], axis=2)
    for k in range(len(p)):
        uv = np.linalg.lstsq(m[k], got[k] - a[k], rcond=None)[0]
        assert uv.min() >= -1e-9 and uv.sum() <= 1 + 1e-9
    # nearer than every point of a dense barycentric grid (the grid's own spacing apart at most)
    u, v = np.meshgrid(np.linspace(0, 1, 81), np.linspace(0, 1, 81))
    keep = u + v <= 1
    grid = a[:, None] + (b - a)[:, None] * u[keep][None, :, None] + (c - a)[:, None] * v[keep][None, :, None]
    brute = np.min(np.sum((grid - p[:, None]) ** 2, axis=2), axis=1)
    ours = np.sum((got - p) ** 2, axis=1)
    assert np.all(ours <= brute + 1e-12)
    assert np.all(np.sqrt(brute) - np.sqrt(ours) <= 0.05 * np.linalg.norm(b - a, axis=1) + 0.05 * np.linalg.norm(c - a, axis=1))
    assert np.allclose(np.linalg.norm(normals, axis=1), 1.0)


def test_surface_distances_are_exact_in_float64_where_float32_would_round():
    # a tilted plane a few units across, queries 0.1 mm above it: float32 points (7 digits) would misplace
    # the closest point by ~1e-7 units, a relative error of ~1e-3 in the squared distance
    x, y = np.meshgrid(np.linspace(-3, 3, 13), np.linspace(-3, 3, 13))
    n = np.array([0.3, 0.2, -1.0]) / np.linalg.norm([0.3, 0.2, -1.0])
    verts = np.column_stack([x.ravel(), y.ravel(), 0.3 * x.ravel() + 0.2 * y.ravel()]) + [1000.0, 2000.0, 500.0]
    faces = Delaunay(verts[:, :2]).simplices.astype(np.int64)
    surf = Surface(verts, faces)
    rng = np.random.default_rng(1)
    on = verts.mean(0) + rng.uniform(-2, 2, (50, 1)) * [1, 0, 0.3] + rng.uniform(-2, 2, (50, 1)) * [0, 1, 0.2]
    h = rng.uniform(1e-5, 1e-4, 50)
    q = on + h[:, None] * n
    c, d2, normals = surf.closest_with_normals(q)
    assert np.allclose(d2, h**2, rtol=1e-6, atol=0)  # float32 points: ~4e-3
    assert np.allclose(np.abs(normals @ n), 1.0, atol=1e-12)
