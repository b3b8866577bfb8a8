"""Each step of a merge on its own (core.merge_*): pairs, graph, rounds, groups, report, progress. The
campaign is a small simulated turntable; pair registrations are written into the state by hand, so each
step is checked against what it must do with them, not against the registration engine."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from rangereg.core import merge_graph, merge_groups, merge_pairs, merge_report, merge_rounds, merge_tasks
from rangereg.core.merge import MergeConfig, _Campaign, serial_map
from rangereg.core.merge_progress import Counter, MergeProgress, Step
from rangereg.core.merge_result import PairResult, PairStatus, Rejection, ScanStatus, Start
from rangereg.core.register import Config
from rangereg.core.result import Stop, StopReason
from rangereg.core.threshold import Constraint
from rangereg.core.transforms import apply, from_params, invert, pose_error
from rangereg.core.turntable import arc_ends, make_campaign, shared_axis

from tests.test_campaign import SMALL

TRUSTED = Stop(StopReason.TRUSTED)
BOUND = Stop(StopReason.TIME_BOUND)


@pytest.fixture(scope="module")
def camp():
    return make_campaign(3, SMALL)


def _campaign(camp, initial=None, **settings) -> _Campaign:
    scans = [replace(s, guess=None) for s in camp.scans]
    have = initial is not None
    return _Campaign(scans, initial if have else [np.eye(4)] * len(scans), have, Config(method="global"),
                     MergeConfig(**settings), lambda _e: None, serial_map)


def _truth(camp, i, j):
    return invert(camp.scans[i].pose) @ camp.scans[j].pose


def _pair(c, camp, i, j, trusted=True, misfit=0.5, error=1e-3, T=None, stop=TRUSTED, failure="",
          start=Start.ROUGH_POSES):
    c.pairs[i, j] = PairResult(i, j, _truth(camp, i, j) if T is None else T, error, 0.5, trusted, misfit, True, 0.1,
                               1, start, stop=stop if not failure else None, failure=failure)
    c.tried[i, j] = c.tried.get((i, j), 0) + 1


# ---- the polish of a trusted pair ----

def _turned(camp, i, j, degrees: float) -> np.ndarray:
    """The true T_i_j turned by ``degrees`` about the moved source's centroid (a trusted pose that far off)."""
    T = _truth(camp, i, j)
    c = apply(T, camp.scans[j].centroid[None])[0]
    R = from_params(np.r_[0.0, 0.0, 0.0, np.radians(degrees) * np.array([0.6, 0.0, 0.8])])
    D = np.eye(4)
    D[:3, :3], D[:3, 3] = R[:3, :3], c - R[:3, :3] @ c
    return D @ T


@pytest.mark.parametrize("degrees", [0.3, 5.0])
def test_the_polish_of_a_trusted_pair_is_taken_where_it_only_polishes(camp, degrees):
    # 5 deg: a larger step than the polish is taken for alone (POLISH_STEP_DEG), taken because clearly more of the
    # pair matches after it (as on the RGB-D drives, where a trusted pair 1.5 deg off was polished to 0.02 and refused)
    c = _campaign(camp)
    task = merge_tasks.PairTask(1, 2, np.eye(4), 15.0, None)
    T = _turned(camp, 1, 2, degrees)
    assert (pose_error(T, _truth(camp, 1, 2))[0] >= merge_tasks.POLISH_STEP_DEG) == (degrees > 1)
    P = merge_tasks.polished(c.shared, task, T)
    assert pose_error(P, _truth(camp, 1, 2))[0] < 0.25
    if degrees > 1:
        rise = merge_tasks.share_at(c.shared, 1, 2, P) - merge_tasks.share_at(c.shared, 1, 2, T)
        assert rise > merge_tasks.POLISH_MORE_MATCHING


def test_a_large_polish_after_which_about_as_much_of_the_pair_matches_is_not_taken(camp):
    # 1.5 deg off on these small scans: the polish corrects it, but the share matching rises by less than any small
    # polish may move it, so it cannot tell a correction from a slide, and the trusted pose stays
    c = _campaign(camp)
    task = merge_tasks.PairTask(1, 2, np.eye(4), 15.0, None)
    T = _turned(camp, 1, 2, 1.5)
    assert merge_tasks.polished(c.shared, task, T) is T


def test_a_polish_that_wanders_off_the_pair_is_not_taken(camp, monkeypatch):
    c = _campaign(camp)
    task = merge_tasks.PairTask(1, 2, np.eye(4), 15.0, None)
    T = _turned(camp, 1, 2, 0.2)
    slid = np.eye(4)
    slid[:3, 3] = 10 * camp.scans[2].spacing * np.array([0.0, 0.6, 0.8])
    monkeypatch.setattr(merge_tasks, "polish", lambda *args, **kwargs: slid @ T)
    assert merge_tasks.polished(c.shared, task, T) is T


# ---- pairs ----

def test_the_likeliest_partners_are_the_turntable_neighbours_and_identity_poses_tell_nothing(camp):
    truth = [s.pose for s in camp.scans]
    c = _campaign(camp, truth)
    assert merge_pairs.informative(c, truth)
    n = len(truth)
    near = merge_pairs.likeliest(c, truth, 2)
    ring = lambda i, j: min((j - i) % n, (i - j) % n)  # noqa: E731
    assert near and all(ring(i, j) == 1 for i, j in near)  # 45 deg apart: each scan's 2 nearest are its neighbours
    assert len(merge_pairs.likeliest(c, truth, n)) == n * (n - 1) // 2  # no more scans than partners: every pair
    ident = [np.eye(4)] * n
    c2 = _campaign(camp, ident)
    assert not merge_pairs.informative(c2, ident)
    assert c2.mode == "features"  # identity poses: the pairs are the cue's, not the poses'


def test_typed_candidates_are_chosen_by_overlap():
    from rangereg.core.merge_pairs import Candidate, choose

    picks = choose([Candidate(0, 1, 0.9), Candidate(1, 2, 0.1), Candidate(0, 2, 0.3)], 3, "overlap", MergeConfig())
    assert [p.key for p in picks] == [(0, 1), (0, 2)]
    # a scan left with none keeps its best above min_overlap_any
    picks = choose([Candidate(0, 1, 0.9), Candidate(1, 2, 0.1), Candidate(0, 2, 0.01)], 3, "overlap", MergeConfig())
    assert [p.key for p in picks] == [(0, 1), (1, 2)]


# ---- graph ----

def test_the_graph_step_says_why_each_pair_is_not_usable(camp):
    c = _campaign(camp)
    for i in range(4):
        _pair(c, camp, i, i + 1)
    _pair(c, camp, 0, 2, misfit=6.0)  # trusted, 12 x the typical misfit
    _pair(c, camp, 5, 6, trusted=False, misfit=9.0, stop=BOUND)
    _pair(c, camp, 6, 7, trusted=False, misfit=None, failure="nothing overlaps at the guess")
    s = merge_graph.screen(c)
    assert sorted(s.usable) == [(i, i + 1) for i in range(4)]
    assert s.why[0, 2][0] is Rejection.OUTLIER and "misfit far above" in s.why[0, 2][1]
    assert s.why[5, 6][0] is Rejection.NOT_TRUSTED and s.why[6, 7][0] is Rejection.NOT_REGISTERED
    assert "nothing overlaps" in s.why[6, 7][1]
    g, _ = merge_graph.build(c)
    assert g.placed[:5] == [True] * 5 and not any(g.placed[5:])


def test_an_untrusted_pair_is_used_where_a_triangle_with_a_trusted_pair_corroborates_it(camp):
    c = _campaign(camp)
    for i in range(4):
        _pair(c, camp, i, i + 1)  # trusted, misfit 0.5: the level's bound is 3.3 x 0.5
    _pair(c, camp, 4, 5, trusted=False, misfit=0.6, stop=BOUND)  # right, at the level
    _pair(c, camp, 3, 5, trusted=False, misfit=0.7, stop=BOUND)  # right: closes 3-4-5 with the trusted (3, 4)
    twin = from_params(np.r_[0, 0, 0, 0, 0, np.radians(120.0)])
    # scans 6 and 7 turned the same wrong way onto 4: a triangle that closes, at the level, but none of it trusted
    _pair(c, camp, 4, 6, T=_truth(camp, 4, 6) @ twin, trusted=False, misfit=0.6, stop=BOUND)
    _pair(c, camp, 4, 7, T=_truth(camp, 4, 7) @ twin, trusted=False, misfit=0.6, stop=BOUND)
    _pair(c, camp, 6, 7, T=invert(twin) @ _truth(camp, 6, 7) @ twin, trusted=False, misfit=0.6, stop=BOUND)
    # ... and one closing 3-4-6 with the trusted (3, 4), above the level
    _pair(c, camp, 3, 6, T=_truth(camp, 3, 6) @ twin, trusted=False, misfit=3.6, stop=BOUND)
    s = merge_graph.screen(c)
    assert sorted(s.corroborated) == [(3, 5), (4, 5)]
    assert sorted(s.usable) == sorted([(i, i + 1) for i in range(4)] + [(3, 5), (4, 5)])
    assert all(s.why[k][0] is Rejection.NOT_TRUSTED for k in [(4, 6), (4, 7), (6, 7), (3, 6)])
    g, screened = merge_graph.build(c)
    assert g.placed[:6] == [True] * 6 and not any(g.placed[6:])
    assert np.allclose(invert(g.poses[3]) @ g.poses[5], _truth(camp, 3, 5), atol=1e-6)
    used = {p.key: p for p in merge_report.pair_statuses(c, g, screened)}
    assert used[3, 5].status is PairStatus.USED and "closes the loop through" in used[3, 5].reason
    assert used[4, 6].status is PairStatus.REJECTED and used[4, 6].rejection is Rejection.NOT_TRUSTED


def test_two_twins_of_one_scan_do_not_corroborate_each_other_through_a_trusted_pair(camp):
    # a room turned half a turn: one frame registered onto two frames a step apart ends on the same twin twice, each
    # refused because its points lie where the other's sensor looked through empty space; with the trusted pair
    # between those two frames the triangle closes, at the level, but the threshold saw the poses are wrong (the RGB-D
    # drive at 0.4 m, seed 1, placed 4 frames half a turn off so); the same triangle of doubted poses still corroborates
    twin = from_params(np.r_[0, 0, 0, 0, 0, np.radians(180.0)])
    for looked_through, used in ((True, []), (False, [(2, 5), (3, 5)])):
        c = _campaign(camp)
        for i in range(3):
            _pair(c, camp, i, i + 1)
        for i in (2, 3):
            _pair(c, camp, i, 5, T=_truth(camp, i, 5) @ twin, trusted=False, misfit=0.6, stop=BOUND)
            c.pairs[i, 5] = replace(c.pairs[i, 5], twin=looked_through)
        assert sorted(merge_graph.screen(c).corroborated) == used


def _free(camp, i, j, moves: list[np.ndarray], of: int) -> Constraint:
    """A constraint of pair (i, j) whose weakest motions are the translations ``moves`` (each (3,)) of scan ``of`` (i or
    j), each in that scan's own frame: the constraint's frame is the target's, i's."""
    R = _truth(camp, i, j)[:3, :3] if of == j else np.eye(3)
    free = [np.r_[R @ m, 0.0, 0.0, 0.0] for m in moves]
    vectors = np.linalg.qr(np.column_stack(free + list(np.eye(6))))[0][:, :6]  # spanning the free ones first
    values = np.r_[[1e-4] * len(moves), np.ones(6 - len(moves))]
    return Constraint(values, vectors[:, 0], 1e-4, 500, np.zeros(3), 1.0, vectors=vectors)


LAYOUTS = {"its source": ((3, 5), (4, 5), (3, 4)), "its target": ((3, 4), (3, 5), (4, 5)),
           "one of each": ((3, 5), (5, 6), (3, 6))}
X, Y, Z = np.eye(3)


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("how, vouched", [("same", False), ("apart", True), ("pinned", True),
                                          ("a plane's, one shared", False), ("planes, none shared", True)])
def test_two_pairs_free_along_one_motion_of_the_scan_they_share_do_not_vouch_for_each_other(camp, layout, how,
                                                                                          vouched):
    # two pairs, neither trusted, close their triangle with a trusted one; where both leave the scan they share free
    # to slide one way they would close it as well slid alike (two views of a floor and a wall: the RGB-D drives'
    # frames placed 7-14 cm along a wall), so they corroborate nothing; free along different ways, they pin it
    p, q, trusted = LAYOUTS[layout]
    (shared,) = set(p) & set(q)
    c = _campaign(camp)
    _pair(c, camp, *trusted)
    for i, j in (p, q):
        _pair(c, camp, i, j, trusted=False, misfit=0.6, stop=BOUND)
    _pair(c, camp, 0, 1)  # the level's trusted pairs: three at misfit 0.5
    _pair(c, camp, 1, 2)
    moves = {"same": ([X], [X]), "apart": ([X], [Y]), "a plane's, one shared": ([X], [Y, X]),
             "planes, none shared": ([X, Z], [Y])}.get(how)
    if moves is not None:
        for (i, j), m in zip((p, q), moves):
            c.pairs[i, j] = replace(c.pairs[i, j], free=_free(camp, i, j, m, shared))
    s = merge_graph.screen(c)
    assert sorted(s.corroborated) == (sorted([p, q]) if vouched else [])
    if not vouched:  # the report says why the loop did not count
        assert all("free along one motion" in s.why[k][1] and s.why[k][0] is Rejection.NOT_TRUSTED for k in (p, q))
    assert merge_graph.alike(c, p, q) is (not vouched) and merge_graph.alike(c, q[::-1], p) is (not vouched)


def _free_world(camp, i, j, moves: list[np.ndarray]) -> Constraint:
    """A constraint of pair (i, j) whose weakest motions move scan j against scan i by the translations ``moves`` (each
    (3,), in the turntable's world frame); the constraint's frame is the target's, i's."""
    R_i = camp.scans[i].pose[:3, :3]
    free = [np.r_[R_i.T @ m, 0.0, 0.0, 0.0] for m in moves]
    vectors = np.linalg.qr(np.column_stack(free + list(np.eye(6))))[0][:, :6]
    values = np.r_[[1e-4] * len(moves), np.ones(6 - len(moves))]
    return Constraint(values, vectors[:, 0], 1e-4, 500, np.zeros(3), 1.0, vectors=vectors)


def test_a_ring_of_four_with_one_trusted_pair_corroborates_its_other_three_where_it_closes(camp):
    # a turntable of 4 stops: each scan overlaps its two neighbours only, no triangle; one neighbour pair trusted, three
    # right but weakly pinned (the 4-stop simulated turntable: 2 of 4 scans placed in 28 s before, 4 of 4 in 4 s); no
    # level from three trusted pairs is needed for it (one sets it), but a pair turned 5 deg opens the ring: none used
    ring = [(0, 1), (1, 2), (2, 3), (0, 3)]
    for turned, used in ((0.0, [(0, 1), (0, 3), (1, 2)]), (5.0, [])):
        c = _campaign(camp)
        _pair(c, camp, 2, 3)
        for (i, j), way in zip(ring[:2] + ring[3:], (X, Y, Z)):  # each weakly pinned, free its own way
            _pair(c, camp, i, j, T=_turned(camp, i, j, turned) if (i, j) == (1, 2) else None, trusted=False,
                  misfit=0.6, stop=BOUND)
            c.pairs[i, j] = replace(c.pairs[i, j], free=_free_world(camp, i, j, [way]))
        s = merge_graph.screen(c)
        assert sorted(s.corroborated) == used
        if used:
            assert "closes the loop through scan" in s.corroborated[0, 1] and "," in s.corroborated[0, 1]
            g, _ = merge_graph.build(c)
            assert g.placed[:4] == [True] * 4
            assert all(np.allclose(invert(g.poses[i]) @ g.poses[j], _truth(camp, i, j), atol=1e-6) for i, j in ring)
            c.pairs[0, 1] = replace(c.pairs[0, 1], free=None)  # pinned yet not trusted: one trusted pair's level is
            assert (0, 1) not in merge_graph.screen(c).corroborated  # no median's, such a pair is not taken at it


def test_where_a_rings_pairs_leave_scans_too_uncertain_the_graph_without_them_is_kept(camp, monkeypatch):
    # the 5-stop simulated turntable: its ring of three weakly pinned pairs (one 1 deg off) closed, but with them the
    # graph's uncertainty left every scan out, even those the trusted pairs place; without them those three stay
    ring = [(0, 1), (1, 2), (2, 3), (0, 3)]
    c = _campaign(camp)
    _pair(c, camp, 2, 3)
    for (i, j), way in zip(ring[:2] + ring[3:], (X, Y, Z)):
        _pair(c, camp, i, j, trusted=False, misfit=0.6, stop=BOUND)
        c.pairs[i, j] = replace(c.pairs[i, j], free=_free_world(camp, i, j, [way]))
    g, screened = merge_graph.build(c)
    assert screened.rings == {(0, 1), (0, 3), (1, 2)} and g.placed[:4] == [True] * 4
    drift = merge_graph.drift

    def strict(c, g, keys):  # as if the ring's pairs left every scan too uncertain
        out = drift(c, g, keys)
        return replace(out, poses=[None] * len(out.poses)) if (0, 1) in keys else out

    monkeypatch.setattr(merge_graph, "drift", strict)
    kept, after = merge_graph.vouched(c, g, screened)
    assert [p is not None for p in kept.poses[:4]] == [False, False, True, True]  # the trusted pair's two scans
    assert after.rings == frozenset() and (0, 1) not in after.usable and (2, 3) in after.usable
    assert "the graph could vouch for fewer scans" in after.why[0, 1][1]


def test_a_pair_a_loop_of_trusted_pairs_leaves_open_is_vouched_for_by_no_longer_loop(camp):
    # scan 4 turned half a turn the same way onto scans 0 and 3, neither trusted: the loop 4-0-2-3 of them and two
    # trusted pairs closes, but the trusted 0-1-4 leaves (0, 4) open and the trusted 3-2-0-1-4 leaves (3, 4) open, so
    # neither is used (before that rule the graph placed scan 4 half a turn off and dropped scan 1)
    twin = from_params(np.r_[0, 0, 0, 0, 0, np.radians(180.0)])
    c = _campaign(camp)
    for k in [(0, 1), (1, 4), (0, 2), (2, 3)]:
        _pair(c, camp, *k)
    for i, j in [(0, 4), (3, 4)]:
        _pair(c, camp, i, j, T=_truth(camp, i, j) @ twin, trusted=False, misfit=0.6, stop=BOUND)
        c.pairs[i, j] = replace(c.pairs[i, j], free=_free_world(camp, i, j, [X if i else Y]))
    assert merge_graph.screen(c).corroborated == {}
    g, _ = merge_graph.build(c)
    assert g.placed[:5] == [True] * 5
    assert all(np.allclose(g.poses[k], _truth(camp, 0, k), atol=1e-6) for k in range(5))


def _brute_paths(near: dict, j: int, path: list, length: int) -> list:
    """Every simple path from ``path`` on to j of ``length`` pairs, not through j before its end, by brute force."""
    if len(path) == length:
        return [path + [j]] if j in near.get(path[-1], ()) else []
    return [p for k in near.get(path[-1], ()) if k != j and k not in path for p in _brute_paths(near, j, path + [k],
                                                                                                length)]


def test_the_loops_paths_are_every_simple_path_of_their_length_in_order():
    rng = np.random.default_rng(0)
    for _ in range(20):
        pairs = {(a, b) for a in range(12) for b in range(a + 1, 12) if rng.random() < 0.3}
        near = merge_graph._partners(pairs)
        i, j = sorted(pairs)[0]
        for length in (2, 3, 4):
            assert list(merge_graph._paths(near, i, j, length)) == _brute_paths(near, j, [i], length)


@pytest.mark.parametrize("second, vouched", [(Y, True), (X, False), (None, True)])
def test_two_pairs_of_a_ring_that_share_no_scan_but_slide_one_way_do_not_vouch_for_each_other(camp, second, vouched):
    # in the ring 0-1-2-3, (0, 1) and (2, 3) not trusted: slid along one motion both (scan 1 against 0 and scan 3
    # against 2 by the same translation, one forward and one back), the ring still closes, so it says nothing of where
    # either lies (alike's test, for pairs apart in a longer loop); along two motions, or one pair pinned, it pins both
    c = _campaign(camp)
    _pair(c, camp, 1, 2)
    _pair(c, camp, 0, 3)
    _pair(c, camp, 4, 5)  # a third trusted pair: the level a median's (a pinned pair not trusted is taken at it)
    _pair(c, camp, 0, 1, trusted=False, misfit=0.6, stop=BOUND)
    _pair(c, camp, 2, 3, trusted=False, misfit=0.6, stop=BOUND)
    c.pairs[0, 1] = replace(c.pairs[0, 1], free=_free_world(camp, 0, 1, [X]))
    if second is not None:
        c.pairs[2, 3] = replace(c.pairs[2, 3], free=_free_world(camp, 2, 3, [second]))
    s = merge_graph.screen(c)
    assert sorted(s.corroborated) == ([(0, 1), (2, 3)] if vouched else [])
    assert merge_graph.loop_leaves_free(c, [(0, 1), (0, 3), (3, 2), (2, 1)]) is (not vouched)  # 1 -> 0 -> 3 -> 2 -> 1
    if not vouched:
        assert all("leave one motion free together" in s.why[k][1] for k in ((0, 1), (2, 3)))


# ---- rounds ----

def test_the_next_round_registers_again_from_the_graph_and_measures_only_near_pairs(camp):
    c = _campaign(camp)
    twin = from_params(np.r_[0, 0, 0, 0, 0, np.radians(120.0)])
    for i in range(7):
        _pair(c, camp, i, i + 1)
    _pair(c, camp, 0, 7)
    _pair(c, camp, 2, 4, T=_truth(camp, 2, 4) @ twin, trusted=False, misfit=8.0, stop=BOUND)  # wrong, not trusted
    g, screened = c.graph()
    assert all(g.placed)
    near = merge_rounds.near_pairs(c, g, {screened.usable[k] for k in g.kept})
    assert (2, 4) in near and all(merge_rounds.close(c, g.poses, i, j) for i, j in near)
    tasks = merge_rounds.next_tasks(c, g, screened)
    again = [t for t in tasks if (t.i, t.j) == (2, 4)]
    assert len(again) == 1 and again[0].start is Start.GRAPH_POSE and again[0].attempt == 1
    assert np.allclose(again[0].T0, _truth(camp, 2, 4), atol=1e-6)  # from the graph's pose, not its own
    # between scans the graph places, each ends at a weakly pinned pose, as round 1's from a guess: the next graph
    # judges it (and one no loop corroborates is tried once more with every stage: below)
    assert all(t.end_on_weak for t in tasks if t.start is Start.GRAPH_POSE)
    c.round = c.mc.max_rounds - 1  # the last regular round's: no round after it could give them every stage
    assert not any(t.end_on_weak for t in merge_rounds.next_tasks(c, g, screened))
    c.round = 0
    c.mc = replace(c.mc, guess_ends_on_weak=False)
    assert not any(t.end_on_weak for t in merge_rounds.next_tasks(c, g, screened))
    # pairs that match too little under the poses found are not registered
    assert all(c.shares[t.i, t.j] >= c.mc.min_overlap for t in tasks)


def test_the_round_after_the_cues_takes_long_links_among_more_partners_once(camp):
    # from no poses the cue's pairs are each scan's nearest, and a chain of them drifts: the next round measures
    # long_measure_partners likeliest partners and takes half of each scan's best as long links, once
    c = _campaign(camp, measure_partners=2, long_measure_partners=6, max_partners=2)
    assert c.mode == "features" and not c.long_links
    for i in range(len(camp.scans) - 1):
        _pair(c, camp, i, i + 1, start=Start.NO_GUESS)
    g, screened = c.graph()
    measured = []
    near_pairs = merge_rounds.near_pairs

    def spy(c_, g_, used, partners=None):
        measured.append(partners)
        return near_pairs(c_, g_, used, partners)

    merge_rounds.near_pairs = spy
    try:
        first = merge_rounds.next_tasks(c, g, screened)
        second = merge_rounds.next_tasks(c, g, screened)
    finally:
        merge_rounds.near_pairs = near_pairs
    assert measured == [6, None] and c.long_links

    def apart(tasks):
        n = len(camp.scans)
        return {min(abs(t.j - t.i), n - abs(t.j - t.i)) for t in tasks if t.start is Start.GRAPH_POSE}

    assert max(apart(first)) > max(apart(second), default=0)


def _ring_with_a_slid_pair(camp):
    """A campaign whose scans 0-7 close a ring of trusted pairs, the stop of a weakly pinned registration, and pair
    2 -> 5 slid 30 units along x: at the trusted pairs' level, off the ring's loops."""
    c = _campaign(camp)
    for i in range(7):
        _pair(c, camp, i, i + 1)
    _pair(c, camp, 0, 7)
    return c, Stop(StopReason.WEAKLY_PINNED), _truth(camp, 2, 5) @ from_params(np.r_[30.0, 0, 0, 0, 0, 0])


def test_a_weakly_pinned_pair_no_loop_corroborates_is_registered_again_with_every_stage(camp):
    from rangereg.core.merge_tasks import PairTask

    c, weak, slid = _ring_with_a_slid_pair(camp)
    T0 = _truth(camp, 2, 5) @ from_params(np.r_[0, 0, 0, 0.1, 0, 0])
    _pair(c, camp, 2, 5, T=slid, trusted=False, misfit=0.6, stop=weak)
    c.tasks[2, 5] = PairTask(2, 5, T0, 30.0, None, start=Start.ROUGH_POSES, fallback_steps=0, end_on_weak=True)
    g, screened = c.graph()
    assert (2, 5) not in screened.usable
    tasks = [t for t in merge_rounds.next_tasks(c, g, screened) if (t.i, t.j) == (2, 5)]
    # as first asked (its guess and region), now with every stage: not ended at a weakly pinned pose
    assert len(tasks) == 1 and tasks[0].attempt == 1 and not tasks[0].end_on_weak
    assert tasks[0].start is Start.ROUGH_POSES and tasks[0].rotation_deg == 30.0 and np.array_equal(tasks[0].T0, T0)
    # once only: a second weakly pinned end is the pair's answer
    _pair(c, camp, 2, 5, T=slid, trusted=False, misfit=0.6, stop=weak)
    g, screened = c.graph()
    assert not [t for t in merge_rounds.next_tasks(c, g, screened) if (t.i, t.j) == (2, 5)]


def test_a_retry_from_the_graph_that_ends_weakly_pinned_uncorroborated_gets_every_stage_once(camp):
    from rangereg.core.merge_tasks import PairTask

    c, weak, slid = _ring_with_a_slid_pair(camp)
    _pair(c, camp, 2, 5, trusted=False, misfit=8.0, stop=BOUND)  # round 1: nothing
    _pair(c, camp, 2, 5, T=slid, trusted=False, misfit=0.6, stop=weak)  # round 2, from the graph: ended weakly pinned
    T_graph = _truth(camp, 2, 5)
    c.tasks[2, 5] = PairTask(2, 5, T_graph, 5.0, None, attempt=1, start=Start.GRAPH_POSE, end_on_weak=True)
    g, screened = c.graph()
    assert (2, 5) not in screened.usable and c.tried[2, 5] == 2
    tasks = [t for t in merge_rounds.next_tasks(c, g, screened) if (t.i, t.j) == (2, 5)]
    # as last asked (the graph's pose and region), with every stage, numbered as the pair's third registration
    assert len(tasks) == 1 and not tasks[0].end_on_weak and tasks[0].attempt == 2
    assert tasks[0].start is Start.GRAPH_POSE and np.array_equal(tasks[0].T0, T_graph)
    _pair(c, camp, 2, 5, T=slid, trusted=False, misfit=0.6, stop=weak)
    g, screened = c.graph()
    assert not [t for t in merge_rounds.next_tasks(c, g, screened) if (t.i, t.j) == (2, 5)]


def test_a_weakly_pinned_groups_link_is_tried_again_as_asked_once_a_round_then_with_no_guess(camp):
    from rangereg.core.merge_tasks import PairTask

    c = _campaign(camp, [s.pose for s in camp.scans])
    for i in range(4):
        _pair(c, camp, i, i + 1)  # scans 0-4 joined; 5-7 reached only by the weakly pinned (4, 5)
    weak = Stop(StopReason.WEAKLY_PINNED)
    slid = _truth(camp, 4, 5) @ from_params(np.r_[30.0, 0, 0, 0, 0, 0])
    _pair(c, camp, 4, 5, T=slid, trusted=False, misfit=0.6, stop=weak)
    c.tasks[4, 5] = PairTask(4, 5, _truth(camp, 4, 5), 30.0, None, start=Start.ROUGH_POSES, fallback_steps=0,
                             end_on_weak=True)
    g, screened = c.graph()
    assert not g.placed[5]
    link = [t for t in merge_rounds.next_tasks(c, g, screened) if (t.i, t.j) == (4, 5)]
    assert len(link) == 1 and link[0].start is Start.ROUGH_POSES and not link[0].end_on_weak  # not a join's too
    _pair(c, camp, 4, 5, T=slid, trusted=False, misfit=8.0, stop=BOUND)  # that try found nothing better
    g, screened = c.graph()
    link = [t for t in merge_rounds.next_tasks(c, g, screened) if (t.i, t.j) == (4, 5)]
    assert len(link) == 1 and link[0].start is Start.NO_GUESS  # the join's one try with no guess, as before


# ---- groups ----

def test_a_turntable_arc_has_its_ends_where_its_gap_is():
    R = [from_params(np.r_[0, 0, 0, 0, 0, np.radians(a)])[:3, :3] for a in (0, 30, 60, 90, 300, 330)]
    assert shared_axis(R) is not None
    assert set(arc_ends(R)) == {3, 4}  # 90 and 300 deg: either side of the gap
    assert arc_ends(R[:1]) == (0, 0)
    tilted = [from_params(np.r_[0, 0, 0, np.radians(a), np.radians(a), 0])[:3, :3] for a in (0, 40)]
    assert shared_axis(tilted + [from_params(np.r_[0, 0, 0, 0, 0, np.radians(90)])[:3, :3]]) is None


def test_a_group_apart_is_tried_first_by_the_ends_of_the_rings_arcs(camp):
    # scans 0-3 joined among themselves, 4-7 among themselves, nothing between: a ring missing two links
    c = _campaign(camp)
    for i in (0, 1, 2, 4, 5, 6):
        _pair(c, camp, i, i + 1)
    g, screened = c.graph()
    assert sum(g.placed) == 4
    used = sorted(screened.usable[k] for k in g.kept)
    (inside,) = merge_groups.groups(c, g, used)
    placed = [k for k in range(8) if g.placed[k]]
    ends = merge_groups.ring_pairs(c, g, inside, placed)
    assert {(3, 4), (0, 7)} <= set(ends)  # the two missing links are among the ends' pairs
    tasks = merge_groups.join_tasks(c, g, used)
    assert tasks and all(t.start is Start.NO_GUESS for t in tasks)
    assert {(t.i, t.j) for t in tasks} <= set(ends) and len(tasks) == c.mc.reach_partners


def test_groups_apart_are_paired_with_each_other_not_only_with_the_placed_scans(camp):
    # no poses; 0-1 joined to the reference, 3-4 and 5-6 joined among themselves, 2 and 7 alone: a group apart
    # may be joined to another group apart first (the two then reach the reference together), as on the crops
    # of the 24-stop turntable from no poses, where 0-1 alone reached the reference and the groups 13-14,
    # 15-16, 18-21 and 22-23, each right and trusted, were tried only against scans 0 and 1
    c = _campaign(camp, reach_partners=8)
    for i, j in ((0, 1), (3, 4), (5, 6)):
        _pair(c, camp, i, j)
    g, screened = c.graph()
    assert [k for k in range(8) if g.placed[k]] == [0, 1]
    tasks = merge_groups.join_tasks(c, g, sorted(screened.usable[k] for k in g.kept))
    keys = [(t.i, t.j) for t in tasks]
    assert len(set(keys)) == len(keys)  # a pair between two groups is one task, not one per group
    apart = [k for k in keys if not g.placed[k[0]] and not g.placed[k[1]]]
    assert apart and all(t.start is Start.NO_GUESS for t in tasks)
    # the pair of neighbours across two groups apart is among them (4-5: the cue's likeliest)
    assert (4, 5) in keys


def test_a_scan_at_the_end_of_a_long_open_chain_is_not_placed_and_a_closing_pair_places_it(camp):
    # every pair right, but each pins its scans only so far: along the open chain 0-1-...-7 the uncertainty
    # adds up, and the scans far from the reference are said not placed (why: their pose's uncertainty);
    # the pair 0-7 closes the ring and takes it down, so every scan is placed
    # (8 whole scans 45 deg apart: a pair's 0.09 deg, one sd; 3 sd at scan 4-7 0.53-0.62 deg, at most 0.30 on the ring)
    tight = dict(drift_sigmas=3.0, drift_rotation_deg=0.5, drift_translation=0.01)
    c = _campaign(camp, **tight)
    for i in range(7):
        _pair(c, camp, i, i + 1)
    g, screened = c.graph()
    assert all(g.placed)  # the rounds plan on every joined scan
    g = merge_graph.drift(c, g, screened.usable)
    far = [k for k in range(8) if not g.placed[k]]
    assert g.placed[:2] == [True, True] and far and max(far) == 7 and far == list(range(min(far), 8))
    pairs = merge_report.pair_statuses(c, g, screened)
    reports = merge_report.scan_reports(c, g, pairs)
    assert all("uncertain" in reports[k].why for k in far)
    assert any(p.rejection is Rejection.NOT_JOINED and "uncertain" in p.reason for p in pairs)
    _pair(c, camp, 0, 7)
    g, screened = c.graph()
    assert all(merge_graph.drift(c, g, screened.usable).placed) and not c.loose
    # with the defaults every scan of the open chain of whole scans is placed
    c = _campaign(camp)
    for i in range(7):
        _pair(c, camp, i, i + 1)
    g, screened = c.graph()
    assert all(merge_graph.drift(c, g, screened.usable).placed)


# ---- report ----

def test_the_report_gives_typed_statuses_and_the_rings_closing_residual(camp):
    c = _campaign(camp)
    for i in range(7):
        _pair(c, camp, i, i + 1)
    _pair(c, camp, 0, 7)
    _pair(c, camp, 3, 5, trusted=False, misfit=7.0, stop=BOUND)
    g, screened = merge_graph.build(c)
    pairs = merge_report.pair_statuses(c, g, screened)
    by = {p.key: p for p in pairs}
    assert by[3, 5].status is PairStatus.REJECTED and by[3, 5].rejection is Rejection.NOT_TRUSTED
    assert all(by[i, i + 1].status is PairStatus.USED and by[i, i + 1].rejection is None for i in range(7))
    scans = merge_report.scan_reports(c, g, pairs)
    assert all(s.status is ScanStatus.PLACED for s in scans)
    (ring,) = merge_report.rings(c, g, screened)
    assert sorted(ring.order) == list(range(8)) and ring.residual[0] < 1e-6 and ring.after[0] < 1e-6


# ---- progress ----

def test_a_loop_inside_a_group_not_placed_is_not_reported_as_a_ring(camp):
    # scans 0-2 placed; 4, 5 and 6 a closed triangle of trusted pairs, joined to nothing placed: the graph
    # keeps their pairs, but they have no final poses (a crop campaign's merge once failed here)
    c = _campaign(camp)
    for i, j in ((0, 1), (1, 2), (0, 2), (4, 5), (5, 6), (4, 6)):
        _pair(c, camp, i, j)
    g, screened = c.graph()
    assert [k for k in range(8) if g.placed[k]] == [0, 1, 2]
    loops = merge_report.rings(c, g, screened)
    assert [set(r.order) for r in loops] == [{0, 1, 2}]


def test_progress_counts_every_round_and_estimates_from_the_median_task():
    events: list[MergeProgress] = []
    counter = Counter(Step.PAIRS, events.append, t0=0.0, every=0.0)
    done = counter.begin(10, 1)
    counter.durations = [5.0]  # a first task that built the scans' geometry
    counter.done = 1
    done(1)
    counter.durations += [0.1] * 4
    counter.done = 5
    assert counter.estimate() == pytest.approx(0.1 * 5)  # the first tasks (that built the geometry) left out
    for k in range(6, 11):
        done(k)
    assert events[-1].done == events[-1].total == 10 and events[-1].finished and events[-1].estimate is None
    more = counter.begin(4, 2)
    more(4)
    assert (events[-1].round, events[-1].done, events[-1].total) == (2, 14, 14)
    assert str(events[-1]).startswith("pairs, round 2 14/14") and str(events[-1]).endswith("done")
    assert counter.forecasts and counter.forecasts[0].left < 10


def test_a_scan_and_its_quality_are_made_once_when_two_threads_ask_at_once(camp, monkeypatch):
    # a task and the qualities made ahead for the model (core.merge._Campaign._qualities_ahead) may ask together
    import threading
    from concurrent.futures import ThreadPoolExecutor

    c = _campaign(camp)
    merge_tasks.clear_geometry_cache()
    made, real = [], merge_tasks.Surface.from_scan
    gate = threading.Barrier(2, timeout=10)

    def slow(scan):
        made.append(scan)
        return real(scan)

    monkeypatch.setattr(merge_tasks.Surface, "from_scan", staticmethod(slow))

    def ask(_):
        gate.wait()
        return merge_tasks.built(c.shared, 0), merge_tasks.quality(c.shared, 0)

    with ThreadPoolExecutor(2) as pool:
        (a, qa), (b, qb) = pool.map(ask, range(2))
    assert len(made) == 1 and a is b and qa is qb


def test_two_merges_under_way_in_one_process_keep_each_others_scans(camp):
    # two of the workbench's tabs merging different scan sets: each set's scans built once, not freed by the other's
    # tasks; a third set frees the one used least recently
    from dataclasses import replace as with_

    c = _campaign(camp)
    merge_tasks.clear_geometry_cache()
    a, b, third = c.shared, with_(c.shared, token="another set"), with_(c.shared, token="a third set")
    first_a, first_b = merge_tasks.built(a, 0), merge_tasks.built(b, 0)
    assert merge_tasks.built(a, 0) is first_a and merge_tasks.built(b, 0) is first_b
    merge_tasks.built(third, 0)  # a was used least recently
    assert merge_tasks.built(b, 0) is first_b and merge_tasks.built(a, 0) is not first_a
    merge_tasks.clear_geometry_cache()


def test_a_merge_makes_its_qualities_ahead_only_for_a_model_and_they_are_the_scans_own(camp):
    from rangereg.core.fuse import sample_quality
    from rangereg.core.merge import merge

    def made() -> dict:
        cache = next(iter(merge_tasks._BUILT.values()))
        return {k[1]: v for k, v in cache.items() if isinstance(k, tuple) and k[0] == "quality"}

    scans = camp.scans[:2]
    merge_tasks.clear_geometry_cache()
    assert merge(scans, build_model=False).model is None and made() == {}
    merge_tasks.clear_geometry_cache()
    assert merge(scans, build_model=True).model is not None and sorted(made()) == [0, 1]
    for k, (n, q) in made().items():
        n0, q0 = sample_quality(scans[k])
        assert np.array_equal(n, n0) and np.array_equal(q, q0)


def test_qualities_made_ahead_leave_a_scan_whose_quality_fails_to_the_model(camp, monkeypatch):
    # made ahead for every scan, the quality of one the graph never places (its failure no merge's concern before)
    # must not end the merge; where the model asks for it, the failure is raised there, as before
    c = _campaign(camp)
    merge_tasks.clear_geometry_cache()
    real = merge_tasks.sample_quality
    bad = c.scans[1].name

    def failing(scan):
        if scan.name == bad:
            raise ValueError("no normals")
        return real(scan)

    monkeypatch.setattr(merge_tasks, "sample_quality", failing)
    made, _ = c._qualities_ahead()
    assert made.result(timeout=120) is None
    cache = next(iter(merge_tasks._BUILT.values()))
    assert ("quality", 1) not in cache and all(("quality", k) in cache for k in range(c.n) if k != 1)
    with pytest.raises(ValueError, match="no normals"):
        c.sample_quality(1)


_EXIT_WHILE_QUALITIES = """
import time
import numpy as np
from rangereg.core import merge_tasks
from rangereg.core.merge import MergeConfig, _Campaign, serial_map
from rangereg.core.register import Config
from rangereg.core.turntable import make_campaign
from tests.test_campaign import SMALL

camp = make_campaign(3, SMALL)
c = _Campaign(camp.scans, [np.eye(4)] * len(camp.scans), False, Config(method="global"), MergeConfig(),
              lambda e: None, serial_map)
merge_tasks.sample_quality = lambda scan: time.sleep(2)  # 8 scans: 16 s of qualities
c._qualities_ahead()
time.sleep(0.3)
print(time.time(), flush=True)
"""


def test_qualities_made_ahead_do_not_hold_the_exit_of_a_process_whose_merge_is_left_running():
    # the page runs merges on daemon threads: a merge left running at the end must not keep the process alive
    import subprocess
    import sys
    import time

    from tests.conftest import ROOT

    p = subprocess.run([sys.executable, "-c", _EXIT_WHILE_QUALITIES], capture_output=True, text=True, timeout=120,
                       cwd=ROOT)
    ended = time.time()
    assert p.returncode == 0, p.stderr
    assert ended - float(p.stdout.split()[-1]) < 5.0  # (16 s when the qualities held the exit)
