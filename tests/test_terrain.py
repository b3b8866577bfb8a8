"""The slice as a 3-D height field: its surface, and a path that lies on it."""

from __future__ import annotations

import numpy as np
from rangereg.app.tab.terrain import HEIGHT, LIFT, TERRAIN_SIZE, heights, on_surface, surface
from rangereg.core.landscape import Slice


def bowl(steps: int = 9) -> Slice:
    a = np.linspace(-2.0, 2.0, steps)
    b = np.linspace(-30.0, 30.0, steps)
    A, B = np.meshgrid(a, b, indexing="ij")
    return Slice(("tx", "ry"), a, b, 1e-3 + A**2 + (B / 15.0) ** 2, np.eye(4))


def test_the_height_field_spans_the_box_lowest_at_the_minimum():
    sl = bowl()
    v, f, rgba = surface(sl)
    assert v.shape == (81, 3) and f.shape == (2 * 64, 3) and rgba.shape == (81, 4)
    assert np.allclose([v[:, 0].min(), v[:, 0].max()], [-TERRAIN_SIZE / 2, TERRAIN_SIZE / 2])
    h = heights(sl)
    assert np.isclose(h.min(), 0.0) and np.isclose(h.max(), HEIGHT) and np.argmin(h) == 40  # the centre


def test_a_path_lies_on_the_surface_and_is_clipped_to_its_box():
    sl = bowl()
    p = on_surface(sl, np.array([[0.0, 0.0], [2.0, 30.0], [50.0, 0.0]]))
    h = heights(sl)
    assert np.isclose(p[0, 1], h[4, 4] + LIFT) and np.isclose(p[1, 1], h[-1, -1] + LIFT)
    assert np.isclose(p[2, 0], TERRAIN_SIZE / 2)  # beyond the slice: on its edge


def test_a_run_is_projected_onto_the_slice_in_one_batch_as_the_problem_measures_each_pose():
    from pathlib import Path

    from rangereg.core.io import load_scan
    from rangereg.core.landscape import project
    from rangereg.core.problem import prepare, relative_guess
    from rangereg.core.transforms import PARAM_NAMES
    from scipy.spatial.transform import Rotation

    corner = Path(__file__).resolve().parent.parent / "assets" / "corner"
    source, target = load_scan(corner / "scan2.ply"), load_scan(corner / "scan1.ply")
    T0 = relative_guess(source, target)
    problem = prepare(source, target, T0, seed=0)
    rng = np.random.default_rng(1)
    poses = []
    for _ in range(20):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix(), rng.normal(0, 5.0, 3)
        poses.append(T @ T0)
    for params in (("tx", "ry"), ("rz", "ty"), ("rx", "tz")):
        one_by_one = [[problem.coords(T, poses[0])[PARAM_NAMES.index(p)] * (problem.scale if p[0] == "t" else 1)
                       for p in params] for T in poses]
        one_by_one = [[v if p[0] == "t" else np.degrees(v) for v, p in zip(row, params)] for row in one_by_one]
        np.testing.assert_allclose(project(problem, poses[0], params, poses), one_by_one, atol=1e-9)
    assert project(problem, T0, ("tx", "ry"), []).shape == (0, 2)
