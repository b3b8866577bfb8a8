"""Model construction (paper sections 1-2, Fig. 2): fusing registered scans, merging a set of scans."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
from rangereg.core.fuse import double_layer_fraction, fuse
from rangereg.core.merge import merge
from rangereg.core.result import Stop, StopReason
from rangereg.core.surface import Surface
from rangereg.core.transforms import apply, invert, pose_error

from tests.conftest import ASSETS, BUNNY
from tests.conftest import run_cli as rangereg


@pytest.mark.parametrize("name", ["corner", "bowl"])
def test_fused_two_scans_have_no_double_layer(scene, name):
    from rangereg.core.simulate import true_transform

    target, source = scene(name)
    T = true_transform(source, target)
    model = fuse([target, source], [np.eye(4), T])
    gap = float(np.median([target.spacing, source.spacing]))
    # The measure itself must see a double layer: both scans' own surfaces left on top of each other.
    s_t, s_s = Surface.from_scan(target), Surface.from_scan(source)
    both_v = np.vstack([target.points, apply(T, source.points)])
    both_f = np.vstack([s_t.faces, s_s.faces + len(target.points)])
    assert double_layer_fraction(both_v, both_f, gap) > 0.3
    assert double_layer_fraction(model.vertices, model.faces, gap) < 0.01
    # Over the overlap one scan is kept, point by point; both scans contribute to the model.
    share = np.bincount(model.owner, minlength=2)
    assert share.min() > 0.2 * share.sum()
    assert share.sum() < len(target.points) + len(source.points) - 1000
    # The model covers the data: every kept sample has the mesh near it.
    from scipy.spatial import cKDTree

    d, _ = cKDTree(model.vertices).query(model.points)
    assert np.quantile(d, 0.99) < 2 * gap


def test_merge_cli_on_a_bundled_scene(tmp_path):
    out = tmp_path / "model.ply"
    r = rangereg("merge", str(ASSETS / "corner" / "scan1.ply"), str(ASSETS / "corner" / "scan2.ply"),
                 "--out", str(out), "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    assert set(rep) >= {"poses", "pairs", "seconds", "rotation_error_deg", "translation_error", "model"}
    assert np.allclose(rep["poses"][0], np.eye(4))
    assert max(rep["rotation_error_deg"]) < 1.0 and max(rep["translation_error"]) < 0.01 * 1219
    assert rep["model"]["double_layer_fraction"] < 0.01
    from rangereg.core.io import load_scan

    mesh = load_scan(out)
    assert mesh.faces is not None and len(mesh.faces) == rep["model"]["triangles"]


def test_merge_bad_conf_gets_one_line(tmp_path):
    a, b = str(ASSETS / "corner" / "scan1.ply"), str(ASSETS / "corner" / "scan2.ply")
    bad = tmp_path / "bad.conf"
    bad.write_text("camera 0 0 0 0 0 0 1\nbmesh scan1.ply 0 0 zero 0 0 0 1\n")
    other = tmp_path / "other.conf"
    other.write_text("bmesh elsewhere.ply 0 0 0 0 0 0 1\n")
    nan = tmp_path / "nan.conf"
    nan.write_text("bmesh scan1.ply 0 0 0 0 0 0 1\nbmesh scan2.ply nan 0 0 0 0 0 1\n")
    for conf, words in ((bad, "not a number"), (other, "no pose for"), (tmp_path / "none.conf", "no such file"),
                        (nan, "translation [nan, 0.0, 0.0] is not finite")):
        r = rangereg("merge", a, b, "--init", str(conf))
        assert r.returncode == 2
        assert words in r.stderr and len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


def test_merge_refuses_a_scan_no_pair_could_use_before_any_registration(tmp_path):
    # a flat or a tiny scan is bad input (status 2, one line), not a scan left "not placed" (status 3)
    from rangereg.core.io import load_scan
    from rangereg.core.ply import write_ply

    a = load_scan(ASSETS / "corner" / "scan1.ply")
    flat = a.points.copy()
    flat[:, 2] = 0.0
    write_ply(tmp_path / "flat.ply", flat)
    write_ply(tmp_path / "few.ply", a.points[:10])
    for name, words in (("flat", "flat"), ("few", "only 10 points")):
        r = rangereg("merge", str(ASSETS / "corner" / "scan1.ply"), str(tmp_path / f"{name}.ply"),
                     "--out", str(tmp_path / "m.ply"))
        assert r.returncode == 2 and words in r.stderr, r.stderr
        assert len(r.stderr.strip().splitlines()) == 1 and "round 1" not in r.stderr


def test_strict_json_writes_null_for_every_non_finite_number():
    # a scan not placed: its pose null, any non-finite number null (never NaN or Infinity)
    from rangereg.app.outputs import strict_json

    text = strict_json({"error": float("inf"), "pairs": [{"misfit": float("nan")}], "poses": [None, np.float64(1.5)]})
    assert json.loads(text, parse_constant=lambda c: pytest.fail(f"{c} in strict JSON")) == {
        "error": None, "pairs": [{"misfit": None}], "poses": [None, 1.5]}


def _right(scans, poses, deg: float = 2.0, metres: float = 0.002) -> list[tuple[str, float, float]]:
    """The scans placed beyond deg / metres of the truth relative to the first (empty: all right)."""
    off = []
    for s, T in zip(scans, poses):
        rot, tr = pose_error(T, invert(scans[0].pose) @ s.pose, s.points.mean(0))
        if not (rot < deg and tr < metres):
            off.append((s.name, rot, tr))
    return off


def test_the_four_bunny_scans_with_no_poses_all_land(bunny):
    """No --init, no stored poses: every pair over all rotations; bun315 with bun090 (135 deg apart,
    ~6 % matching) is not trusted and not used; every scan within 2 deg / 2 mm (~40 s)."""
    scans = [replace(bunny(n), guess=None) for n in ("bun000", "bun045", "bun090", "bun315")]
    res = merge(scans, None, build_model=False)
    assert res.mode == "all" and all(res.placed)
    assert not _right(scans, res.poses)
    far = next(p for p in res.pairs if {p.i, p.j} == {2, 3})
    assert far.status == "rejected" and not far.trusted and "not trusted" in far.reason
    # bun045 with bun315 (right, misfit 4.6, just above the pair threshold's 4.5) closes the loop through bun000
    assert all(p.trusted or "closes the loop through" in p.reason for p in res.used) and len(res.used) >= 4
    assert all(r.cycle is not None and r.cycle[0] < 2.0 for r in res.scans)


@pytest.mark.slow
def test_bunny_set_from_rough_poses_comes_back_to_the_conf_poses(bunny):
    from rangereg.core.turntable import rough_poses

    scans = [bunny(n) for n in ("bun000", "bun045", "bun090", "bun315")]
    # each .conf pose turned by 15 degrees about its scan frame's origin and shifted by 25 mm
    initial = rough_poses([s.pose for s in scans], "frame", 15.0, 0.025, seed=0)
    res = merge(scans, initial)
    assert all(res.placed) and not _right(scans, res.poses, 1.0, 0.001)
    assert double_layer_fraction(res.model.vertices, res.model.faces, scans[0].spacing) < 0.02


def test_a_scan_no_trusted_pair_reaches_is_reported_not_placed(tmp_path):
    from rangereg.core.io import load_scan, save_scan

    # a bowl and a corner of walls (two windows of one scan would not do: a patch of wall fits any wall):
    # no pose makes them overlap; no poses stored: no guess
    for name, scene in (("left", "bowl"), ("right", "corner")):
        save_scan(tmp_path / f"{name}.ply", replace(load_scan(ASSETS / scene / "scan1.ply"), pose=None, guess=None))
    out = tmp_path / "model.ply"
    r = rangereg("merge", tmp_path / "left.ply", tmp_path / "right.ply", "--out", out, "--json", "--workers", "1")
    assert r.returncode == 3, r.stderr
    # stdout holds the JSON alone, and strict JSON (a pair with no finite number has null there)
    rep = json.loads(r.stdout, parse_constant=lambda c: pytest.fail(f"{c} in --json"))
    assert rep["placed"] == [True, False] and rep["poses"][1] is None and rep["reference"] == "left"
    assert rep["stated"]["no_guess"] and rep["pairs"][0]["start"] == "no guess"
    assert rep["pairs"][0]["status"] == "rejected" and not rep["pairs"][0]["trusted"]
    assert "no trusted pair" in rep["scan_reports"][1]["why"]
    assert "1 of 2 scans not placed (right)" in r.stderr
    assert out.exists()  # the model of the placed scans


SCRIPTED = Stop(StopReason.TRUSTED, "scripted")


class _Scripted:
    """A task map whose pair registrations are scripted (the rounds, the graph and the report are the
    merge's own): ``answer(i, j, attempt, T0) -> (T_i_j, trusted)``; overlaps and shares are 0.5."""

    def __init__(self, answer):
        self.answer, self.asked = answer, []

    def __call__(self, fn, items, shared, label=None, done=None):
        from rangereg.core.merge_tasks import PairOutcome, pair_task

        if fn is not pair_task:
            return [0.5 for _ in items]
        out = []
        for t in items:
            self.asked.append((t.i, t.j, t.attempt, t.start))
            T, trusted = self.answer(t.i, t.j, t.attempt, t.T0)
            out.append(PairOutcome(T, 1e-3 if trusted else 1.0, trusted, 0.5 if trusted else 9.0, True, 0.5,
                                   SCRIPTED, 0.0))
        return out


def _four_views():
    from rangereg.core.turntable import make_campaign

    from tests.test_campaign import SMALL

    camp = make_campaign(3, SMALL)
    return [replace(s, guess=None) for s in camp.scans[:4]]


@pytest.mark.parametrize("twin", [False, True])
def test_a_scan_whose_pairs_all_end_on_one_twin_is_not_placed_through_them(twin):
    # scan 3 onto each of the others ends on the same wrong pose, half a turn off, not trusted but at the trusted pairs'
    # level: its pairs close triangles with the trusted ones and the graph takes them. Said to be twins (the pose puts
    # points where the other's sensor looked through: core.result.GlobalDetails.looked_through), no loop vouches for them
    from rangereg.core.merge_tasks import PairOutcome, pair_task
    from rangereg.core.transforms import from_params

    scans = _four_views()
    truth = lambda i, j: invert(scans[i].pose) @ scans[j].pose  # noqa: E731
    half = from_params(np.r_[0, 0, 0, 0, 0, np.pi])

    def run(fn, items, shared, label=None, done=None):
        if fn is not pair_task:
            return [0.5 for _ in items]
        return [PairOutcome(truth(t.i, t.j), 1e-3, True, 0.5, True, 0.5, SCRIPTED, 0.0) if t.j < 3 else
                PairOutcome(truth(t.i, t.j) @ half, 1e-3, False, 0.6, True, 0.5, SCRIPTED, 0.0, twin=twin)
                for t in items]

    res = merge(scans, None, build_model=False, map_tasks=run)
    assert res.placed == [True, True, True, False]
    reasons = [p.reason for p in res.pairs if p.j == 3]
    if twin:  # never in the graph
        assert all("a twin" in r for r in reasons)
    else:  # corroborated, in the graph: only the drift test then leaves scan 3 out (its pairs pin it too loosely)
        assert all("too uncertain" in r and "a twin" not in r for r in reasons)


def test_when_the_first_scan_is_in_no_group_the_largest_group_is_placed_in_its_frame():
    scans = _four_views()
    truth = lambda i, j: invert(scans[i].pose) @ scans[j].pose  # noqa: E731
    # every pair with the first scan fails; the other three close a loop
    run = _Scripted(lambda i, j, attempt, T0: (truth(i, j), True) if i > 0 else (T0, False))
    res = merge(scans, None, build_model=False, map_tasks=run)
    assert res.mode == "all" and res.placed == [False, True, True, True] and res.reference == 1
    assert res.poses[0] is None and np.allclose(res.poses[1], np.eye(4))
    for k in (2, 3):
        assert pose_error(res.poses[k], truth(1, k))[0] < 1e-4
    assert "no trusted pair reaches it" in res.scans[0].why
    assert all(p.status == ("rejected" if p.i == 0 else "used") for p in res.pairs)


def test_a_trusted_pair_that_does_not_close_is_registered_again_from_the_graphs_pose():
    from rangereg.core.transforms import from_params

    scans = _four_views()
    truth = lambda i, j: invert(scans[i].pose) @ scans[j].pose  # noqa: E731
    twin = from_params(np.r_[0, 0, 0, 0, 0, np.radians(120.0)])

    def answer(i, j, attempt, T0):
        if (i, j) == (1, 3) and attempt == 0:
            return truth(i, j) @ twin, True  # a wrong pose the pair threshold trusted
        return truth(i, j), True

    run = _Scripted(answer)
    res = merge(scans, None, build_model=False, map_tasks=run)
    assert all(res.placed) and res.rounds == 2
    again = [a for a in run.asked if a[2] == 1]
    assert again == [(1, 3, 1, "graph pose")]  # registered again, from the graph's pose, before given up
    pair = next(p for p in res.pairs if (p.i, p.j) == (1, 3))
    assert pair.status == "used" and pair.round == 2 and "does not close" in pair.earlier
    for k in range(4):
        assert pose_error(res.poses[k], truth(0, k))[0] < 1e-4
    assert all(r.cycle is not None and r.cycle[0] < 1e-4 for r in res.scans)


def test_a_trusted_pair_whose_misfit_is_far_above_the_others_is_not_used():
    # scan 3's only trusted pair is a wrong pose trusted at 6 x the campaign's typical misfit (turntable crops:
    # wrong poses trusted at 2.5-3.4 where right ones sit at 0.3-0.7): scan 3 is not placed, not placed wrong
    from rangereg.core.merge_tasks import PairOutcome, pair_task
    from rangereg.core.transforms import from_params

    scans = _four_views()
    truth = lambda i, j: invert(scans[i].pose) @ scans[j].pose  # noqa: E731
    twin = from_params(np.r_[0, 0, 0, 0, 0, np.radians(120.0)])

    def run(fn, items, shared, label=None, done=None):
        if fn is not pair_task:
            return [0.5 for _ in items]
        out = []
        for t in items:
            if t.j == 3:
                T, trusted, misfit = (truth(t.i, t.j) @ twin, True, 3.0) if t.i == 2 else (t.T0, False, 9.0)
            else:
                T, trusted, misfit = truth(t.i, t.j), True, 0.5
            out.append(PairOutcome(T, 1e-3, trusted, misfit, True, 0.5, SCRIPTED, 0.0))
        return out

    res = merge(scans, None, build_model=False, map_tasks=run)
    assert res.placed == [True, True, True, False] and res.poses[3] is None
    pair = next(p for p in res.pairs if (p.i, p.j) == (2, 3))
    assert pair.status == "rejected" and "misfit far above" in pair.reason


def test_when_no_pair_overlaps_under_the_rough_poses_the_scans_are_reached_with_no_guess_at_once():
    from rangereg.core.merge_tasks import PairOutcome, feature_task, pair_task

    scans = _four_views()
    truth = lambda i, j: invert(scans[i].pose) @ scans[j].pose  # noqa: E731
    far = [np.eye(4) for _ in scans]
    for k, T in enumerate(far):
        T[0, 3] = 1e6 * k  # rough poses that put every scan far from every other: no pair overlaps
    asked = []

    def run(fn, items, shared, label=None, done=None):
        if fn is feature_task:
            return [fn(shared, k) for k in items]
        if fn is not pair_task:
            return [0.0 for _ in items]
        asked.extend(t.start for t in items)
        return [PairOutcome(truth(t.i, t.j), 1e-3, True, 0.5, True, 0.5, SCRIPTED, 0.0) for t in items]

    res = merge(scans, far, build_model=False, map_tasks=run)
    assert asked and set(asked) == {"no guess"} and all(res.placed)
    for k in range(4):
        assert pose_error(res.poses[k], truth(0, k))[0] < 1e-4


def test_candidate_pairs_per_mode():
    from rangereg.core.merge import MergeConfig
    from rangereg.core.merge_pairs import Candidate, choose

    n = 12  # a ring: overlap falls with the distance round the ring
    ring = lambda i, j: min((j - i) % n, (i - j) % n)  # noqa: E731
    overlaps = [Candidate(i, j, max(0.0, 0.9 - 0.12 * ring(i, j))) for i in range(n) for j in range(i + 1, n)]
    mc = MergeConfig()
    every = choose(overlaps, n, "overlap", mc)
    assert {c.key for c in every} == {c.key for c in overlaps if c.overlap >= 0.25}
    best = choose(overlaps, n, "init", mc)
    # half the partners the nearest (1 stop either way), half the longest links still overlapping by
    # long_overlap (3 stops: 54 %; 4 stops: 42 %)
    assert {c.key for c in best} == {c.key for c in overlaps if ring(c.i, c.j) in (1, 3)}
    chain = [Candidate(i, i + 1, 0.8) for i in range(n - 1)] + [Candidate(0, n - 1, 0.02)]
    assert [c.key for c in choose(chain, n, "chain", mc)] == [(i, i + 1) for i in range(n - 1)]


def test_a_scan_whose_rough_pose_is_far_beyond_the_stated_uncertainty_is_found_with_no_guess(tmp_path):
    # its only pair, tried from the rough poses, is not trusted: one more try with no guess places it
    if not BUNNY.is_dir():
        pytest.skip("the shared bunny scans are absent")
    conf = tmp_path / "far.conf"
    conf.write_text("bmesh bun000.ply 0 0 0 0 0 0 1\nbmesh bun045.ply 100 0 0 0 0 0 1\n")
    r = rangereg("merge", str(BUNNY / "bun000.ply"), str(BUNNY / "bun045.ply"), "--init", str(conf),
                 "--truth", str(BUNNY / "bun.conf"), "--out", str(tmp_path / "m.ply"), "--json")
    assert r.returncode == 0, r.stderr
    rep = json.loads(r.stdout)
    (pair,) = rep["pairs"]
    assert pair["start"] == "no guess" and pair["trusted"] and pair["earlier"] and rep["graph"]["rounds"] == 2
    assert max(rep["rotation_error_deg"]) < 1.0 and max(rep["translation_error"]) < 0.002
    assert all(s["placed"] and not s["checked"] for s in rep["scan_reports"])  # one pair: no loop checks it


def test_the_clis_pair_modes_are_the_merges():
    # the parser names them without importing the engine (a fast --help); they must stay the same
    from rangereg.app.cli import build_parser
    from rangereg.core.merge import MergeConfig

    merge_parser = build_parser()._subparsers._group_actions[0].choices["merge"]
    (pairs,) = [a for a in merge_parser._actions if a.dest == "pairs"]
    assert tuple(pairs.choices) == MergeConfig.PAIR_MODES
