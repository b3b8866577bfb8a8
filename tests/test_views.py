"""What the page draws (app/views.py): the path's colours per phase, its local-minimum markers, the slice figure."""

from __future__ import annotations

import numpy as np
import pytest
from rangereg.app.views import MAX_PATH_POINTS, PHASE_RGB, Display, Trail, slice_figure, thin
from rangereg.core.events import Event
from rangereg.core.io import load_scan
from rangereg.core.landscape import Slice
from rangereg.core.transforms import from_params

from tests.conftest import ASSETS


@pytest.fixture(scope="module")
def display() -> Display:
    return Display(load_scan(ASSETS / "corner" / "scan2.ply"), load_scan(ASSETS / "corner" / "scan1.ply"))


def events(phases: list[str], minima: set[int] = frozenset()) -> list[Event]:
    """One event per phase letter, each pose a small step along x; ``minima``: indices marked local minima."""
    return [Event(p, k + 1, k + 1, 1, from_params(np.r_[0.01 * k, 0, 0, 0, 0, 0]), 1.0 / (k + 1),
                  None if p == "icp" else 0.5, True, k in minima) for k, p in enumerate(phases)]


def test_each_segment_takes_the_colour_of_the_phase_it_leads_into(display):
    phases = ["icp"] * 3 + ["sa"] * 4 + ["icp"] * 2
    trail = Trail(display, events(phases))
    assert trail.update() == len(phases)
    seg, rgb = trail.segments()
    assert seg.shape == (len(phases) - 1, 2, 3) and rgb.shape == seg.shape and rgb.dtype == np.uint8
    want = np.array([PHASE_RGB[p] for p in phases[1:]], np.uint8)
    assert np.array_equal(rgb[:, 0], want) and np.array_equal(rgb[:, 1], want)
    # the segments chain the drawn node positions in order
    assert np.allclose(seg[1:, 0], seg[:-1, 1]) and np.allclose(seg[0, 0], trail.pos[0])


def test_local_minima_are_marked_where_icp_stopped(display):
    trail = Trail(display, events(["icp"] * 3 + ["sa"] * 2 + ["icp"] * 2, minima={2, 6}))
    trail.update()
    assert np.array_equal(np.flatnonzero(trail.minimum), [2, 6])
    assert np.allclose(trail.minima(), trail.pos[[2, 6]])
    assert trail.counts == (5 - 2, 2, 2)  # a minimum mark repeats ICP's last pose: not an iteration


def test_candidates_are_counted_apart_from_icp_iterations(display):
    trail = Trail(display, events(["candidates"] * 4 + ["icp"] * 3 + ["sa"] * 2))
    trail.update()
    assert trail.counts == (3, 2, 0) and trail.candidates == 4


def test_a_trail_takes_in_new_events_incrementally(display):
    evs = events(["icp"] * 2)
    trail = Trail(display, evs)
    trail.update()
    evs.extend(events(["icp"] * 2 + ["sa"] * 3)[2:])
    assert trail.update() == 5 and trail.counts == (2, 3, 0) and len(trail.pos) == 5
    assert trail.minima().shape == (0, 3)


def test_a_long_path_is_thinned_but_keeps_its_last_point(display):
    trail = Trail(display, events(["sa"] * (3 * MAX_PATH_POINTS)))
    trail.update()
    seg, _ = trail.segments()
    assert len(seg) < MAX_PATH_POINTS and np.allclose(seg[-1, 1], trail.pos[-1])


def test_a_short_leg_and_a_minimum_inside_a_long_thinned_path_keep_their_colour(display):
    # a 3-event ICP leg ending in a minimum between thousands of SA moves: thinning drops neither
    phases = ["sa"] * (4 * MAX_PATH_POINTS) + ["icp"] * 3 + ["sa"] * (4 * MAX_PATH_POINTS)
    k = 4 * MAX_PATH_POINTS + 2
    trail = Trail(display, events(phases, minima={k}))
    trail.update()
    seg, rgb = trail.segments()
    assert len(seg) <= MAX_PATH_POINTS + 8
    icp = np.all(rgb[:, 0] == PHASE_RGB["icp"], axis=1)
    assert icp.sum() >= 2 and any(np.allclose(s, trail.pos[k]) for s in seg[:, 1])


def test_the_thinned_path_keeps_the_same_points_as_it_grows():
    # a live path must not shimmer: between two pushes the kept points only gain the new end, until the stride
    # doubles (then every other one goes)
    most = 64
    for n in range(most + 1, 8 * most):
        a, b = set(thin(n, most)) - {n - 1}, set(thin(n + 1, most))
        if len(b) >= len(a):
            assert a <= b, n
        assert len(b) <= most + 1 and {0, n} <= b


def test_the_chart_starts_both_series_at_the_initial_error(display):
    trail = Trail(display, events(["icp"] * 2 + ["sa"] * 2))
    trail.update()
    it, icp, sa, candidates = trail.plot(E0=7.0)
    assert icp[0] == sa[0] == candidates[0] == np.log10(7.0) and np.all(np.diff(it) > 0)
    assert np.isnan(icp[3:]).all() and np.isnan(sa[1:3]).all() and np.isnan(candidates[1:]).all()


def test_the_chart_draws_log10_E_on_a_linear_axis_so_its_ticks_are_spaced(display):
    # uPlot's log axis (distr 3) stacked a tick on every 1-9 of each decade and printed E < 0.01 as '0': a column
    # of overlapping labels. The chart draws log10 E on a linear axis, whose ticks uPlot spaces by `space` pixels
    from rangereg.app.tab.run import CHART_AXES, CHART_SCALES, CHART_TITLE

    assert CHART_SCALES["y"].get("distr", 1) == 1 and CHART_AXES[1]["space"] >= 20 and "log10 E" in CHART_TITLE
    errors = [3e-3, 2e-5, 4e-9, 0.0]  # spans six decades, and a zero (no log: drawn at the smallest positive E)
    evs = [Event("sa", k + 1, k + 1, 1, np.eye(4), e, 0.5, True, False) for k, e in enumerate(errors)]
    trail = Trail(display, evs)
    trail.update()
    _, _, sa, _ = trail.plot(E0=1e-2)
    assert np.allclose(sa, np.log10([1e-2, 3e-3, 2e-5, 4e-9, 4e-9]))


def a_slice() -> Slice:
    a, b = np.linspace(-1, 1, 5), np.linspace(-10, 10, 7)
    return Slice(("tx", "ry"), a, b, 1.0 + a[:, None] ** 2 + (b[None, :] / 10) ** 2, np.eye(4))


def test_slice_figure_draws_both_legs_in_the_page_colours_and_the_current_pose():
    path = np.array([[0.9, 8.0], [0.5, 5.0], [0.4, 4.0], [0.1, 1.0], [0.0, 0.0]])
    fig = slice_figure(a_slice(), path, ["icp", "icp", "sa", "sa", "icp"], np.array([0.0, 0.5]), "t")
    traces = {t.name: t for t in fig.data if t.name}
    for phase, name in (("icp", "ICP"), ("sa", "SA")):
        assert traces[name].line.color == f"rgb{PHASE_RGB[phase]}"
        drawn = ~np.isnan(np.asarray(traces[name].x, float))
        assert drawn.any()
    assert np.array_equal(~np.isnan(np.asarray(traces["SA"].x, float)), [False, False, True, True, False])
    # each leg over a wider white casing of the same points, so the path shows on every colour of the contour
    for name in ("ICP", "SA"):
        k = list(fig.data).index(traces[name])
        casing = fig.data[k - 1]
        assert casing.line.color == "white" and casing.line.width > traces[name].line.width and not casing.showlegend
        assert np.array_equal(np.asarray(casing.x, float), np.asarray(traces[name].x, float), equal_nan=True)
    assert (traces["shown pose"].x[0], traces["shown pose"].y[0]) == (0.0, 0.5)
    assert (traces["minima of the slice"].x[0], traces["minima of the slice"].y[0]) == (0.0, 0.0)  # the bowl's floor
    assert (traces["start"].x[0], traces["start"].y[0]) == (0.9, 8.0)
    assert fig.layout.xaxis.title.text.startswith("tx") and "deg" in fig.layout.yaxis.title.text


def test_slice_figure_without_a_run_shows_the_surface_its_minima_and_the_pose_only():
    fig = slice_figure(a_slice(), None, None, np.array([0.0, 0.0]), "t")
    assert [t.name for t in fig.data if t.name] == ["minima of the slice", "shown pose"]


def test_the_png_draws_each_leg_in_the_page_colour():
    import matplotlib.colors as mcolors
    import matplotlib.pyplot as plt
    from rangereg.app.plots import slice_axes

    path = np.array([[0.9, 8.0], [0.5, 5.0], [0.4, 4.0], [0.1, 1.0]])
    fig = slice_axes(a_slice(), path, ["icp", "icp", "sa", "sa"], np.array([0.0, 0.5]), "t", units="m")
    ax = fig.axes[0]
    legend = {t.get_text(): line for t, line in zip(ax.get_legend().get_texts(), ax.get_legend().get_lines())}
    for phase, name in (("icp", "ICP"), ("sa", "SA")):
        assert mcolors.to_hex(legend[name].get_color()) == "#{:02x}{:02x}{:02x}".format(*PHASE_RGB[phase])
    drawn = {mcolors.to_hex(line.get_color()) for line in ax.get_lines() if len(line.get_xdata()) > 1}
    assert drawn == {"#{:02x}{:02x}{:02x}".format(*PHASE_RGB[p]) for p in ("icp", "sa")}
    assert ax.get_xlabel() == "tx (m)" and ax.get_ylabel() == "ry (deg)"
    plt.close(fig)


def test_every_phase_core_emits_has_its_own_colour_in_every_path_the_page_draws(display):
    # one palette (app.figures.PHASE_RGB) for the 3-D path, the terrain's path, the recording and the chart
    from rangereg.app.figures import PHASE_LABEL
    from rangereg.app.recording import _part
    from rangereg.app.tab.terrain import PathOnSlice
    from rangereg.core.events import PHASES
    from rangereg.core.problem import prepare, relative_guess

    assert set(PHASES) <= set(PHASE_RGB) and set(PHASES) <= set(PHASE_LABEL)
    assert len({PHASE_RGB[p] for p in PHASES}) == len(PHASES)  # no two phases look alike
    phases = [p for p in PHASES for _ in range(2)]
    want = np.array([PHASE_RGB[p] for p in phases[1:]], np.uint8)
    trail = Trail(display, events(phases))
    trail.update()
    _, rgb = trail.segments()
    assert np.array_equal(rgb[:, 0], want) and np.array_equal(rgb[:, 1], want)

    source, target = load_scan(ASSETS / "corner" / "scan2.ply"), load_scan(ASSETS / "corner" / "scan1.ply")
    T0 = relative_guess(source, target)
    problem = prepare(source, target, T0, seed=0)
    sl = Slice(("tx", "ry"), np.linspace(-50, 50, 5), np.linspace(-10, 10, 5), np.ones((5, 5)), T0)
    path = PathOnSlice(problem, sl, T0, events(phases))
    path.update()
    _, rgb = path.segments()  # the start (the guess) leads into the first event
    assert np.array_equal(rgb[:, 0], np.array([PHASE_RGB[p] for p in phases], np.uint8))

    class Scene:
        def add_line_segments(self, name, segments, colors, **kw):
            self.colors = colors

    scene = Scene()
    _part(scene, "/path", trail.pos, trail.phase)
    assert np.array_equal(scene.colors[:, 0], want)

    it, *series = trail.plot(E0=1.0)  # one chart series per phase, in PHASE_RGB's order, each drawn where it ran
    for k, p in enumerate(PHASE_RGB):
        ran = np.r_[True, [q == p for q in phases]]
        assert np.array_equal(~np.isnan(series[k]), ran)


def test_every_chart_series_starts_with_a_number_so_uplot_can_range_it(display):
    # a series whose first value was NaN (the temperature before any annealing) left the chart blank
    trail = Trail(display, events(["icp"] * 3 + ["sa"] * 2))
    trail.update()
    for threshold in (0.5, None):
        series = trail.chart(E0=7.0, threshold=threshold)
        assert len(series) == 1 + len(PHASE_RGB) + 2 and all(np.isfinite(s[0]) for s in series)
    *_, line, temp = trail.chart(E0=7.0, threshold=0.5)
    assert np.allclose(line, np.log10(0.5)) and np.isnan(temp[1:4]).all()  # ICP has no temperature


def test_the_recording_says_the_event_iteration_phase_E_and_temperature_and_shows_the_legend(display):
    from rangereg.app.figures import LEGEND
    from rangereg.app.recording import RECORDED_LEGEND, RunToRecord, _legend, event_line

    evs = events(["icp"] * 2 + ["sa"] * 2)
    run = RunToRecord(None, None, display, (), np.eye(4), evs, units="mm")
    assert event_line(run, 0) == "event 0 of 4: the start"
    assert event_line(run, 2) == "event 2 of 4 · iteration 2 · ICP · E = 0.5 mm²"  # ICP: no temperature
    assert event_line(run, 4) == "event 4 of 4 · iteration 4 · SA · E = 0.25 mm² · temperature 0.5 mm²"

    class Scene:
        def __init__(self):
            self.labels, self.colours = [], []

        def add_icosphere(self, name, radius, color, position):
            self.colours.append(color)

        def add_label(self, name, text, position, anchor):
            self.labels.append(text)

    scene = Scene()
    _legend(scene)
    assert scene.labels == list(RECORDED_LEGEND)
    assert scene.colours == [rgb for name, rgb in LEGEND if name in RECORDED_LEGEND]


def test_every_two_colours_of_the_legend_are_told_apart():
    from rangereg.app.figures import LEGEND

    def lab(rgb):  # CIE L*a*b* of an sRGB triple (D65)
        c = np.asarray(rgb, float) / 255
        c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
        xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]) @ c
        f = np.cbrt(xyz / np.array([0.9505, 1.0, 1.089]))
        return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])

    for i, (a, ra) in enumerate(LEGEND):
        for b, rb in LEGEND[i + 1:]:
            assert np.linalg.norm(lab(ra) - lab(rb)) > 25, (a, b)  # CIE76 Delta E: ~2 is just noticeable
