"""Point-pair coarse alignment (Pose tab): click a source point, then its partner on the target.

A click in the scene gives a ray (viser's scene click event, page coordinates); the scan point
taken is the one drawn under the click (within its drawn half width, or PICK_PIXELS where the scan is
drawn smaller than that; in a hole between points, within three spacings), on the surface nearest the
camera, nearest the ray. Three or more pairs give a pose by Horn's closed form
(core.horn.weighted_horn), which becomes the initial guess. The gizmo is hidden while picking: it sits
on the source's middle and takes the clicks there.

Each pick is marked by its label ("S1", "T1": source or target, and the pair's number), centred on the
picked point and drawn over the scans (no depth test), and a small ball of the pick's colour round it.
A depth-tested marker is half hidden by the scan's own points wherever the surface leans away from the
screen, and what shows of it sits beside the click (15-45 px on the bunny zoomed in).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import viser
from rangereg.app.figures import SOURCE_PICK_RGB, TARGET_PICK_RGB, fmt
from rangereg.core.errors import InputError
from rangereg.core.horn import weighted_horn
from rangereg.core.transforms import apply

MIN_PAIRS = 3
PICK_PIXELS = 2.5  # a click this many pixels from a drawn point still picks it, however far the camera is: a point
# is drawn at least a pixel or two wide, and zoomed out the scan's spacing is less than a pixel
BALL = 1.5  # the pick's ball: this many point spacings in radius (a size in the scene: it grows as one zooms in,
# where the label, of fixed pixel size, would hide it otherwise)


def nearest_to_ray(points: np.ndarray, origin, direction, reach: float, depth: float, per_distance: float = 0.0,
                   cover: float = 0.0) -> int | None:
    """Index of the point (N, 3) a click ray picks, or None when none lies within reach of it.

    First the points drawn under the click: within ``cover`` of the ray (a drawn point's half width, page units)
    or ``per_distance`` times their distance along it (PICK_PIXELS on the screen at that depth); in a hole between
    them, the points within ``reach``. Of those, the surface nearest the camera (within ``depth`` of the nearest
    along the ray: a click lands on the visible surface, not one behind it), and on it the point nearest the ray.
    """
    o = np.asarray(origin, np.float64)
    d = np.asarray(direction, np.float64)
    d = d / max(np.linalg.norm(d), 1e-12)
    rel = np.asarray(points, np.float64) - o
    along = rel @ d
    perp = np.linalg.norm(rel - along[:, None] * d, axis=1)
    ahead = along > 0
    under = np.flatnonzero(ahead & (perp <= np.maximum(cover, per_distance * along)))
    within = under if len(under) else np.flatnonzero(ahead & (perp <= np.maximum(reach, per_distance * along)))
    if not len(within):
        return None
    front = within[along[within] <= along[within].min() + depth]
    return int(front[np.argmin(perp[front])])


@dataclass
class PointPairs:
    """Picked pairs as indices into the source and target scans; ``pending``: a source pick awaiting its partner."""

    source_index: list[int] = field(default_factory=list)
    target_index: list[int] = field(default_factory=list)
    pending: int | None = None

    def __len__(self) -> int:
        return len(self.source_index)

    def add(self, which: str, index: int) -> None:
        if which == "source":
            self.pending = index
        elif self.pending is None:
            raise InputError("click a point on the source (orange) first, then its partner on the target")
        else:
            self.source_index.append(self.pending)
            self.target_index.append(index)
            self.pending = None

    def remove(self, k: int) -> None:
        if not 0 <= k < len(self):
            raise InputError(f"there is no pair {k + 1}; pairs are numbered 1 to {len(self)}")
        del self.source_index[k], self.target_index[k]

    def align(self, source: np.ndarray, target: np.ndarray) -> np.ndarray:
        """T_target_source (4, 4) fitting the pairs (source points (N, 3), target points (M, 3))."""
        if len(self) < MIN_PAIRS:
            raise InputError(f"pick at least {MIN_PAIRS} pairs (now {len(self)})")
        x, y = source[self.source_index], target[self.target_index]
        if np.linalg.matrix_rank(x - x.mean(0), tol=1e-9 * max(np.ptp(x), 1e-12)) < 2:
            raise InputError("the source points of the pairs lie on one line: pick points spread apart")
        return weighted_horn(x, y)

    def residuals(self, source: np.ndarray, target: np.ndarray, T: np.ndarray) -> np.ndarray:
        """(N,) distance of each pair under T_target_source, in the scans' units."""
        if not len(self):
            return np.zeros(0)
        return np.linalg.norm(apply(T, source[self.source_index]) - target[self.target_index], axis=1)


@dataclass(eq=False)
class PairHandles:
    picking: viser.GuiCheckboxHandle
    listing: viser.GuiMarkdownHandle
    remove_which: viser.GuiTextHandle
    remove: viser.GuiButtonHandle
    clear: viser.GuiButtonHandle
    align: viser.GuiButtonHandle


class PairsPanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        gui = tab.gui
        with gui.add_folder("Point pairs"):
            self.h = PairHandles(
                picking=gui.add_checkbox("Pick point pairs", False,
                                         hint="click a point on the source (orange), then its partner on the target"),
                listing=gui.add_markdown("No pairs."),
                remove_which=gui.add_text("Pair number", "1"),
                remove=gui.add_button("Remove pair"),
                clear=gui.add_button("Clear pairs"),
                align=gui.add_button("Align from pairs", disabled=True,
                                     hint=f"Horn's closed form on >= {MIN_PAIRS} pairs; sets the initial pose"))
        self.pairs = PointPairs()
        self.markers: list = []
        self.h.picking.on_update(lambda e: tab.guarded(self._picking))
        self.picking = False
        self.h.remove.on_click(tab.action(self._remove))
        self.h.clear.on_click(tab.action(self.forget))
        self.h.align.on_click(tab.action(self.align))
        self._callback = None

    def _picking(self) -> None:
        scene = self.tab.client.scene
        self.picking = bool(self.h.picking.value)
        if self.picking and self._callback is None:
            self._callback = scene.on_click()(self.tab.action(lambda o, d: self.clicked(o, d),  # (looked up at the click)
                                                                event=lambda e: (e.ray_origin, e.ray_direction)))
        elif not self.picking and self._callback is not None:
            scene.remove_click_callback(self._callback)
            self._callback = None
        self.tab.apply_visibility()  # no gizmo while picking: it sits where the source's points are clicked

    def _per_distance(self) -> float:
        """PICK_PIXELS as a reach per unit of distance from the camera (0 before the browser reports its camera)."""
        cam = self.tab.client.camera
        try:
            return PICK_PIXELS * 2.0 * float(np.tan(float(cam.fov) / 2)) / max(int(cam.image_height), 1)
        except (AssertionError, AttributeError, TypeError, ValueError):
            return 0.0

    def page_points(self, which: str) -> np.ndarray:
        """(N, 3) the source (at the shown pose) or the target, in page coordinates."""
        st = self.state
        if which == "target":
            return st.display.points(st.target.points)
        return st.display.points(apply(st.T, st.source.points))

    def clicked(self, origin, direction) -> int | None:
        """A scene click while picking: the source point first, then its partner on the target. Returns the index."""
        st = self.state
        st.require_scans()
        which = "source" if self.pairs.pending is None else "target"
        spacing = (st.source if which == "source" else st.target).spacing
        with st.lock:
            pts = self.page_points(which)
        # a scan's points have point_size 0.8 spacing (scene3d.draw_pair), which viser draws 2 x point_size wide (a
        # point of size 0.1 at 3 units: 26 px, where 0.1 of scene would be 13 px): a click on one is within 0.8 of it
        index = nearest_to_ray(pts, origin, direction, reach=3.0 * spacing / st.display.size,
                               depth=3.0 * spacing / st.display.size, per_distance=self._per_distance(),
                               cover=0.8 * spacing / st.display.size)
        if index is None:
            self.tab.notify("No point there", f"the click missed the {which}; click on its points", error=False)
            return None
        self.pairs.add(which, index)
        self.show()
        return index

    def _remove(self) -> None:
        from rangereg.app.tab.fields import Range, parse_number

        k = parse_number(self.h.remove_which.value, "pair number", Range(1, 10**6, integer=True))
        self.pairs.remove(int(k) - 1)
        self.show()

    def align(self) -> None:
        """Horn's pose of the pairs becomes the initial guess; the pairs, their numbers and markers are cleared."""
        st = self.state
        st.require_scans()
        T = self.pairs.align(st.source.points, st.target.points)
        res = self.pairs.residuals(st.source.points, st.target.points, T)
        n = len(self.pairs)
        self.tab.set_initial(T)
        self.forget()
        units = st.target.units if st.target.units != "unknown" else "units"
        self.h.listing.content = (f"Aligned from {n} pairs (largest residual {fmt(float(res.max()))} {units}); "
                                  "the pairs are cleared.")

    def forget(self) -> None:
        """No pairs (a new pair of scans, or Clear)."""
        self.pairs = PointPairs()
        self.show()

    def show(self) -> None:
        """The list with residuals (under the pairs' own fit from 3 pairs on, else the shown pose) and the markers."""
        st, p = self.state, self.pairs
        self.h.align.disabled = len(p) < MIN_PAIRS
        if st.source is None:
            return
        units = st.target.units if st.target.units != "unknown" else "units"
        T, under = st.T, "the shown pose"
        if len(p) >= MIN_PAIRS:
            try:
                T, under = p.align(st.source.points, st.target.points), "their own fit"
            except InputError:
                pass
        res = p.residuals(st.source.points, st.target.points, T)
        lines = [f"pair {k + 1}: source {i} → target {j}: {fmt(r)} {units}"
                 for k, (i, j, r) in enumerate(zip(p.source_index, p.target_index, res))]
        if p.pending is not None:
            lines.append(f"source {p.pending} picked: now click its partner on the target")
        head = f"Residuals under {under} ({units}):" if len(p) else "No pairs."
        self.h.listing.content = "  \n".join([head, *lines])
        self._markers()

    def _markers(self) -> None:
        """Each pick as its label ("S1", "T1") centred on the point, over the scans, and a ball of its colour."""
        st, p, scene = self.state, self.pairs, self.tab.client.scene
        d = st.display
        src = p.source_index + ([p.pending] if p.pending is not None else [])
        radius = BALL * min(st.source.spacing, st.target.spacing) / d.size
        with self.tab.client.atomic():
            for node in self.markers:
                node.remove()
            drawn: list = []
            # the source's picks are children of the moving source node: they move with it; each drawing has names
            # of its own (scene3d.pair_root says why)
            nodes = self.tab.nodes
            nodes.drawn += 1
            for root, letter, at, rgb in (
                    (f"{nodes.source.root}/picks{nodes.drawn}", "S",
                     d.source_local(st.source.points[src]).reshape(-1, 3), SOURCE_PICK_RGB),
                    (f"{nodes.target.root}_picks{nodes.drawn}", "T",
                     d.points(st.target.points[p.target_index]).reshape(-1, 3), TARGET_PICK_RGB)):
                for k, xyz in enumerate(at):
                    drawn.append(scene.add_icosphere(f"{root}/{k}/ball", radius=radius, color=rgb,
                                                     position=tuple(xyz), cast_shadow=False, receive_shadow=False))
                    drawn.append(scene.add_label(f"{root}/{k}/label", f"{letter}{k + 1}", position=tuple(xyz),
                                                 anchor="center-center", depth_test=False))
            self.markers = drawn  # whole: a reader never sees a drawing half made

    def marker_positions(self) -> dict[str, np.ndarray]:
        """{"S1": (3,), "T1": ...}: where each pick's label is, in page coordinates (the source's at the shown pose)."""
        st, p = self.state, self.pairs
        src = p.source_index + ([p.pending] if p.pending is not None else [])
        out = {}
        for k, xyz in enumerate(self.page_points("source")[src] if src else []):
            out[f"S{k + 1}"] = xyz
        for k, xyz in enumerate(st.display.points(st.target.points[p.target_index]) if p.target_index else []):
            out[f"T{k + 1}"] = xyz
        return out
