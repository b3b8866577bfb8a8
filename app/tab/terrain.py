"""The slice as a height field in the 3-D scene (Landscape tab), beside the scans, with the run's path on it.

The terrain's box is the slice's two parameter axes (horizontal) by log10 E (up), scaled to
TERRAIN_SIZE page units and placed at TERRAIN_AT: an abstract space beside the scans, labelled with
the parameters and their units. The path is drawn on the surface (ICP green, SA magenta), the local
minima as red points, the shown pose as a white point. The projection of the events onto the slice's
axes is kept incrementally (each event is projected once), so the path follows a run live; the
Landscape panel shares one such projection between the terrain and the contour. During a run only the
shown pose's marker moves on every push; the mesh is sent once per slice and the path in batches.
"""

from __future__ import annotations

import numpy as np
from rangereg.app.figures import MINIMUM_RGB, PHASE_TABLE, axis_label, fmt, log_values, phase_code, squared_unit
from rangereg.app.tab.scene3d import MARKER
from rangereg.app.views import phase_ends, thin
from rangereg.core.landscape import Slice, project
from scipy.interpolate import RegularGridInterpolator

TERRAIN_AT = (1.4, -0.4, 0.0)  # page units: right of the scans (the page scales the target to size 1)
TERRAIN_SIZE = 1.0  # width and depth of the box; its height is HEIGHT
HEIGHT = 0.5
LIFT = 0.01  # the path floats this far above the surface, so the surface never hides it
TICK_OFFSET = 0.1  # the tick values sit this far outside the box, the axis names farther: off the surface
SLICE_MINIMUM_RGB = (200, 200, 200)  # the slice's own minima on the terrain: grey dots, as the contour's white
# rings (red is the run's own local minimum alone: the lesson's "red marker")
MAX_TERRAIN_PATH = 300  # points drawn at most, plus phase ends and minima (the projection keeps every event; see
# app/views.MAX_PATH_POINTS for what a segment costs a software-rendered page)


def heights(sl: Slice) -> np.ndarray:
    """(A, B) heights in page units: log10 E mapped to [0, HEIGHT]."""
    z = log_values(sl)
    span = max(float(np.nanmax(z) - np.nanmin(z)), 1e-12)
    return (z - np.nanmin(z)) / span * HEIGHT


def to_box(sl: Slice, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal page coordinates (K,), (K,) of slice coordinates (K, 2), clipped to the slice's box."""
    a = np.clip(xy[:, 0], sl.axis_a[0], sl.axis_a[-1])
    b = np.clip(xy[:, 1], sl.axis_b[0], sl.axis_b[-1])
    u = (a - sl.axis_a[0]) / (sl.axis_a[-1] - sl.axis_a[0]) - 0.5
    v = (b - sl.axis_b[0]) / (sl.axis_b[-1] - sl.axis_b[0]) - 0.5
    return u * TERRAIN_SIZE, v * TERRAIN_SIZE


def surface(sl: Slice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V, 3) float32 vertices, (F, 3) faces and (V, 4) uint8 viridis colours of the height field."""
    import matplotlib

    h = heights(sl)
    A, B = np.meshgrid(sl.axis_a, sl.axis_b, indexing="ij")
    x, z = to_box(sl, np.c_[A.ravel(), B.ravel()])
    vertices = np.c_[x, h.ravel(), z].astype(np.float32)
    na, nb = h.shape
    i, j = np.meshgrid(np.arange(na - 1), np.arange(nb - 1), indexing="ij")
    k = (i * nb + j).ravel()
    faces = np.r_[np.c_[k, k + 1, k + nb], np.c_[k + 1, k + nb + 1, k + nb]].astype(np.int32)
    rgba = (matplotlib.colormaps["viridis"](h.ravel() / HEIGHT) * 255).astype(np.uint8)
    return vertices, faces, rgba


def log_range(sl: Slice) -> tuple[float, float]:
    """(lowest, highest) log10 E of the slice: the heights 0 and HEIGHT."""
    z = log_values(sl)
    return float(np.nanmin(z)), float(np.nanmax(z))


def ticks(axis: np.ndarray, count: int = 5) -> np.ndarray:
    """About ``count`` round values inside ``axis``'s range (the terrain's tick labels)."""
    lo, hi = float(axis[0]), float(axis[-1])
    raw = (hi - lo) / max(count - 1, 1)
    step = 10 ** np.floor(np.log10(raw)) if raw > 0 else 1.0
    step *= min((m for m in (1, 2, 2.5, 5, 10) if m * step >= raw), default=10)
    return np.arange(np.ceil(lo / step) * step, hi + 1e-9 * step, step)


def colour_bar(width: float = 0.04, rows: int = 32) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V, 3) vertices, (F, 3) faces and (V, 3) uint8 viridis colours of an upright strip HEIGHT high: the terrain's
    colour scale (its heights are log10 E, coloured as the surface)."""
    import matplotlib

    y = np.linspace(0.0, HEIGHT, rows + 1)
    vertices = np.c_[np.r_[np.zeros(rows + 1), np.full(rows + 1, width)], np.r_[y, y], np.zeros(2 * rows + 2)]
    k = np.arange(rows)
    faces = np.r_[np.c_[k, k + rows + 1, k + 1], np.c_[k + 1, k + rows + 1, k + rows + 2]].astype(np.int32)
    rgb = (matplotlib.colormaps["viridis"](np.r_[y, y] / HEIGHT)[:, :3] * 255).astype(np.uint8)
    return vertices.astype(np.float32), faces, rgb


def height_lookup(sl: Slice) -> RegularGridInterpolator:
    return RegularGridInterpolator((sl.axis_a, sl.axis_b), heights(sl), bounds_error=False, fill_value=None)


def on_surface(sl: Slice, xy: np.ndarray, lookup: RegularGridInterpolator | None = None) -> np.ndarray:
    """(K, 3) float32 page points on the terrain (lifted by LIFT) for slice coordinates (K, 2)."""
    if not len(xy):
        return np.zeros((0, 3), np.float32)
    lookup = lookup or height_lookup(sl)
    a = np.clip(xy[:, 0], sl.axis_a[0], sl.axis_a[-1])
    b = np.clip(xy[:, 1], sl.axis_b[0], sl.axis_b[-1])
    x, z = to_box(sl, xy)
    return np.c_[x, lookup(np.c_[a, b]) + LIFT, z].astype(np.float32)


class PathOnSlice:
    """A run's events projected onto one slice's axes, extended as events arrive.

    xy: (K + 1, 2), the start first; phases: (K + 1,) "icp" / "sa" / "candidates" (the start counts as ICP);
    sa, minimum: (K + 1,) bool. Not thread-safe: its owner (the Landscape panel) updates it under its lock.
    """

    def __init__(self, problem, sl: Slice, T_start: np.ndarray, events: list):
        self.problem, self.slice, self.events, self.T_start = problem, sl, events, T_start
        self.xy = project(problem, sl.T_center, sl.params, [T_start])
        self.phases = np.array(["icp"], dtype=object)
        self.phase = np.zeros(1, np.int8)  # rows of PHASE_TABLE (the start's is never drawn)
        self.minimum = np.zeros(1, bool)
        self.n = 0
        self.lookup = height_lookup(sl)  # built once per slice, used on every redraw

    def follows(self, problem, sl: Slice, T_start: np.ndarray, events: list) -> bool:
        """Whether this projection is the one of these events from this start on this slice."""
        return (self.problem is problem and self.slice is sl and self.events is events
                and np.array_equal(self.T_start, T_start))

    @property
    def sa(self) -> np.ndarray:
        return self.phases == "sa"

    def update(self) -> int:
        n = len(self.events)
        new = self.events[self.n:n]
        if new:
            self.xy = np.r_[self.xy, project(self.problem, self.slice.T_center, self.slice.params, [e.T for e in new])]
            self.phases = np.r_[self.phases, np.array([e.phase for e in new], dtype=object)]
            self.phase = np.r_[self.phase, [phase_code(e.phase) for e in new]].astype(np.int8)
            self.minimum = np.r_[self.minimum, [e.local_minimum for e in new]].astype(bool)
            self.n = n
        return n

    def thinned(self, most: int) -> np.ndarray:
        """Indices of at most ``most`` (+1) points, each phase's ends and the minima always among them
        (:func:`app.views.thin`: the kept points stay put as the path grows)."""
        return thin(len(self.xy), most, phase_ends(self.phase) | self.minimum)

    def segments(self) -> tuple[np.ndarray, np.ndarray]:
        """(S, 2, 3) float32 segments on the terrain and (S, 2, 3) uint8 colours, thinned to MAX_TERRAIN_PATH."""
        if len(self.xy) < 2:
            return np.zeros((0, 2, 3), np.float32), np.zeros((0, 2, 3), np.uint8)
        keep = self.thinned(MAX_TERRAIN_PATH)
        p = on_surface(self.slice, self.xy[keep], self.lookup)
        rgb = PHASE_TABLE[self.phase[keep][1:]]
        return np.stack([p[:-1], p[1:]], axis=1), np.repeat(rgb[:, None, :], 2, axis=1)

    def minima(self) -> np.ndarray:
        return on_surface(self.slice, self.xy[self.minimum], self.lookup)


class Terrain:
    """The terrain's scene nodes for one slice; ``update`` redraws the path, ``mark`` the shown pose.

    ``path``: the projection to draw (shared with the contour); by default one of ``events`` from ``T_start``.
    """

    def __init__(self, scene, view, units: str, T_start: np.ndarray, events: list, path: PathOnSlice | None = None):
        import trimesh

        sl = view.slice
        self.view, self.scene = view, scene
        self.path = path if path is not None else PathOnSlice(view.problem, sl, T_start, events)
        self.drawn = -1  # events of the path drawn so far (-1: none yet)
        vertices, faces, rgba = surface(sl)
        self.frame = scene.add_frame("/terrain", show_axes=False, position=TERRAIN_AT)
        mesh = trimesh.Trimesh(vertices, faces, vertex_colors=rgba, process=False)
        # no shadows: the page's lights cast none (app/tab/page.py), and the surface is sent once per slice
        self.surface = scene.add_mesh_trimesh("/terrain/surface", mesh, cast_shadow=False, receive_shadow=False)
        half = 0.5 * TERRAIN_SIZE
        self._axes(scene, sl, units)
        self.segments = scene.add_line_segments("/terrain/path", np.zeros((0, 2, 3), np.float32), (0, 0, 0),
                                                thickness=3.0, thickness_units="screen")
        self.minima_node = scene.add_point_cloud("/terrain/minima", np.zeros((0, 3), np.float32), MINIMUM_RGB,
                                                 point_size=MARKER, precision="float32", point_shape="circle")
        xy = sl.minima()
        self.slice_minima = scene.add_point_cloud("/terrain/slice_minima", on_surface(sl, xy, self.path.lookup),
                                                  SLICE_MINIMUM_RGB, point_size=0.5 * MARKER, precision="float32",
                                                  point_shape="circle")
        self.current = scene.add_icosphere("/terrain/current", radius=0.02, color=(255, 255, 255))
        self.half = half

    def _axes(self, scene, sl: Slice, units: str) -> None:
        """Tick values along two edges of the box and the axis names beyond them (off the surface), and on a
        colour bar at its back corner the log10 E of the heights (the surface's colours)."""
        half, out = 0.5 * TERRAIN_SIZE, TICK_OFFSET
        for k, v in enumerate(ticks(sl.axis_a)):
            x, _ = to_box(sl, np.array([[v, sl.axis_b[0]]]))
            scene.add_label(f"/terrain/ticks_a/{k}", fmt(v, 3), anchor="center-center", position=(float(x[0]), 0.0, half + out))
        for k, v in enumerate(ticks(sl.axis_b)):
            _, z = to_box(sl, np.array([[sl.axis_a[0], v]]))
            scene.add_label(f"/terrain/ticks_b/{k}", fmt(v, 3), anchor="center-center", position=(half + out, 0.0, float(z[0])))
        scene.add_label("/terrain/label_a", axis_label(sl.params[0], units), position=(0.0, 0.0, half + 2.6 * out))
        scene.add_label("/terrain/label_b", axis_label(sl.params[1], units), position=(half + 3.2 * out, 0.0, 0.0))
        lo, hi = log_range(sl)
        import trimesh

        vertices, faces, rgb = colour_bar()
        scene.add_mesh_trimesh("/terrain/colour_bar", trimesh.Trimesh(vertices, faces, vertex_colors=rgb, process=False),
                               position=(-half - out, 0.0, -half), cast_shadow=False, receive_shadow=False)
        for k, f in enumerate((0.0, 0.5, 1.0)):
            scene.add_label(f"/terrain/ticks_e/{k}", fmt(lo + f * (hi - lo), 3), anchor="center-right",
                            position=(-half - 2.2 * out, f * HEIGHT, -half))
        scene.add_label("/terrain/label_e", f"log10 E ({squared_unit(units)})",
                        position=(-half - out, HEIGHT + out, -half))

    def extent(self) -> np.ndarray:
        """(8, 3) page points: the corners of the terrain's box (Fit view frames them)."""
        x0, y0, z0 = TERRAIN_AT
        h = 0.5 * TERRAIN_SIZE + 3 * TICK_OFFSET
        return np.array([[x0 + sx * h, y0 + y, z0 + sz * h] for sx in (-1, 1) for sz in (-1, 1) for y in (0, HEIGHT)])

    def update(self, T_shown: np.ndarray, path: bool = True) -> None:
        """Draw the shown pose, and (``path``) the events that arrived since the path was last drawn."""
        if path and self.path.update() != self.drawn:
            seg, rgb = self.path.segments()
            self.segments.points, self.segments.colors = seg, rgb
            self.minima_node.points = self.path.minima()
            self.drawn = self.path.n
        self.mark(T_shown)

    def mark(self, T_shown: np.ndarray) -> None:
        sl = self.view.slice
        xy = project(self.view.problem, sl.T_center, sl.params, [T_shown])
        self.current.position = tuple(on_surface(sl, xy, self.path.lookup)[0])

    def remove(self) -> None:
        self.frame.remove()
