"""The merge's graph step (core.merge): which registered pairs the pose graph may use, and the graph.

A pair the pose graph may use is trusted, and not an outlier among the campaign's trusted pairs (its E
or its misfit far above their median: the scans of one campaign share a sensor, so right pairs agree
at much the same level). A pair the pair threshold did not trust is used too where the campaign
corroborates it: its misfit is at the trusted pairs' level (set by one trusted pair or more; three before the
outliers among them are sought) and it closes a triangle, within the graph's cycle tolerance, with two other such
pairs of which one is trusted (three registrations that agree about one motion: the campaign's own evidence, which a
pair alone cannot give), unless the two not trusted share a scan that both leave free along one motion
(:func:`alike`: the triangle closes wherever along it both ended). Where no triangle does, a longer loop of such
pairs (up to LOOP_PAIRS, one trusted) may, unless its untrusted pairs can slide together with the loop closed
(:func:`loop_leaves_free`): a ring of scans that overlap only their neighbours has no triangle. A pair whose pose
puts points where the other scan's sensor looked through empty space (core.intrusion: a twin, as a room turned half
a turn) is neither corroborated nor a leg of another's triangle or loop: the
threshold's free-space test says the pose is wrong, not merely in doubt, and one scan registered onto two frames a
step apart finds the same twin twice (the RGB-D drive at 0.4 m, seed 1: frame 11 onto frames 2 and 3, 179.9 and
178.6 deg off, 7.8 and 10.4 % looked through, closed a triangle with the trusted 2-3 and placed 4 frames half a turn
off). Where that test errs the other way (its notes: an object wider than 2 m fused from views all round reads
0.16-0.20 at its truth), such a right pair is now left out too. The graph
(core.posegraph) keeps the pairs that close; the poses are in the first scan's frame when its group is
the largest, else in the largest group's first scan's. A scan the kept pairs join only so loosely that
its pose is in doubt is not placed (:func:`drift`): right pairs are each a little off, and along an
open chain (a ring that cannot close through scans no pair places) their errors add up.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from .merge_pairs import labels
from .merge_result import PairResult, Rejection
from .posegraph import (
    Edge,
    Graph,
    Tolerance,
    covariances,
    disagreement,
    information_matrix,
    plane_information,
    residual,
    solve,
    spread,
)
from .threshold import ALONG_THE_FREE_MOTION, FACTOR
from .transforms import apply, invert

# core.merge's campaign state and knobs, by name only: core.merge imports this module
_Campaign = Any



@dataclass(frozen=True)
class Screened:
    """The pairs (keys) the graph may use, for each other registered pair (kind, why in words), and for
    each usable pair the threshold did not trust the triangle or longer loop that corroborates it (in words)."""

    usable: list
    why: dict
    corroborated: dict = field(default_factory=dict)
    rings: frozenset = frozenset()  # of the corroborated, those by a loop longer than a triangle

    def rejected(self, key: tuple[int, int]) -> bool:
        return key in self.why


def screen(c: _Campaign) -> Screened:
    """The trusted pairs the graph may use, and why the others may not (module notes)."""
    why: dict[tuple[int, int], tuple[Rejection, str]] = {}
    trusted = [k for k, p in c.pairs.items() if p.trusted]
    bound = error_bound = None  # the misfit and the E of the trusted pairs' level (the outlier bounds)
    for k, p in c.pairs.items():
        if not p.registered:
            why[k] = (Rejection.NOT_REGISTERED, p.stop_text)
        elif not p.trusted:
            why[k] = (Rejection.NOT_TRUSTED, "not trusted: too little of the pair overlaps to judge it" if p.misfit is None
                      else f"not trusted (misfit {p.misfit:.3g}; a twin: its points lie where the other scan's sensor "
                           "looked through empty space, so no loop vouches for it)" if p.twin
                      else f"not trusted (misfit {p.misfit:.3g})")
    if trusted:
        median = float(np.median([c.pairs[k].error for k in trusted]))
        misfits = [c.pairs[k].misfit for k in trusted if c.pairs[k].misfit is not None]
        typical = float(np.median(misfits)) if misfits else None
        bound = c.mc.outlier_misfit * typical if typical else None
        error_bound = c.mc.outlier_error * median
    if len(trusted) >= 3:
        for k in trusted:
            p = c.pairs[k]
            if p.error > error_bound:
                why[k] = (Rejection.OUTLIER, f"E far above the other trusted pairs' ({p.error / median:.3g} x their median)")
            elif bound and p.misfit is not None and p.misfit > bound:
                why[k] = (Rejection.OUTLIER, f"misfit far above the other trusted pairs' ({p.misfit:.3g}, "
                                             f"{p.misfit / typical:.3g} x their median)")
    usable = [k for k in trusted if k not in why]
    refused: dict[tuple[int, int], str] = {}
    rings: set[tuple[int, int]] = set()
    corroborated = corroborate(c, usable, bound, error_bound, refused, rings) if bound and error_bound else {}
    for k in corroborated:
        del why[k]
    for k, note in refused.items():
        why[k] = (why[k][0], why[k][1] + note)
    return Screened(usable + sorted(corroborated), why, corroborated, frozenset(rings))


def corroborate(c: _Campaign, usable: list[tuple[int, int]], bound: float, error_bound: float,
                refused: dict[tuple[int, int], str] | None = None,
                rings: set[tuple[int, int]] | None = None) -> dict[tuple[int, int], str]:
    """The untrusted pairs the campaign corroborates (module notes), each with its triangle's or loop's words;
    ``refused`` receives, for a pair not corroborated whose triangle or loop closed, why it did not count (:func:`alike`,
    :func:`loop_leaves_free`); ``rings`` receives those a loop longer than a triangle corroborates.

    ``usable``: the trusted pairs kept so far; ``bound``, ``error_bound``: the misfit and the E (squared
    units) of the trusted pairs' level (the outlier bounds). Measured on the 24-stop simulated
    turntable's crops 0 (seed 0; right: 2 deg / 2 mm), the pairs of a merge without this step: from the
    "frame" starts 153 untrusted, 15 at the level (11 right, 4 off by 1.7-7 deg), 7 corroborated, all
    right (0.2-0.7 deg off); a triangle closed by any registered pairs would have let in 2 wrong ones too
    (a crop flipped 171 deg onto two neighbouring scans; misfit 3.6 and 7.3, the bound 1.7). From no
    poses: 180 untrusted, 14 at the level, all right, 9 corroborated."""
    refused = {} if refused is None else refused
    # set by fewer than three trusted pairs, the level is one or two pairs' own, not a median: only a pair that fitted
    # as a trusted one does and failed on its pinning alone (its free motion known) is taken at it
    few = len(usable) < 3
    level = set(usable) | {k for k, p in c.pairs.items() if not p.trusted and p.registered and p.misfit is not None
                            and p.misfit <= bound and p.error <= error_bound and not p.twin
                            and (not few or (p.free is not None and p.misfit < FACTOR))}
    trusted = set(usable)

    def motion(a: int, b: int) -> np.ndarray | None:
        """T_a_b of a pair at the level, either way round."""
        if (a, b) in level:
            return c.pairs[a, b].T_i_j
        return invert(c.pairs[b, a].T_i_j) if (b, a) in level else None

    def on_trust(a: int, b: int) -> bool:
        return (a, b) in trusted or (b, a) in trusted

    tol = Tolerance(c.mc.cycle_rotation_deg, c.mc.cycle_translation * c.spacing)
    on_trusted = _partners(trusted)
    # a pair a loop of trusted pairs does not close is wrong: no longer loop vouches for it, nor is it a leg of one
    wrong = {k for k in level - trusted if _contradicted(c, k, on_trusted, motion, tol)}
    near = _partners(level - wrong)
    seen = _Slides()
    out = {}
    for i, j in sorted(level - trusted):
        for k in range(c.n):
            if k in (i, j):
                continue
            T_i_k, T_k_j = motion(i, k), motion(k, j)
            if T_i_k is None or T_k_j is None or not (on_trust(i, k) or on_trust(k, j)):
                continue
            rot, move = residual(c.pairs[i, j].T_i_j, np.eye(4), T_i_k @ T_k_j, c.centers[j])
            if not tol.holds((rot, move)):
                continue
            other = (i, k) if on_trust(k, j) else (k, j)
            if alike(c, (i, j), other):
                shared = c.scans[(set(other) & {i, j}).pop()].name
                refused.setdefault((i, j), f"; it closes the loop through {c.scans[k].name}, but it and the pair "
                                           f"{c.scans[other[0]].name}-{c.scans[other[1]].name}, not trusted either, "
                                           f"leave {shared} free along one motion (the loop says nothing of where)")
                continue
            out[i, j] = (f"not trusted alone (misfit {c.pairs[i, j].misfit:.3g}); used: it closes the loop "
                         f"through {c.scans[k].name} within {rot:.2g} deg / {move:.3g}")
            refused.pop((i, j), None)
            break
        if (i, j) not in out and (i, j) not in wrong:
            _longer_loop(c, (i, j), near, trusted, motion, tol, out, refused, seen)
            if (i, j) in out and rings is not None:
                rings.add((i, j))
    return out


# A loop of up to this many pairs corroborates an untrusted pair where no triangle does (a ring of scans each
# overlapping only its neighbours has none: a turntable of 4 stops, a drive), each loop at least one pair trusted, the
# shortest first; per pair at most LOOPS_TRIED loops with a trusted pair, LOOPS_WALKED paths in all and
# LEAVES_FREE_TRIED tests of :func:`loop_leaves_free`, and LEAVES_FREE_ALL of those a screen (each ~2-4 ms: a
# synthetic ring of 100 scans, 4 partners each, 15 % trusted, every weak pair sliding one way, closed thousands of
# loops: 51 s a screen with no bound, 28 s with 20 tests a pair).
LOOP_PAIRS = 6
LOOPS_TRIED = 200
LOOPS_WALKED = 5000
LEAVES_FREE_TRIED = 4
LEAVES_FREE_ALL = 300


@dataclass
class _Slides:
    """A screen's tests of :func:`loop_leaves_free`: how many were made, and the sets of untrusted pairs found to
    slide together (a loop holding any of them does too: more pairs only lower the smallest singular value)."""

    tests: int = 0
    free: list = field(default_factory=list)

    def known_free(self, pairs: frozenset) -> bool:
        return any(f <= pairs for f in self.free)


def _partners(pairs: set) -> dict[int, list[int]]:
    """Each scan's partners in ``pairs`` ((a, b) keys), by index."""
    near: dict[int, list[int]] = {}
    for a, b in pairs:
        near.setdefault(a, []).append(b)
        near.setdefault(b, []).append(a)
    return {k: sorted(v) for k, v in near.items()}


def _contradicted(c: _Campaign, key: tuple[int, int], on_trusted: dict[int, list[int]], motion,
                  tol: Tolerance) -> bool:
    """Whether a loop of up to LOOP_PAIRS pairs, all trusted but ``key`` (i, j), leaves ``key`` open by more than
    ``tol`` (``on_trusted``: each scan's trusted partners; ``motion(a, b)`` -> T_a_b)."""
    i, j = key
    walked = 0
    for length in range(2, LOOP_PAIRS):
        for path in _paths(on_trusted, i, j, length):
            walked += 1
            if walked > LOOPS_WALKED:
                return False
            chain = np.eye(4)
            for a, b in zip(path[:-1], path[1:]):
                chain = chain @ motion(a, b)
            if not tol.holds(residual(c.pairs[key].T_i_j, np.eye(4), chain, c.centers[j])):
                return True
    return False


def _longer_loop(c: _Campaign, key: tuple[int, int], near: dict[int, list[int]], trusted: set, motion,
                 tol: Tolerance, out: dict, refused: dict, seen: _Slides) -> None:
    """Corroborate the untrusted pair ``key`` (i, j) by a loop of 4 to LOOP_PAIRS pairs at the level (``near``: each
    scan's partners at it; at least one pair ``trusted``; ``motion(a, b)`` -> T_a_b) that closes within ``tol`` and
    whose untrusted pairs leave no motion free together (:func:`loop_leaves_free`; ``seen``: this screen's tests of
    it, kept across pairs): into ``out`` (the words), or why the closing loop did not count into ``refused``."""
    i, j = key
    tried = walked = tests = 0
    for length in range(3, LOOP_PAIRS):  # pairs besides (i, j); triangles (2) are corroborate's own
        for path in _paths(near, i, j, length):
            walked += 1
            steps = list(zip(path[:-1], path[1:]))
            if walked > LOOPS_WALKED or tried >= LOOPS_TRIED or tests >= LEAVES_FREE_TRIED or seen.tests >= LEAVES_FREE_ALL:
                return
            if not any(s in trusted or s[::-1] in trusted for s in steps):
                continue
            tried += 1
            chain = np.eye(4)
            for a, b in steps:
                chain = chain @ motion(a, b)
            rot, move = residual(c.pairs[i, j].T_i_j, np.eye(4), chain, c.centers[j])
            if not tol.holds((rot, move)):
                continue
            through = ", ".join(c.scans[k].name for k in path[1:-1])
            weak = frozenset({key} | {s if s in c.pairs else s[::-1] for s in steps} - trusted)
            if not seen.known_free(weak):
                tests += 1
                seen.tests += 1
                if loop_leaves_free(c, [key] + steps):
                    seen.free.append(weak)
            if seen.known_free(weak):
                refused.setdefault(key, f"; it closes the loop through {through}, but the pairs of that loop not "
                                        "trusted leave one motion free together (the loop says nothing of where)")
                continue
            out[key] = (f"not trusted alone (misfit {c.pairs[key].misfit:.3g}); used: it closes the loop through "
                        f"{through} within {rot:.2g} deg / {move:.3g}")
            refused.pop(key, None)
            return


def _paths(near: dict[int, list[int]], i: int, j: int, length: int) -> Iterator[list[int]]:
    """The simple paths i -> ... -> j of ``length`` pairs over ``near`` (scan -> its partners, by index) that do not
    take the pair (i, j) itself, in a fixed order; a partial path too far from j to end in time is not walked on."""
    hops, frontier = {j: 0}, [j]  # pairs from each scan to j, not through (i, j)
    while frontier:
        ahead = []
        for a in frontier:
            for b in near.get(a, ()):
                if b not in hops and {a, b} != {i, j}:
                    hops[b] = hops[a] + 1
                    ahead.append(b)
        frontier = ahead

    def walk(path: list[int]) -> Iterator[list[int]]:
        if len(path) == length:
            if j in near.get(path[-1], ()):
                yield path + [j]
            return
        for k in near.get(path[-1], ()):
            if k != j and k not in path and len(path) + hops.get(k, length + 1) <= length:
                yield from walk(path + [k])

    yield from walk([i])


def loop_leaves_free(c: _Campaign, steps: list[tuple[int, int]]) -> bool:
    """Whether the untrusted pairs of the loop ``steps`` can slide
    together along their free motions (core.threshold.Constraint.weak) while the loop stays closed: each such slide,
    carried round the loop, moves the first scan's points; the untrusted pairs' moves (each pair's as an orthonormal
    basis, as :func:`alike` makes them) leave a combination that nearly cancels when the smallest singular value of
    their bases side by side is under sqrt(1 - ALONG_THE_FREE_MOTION): for two pairs of one motion each, :func:`alike`'s
    cosine bound (the singular values of two unit vectors side by side are sqrt(1 +- cos)), though measured on how the
    loop's closure moves its first scan, not on the scan two pairs share (for a free turn the two may differ). ``steps``: the pair
    judged (i, j) first, then the loop's path i -> ... -> j as (a, b) steps (T_a_b each, either way round in
    ``c.pairs``), so the loop runs j -> i -> ... -> j."""
    first = steps[0][1]  # the loop runs first -> ... -> first: T_first_first = inv(T_i_j) @ chain
    scan = c.scans[first]
    pts = scan.points[::max(1, len(scan.points) // 2000)]

    def closure(slid: int | None = None, v: np.ndarray | None = None) -> np.ndarray:
        out = np.eye(4)
        for n, (a, b) in enumerate(steps):
            key = (a, b) if (a, b) in c.pairs else (b, a)
            T = c.pairs[key].T_i_j
            if n == slid:
                T = c.pairs[key].free.slid(T, np.array([c.spacing]), v)[0]
            T = T if key == (a, b) else invert(T)
            out = out @ (invert(T) if n == 0 else T)
        return out

    base = apply(closure(), pts)
    bases = []
    for n, (a, b) in enumerate(steps):
        key = (a, b) if (a, b) in c.pairs else (b, a)
        p = c.pairs[key]
        if p.trusted or p.free is None:
            continue
        moves = np.stack([(apply(closure(n, v), pts) - base).ravel() for v in p.free.weak()], axis=1)
        basis, r = np.linalg.qr(moves)
        basis = basis[:, np.abs(np.diag(r)) > 1e-12 * max(float(np.abs(r).max()), 1e-300)]
        if basis.shape[1]:
            bases.append(basis)
    if len(bases) < 2:
        return False
    return bool(np.linalg.svd(np.hstack(bases), compute_uv=False).min() < np.sqrt(1.0 - ALONG_THE_FREE_MOTION))


def alike(c: _Campaign, p: tuple[int, int], q: tuple[int, int]) -> bool:
    """Whether pairs p and q (keys either way round), neither trusted, share a scan that both leave free along one
    motion: among the motions each pair's overlap leaves free (core.threshold.Constraint.weak: the weakest, and
    any other free by the eigenvalue ratio alone, as a plane leaves three), slid, one that moves the shared scan's
    points against its partner as one of the other's does, |cosine| >= ALONG_THE_FREE_MOTION (the two sets'
    nearest directions; a pair whose overlap pins every motion has none: False). Their triangle then closes
    wherever along that motion both ended, and says nothing of where. Measured (2026-12-06,
    benchmarks/sequences.py, RGB-D at 0.2 m, seed 0): frame 7's no-guess pairs onto frames 10 and 11, 0.50 and
    0.54 m along one slide, 0.9997; on the simulated turntable's crops 0 the refused triangles were 0.98-0.995
    and their pairs right: those campaigns place 35 of 72 crops instead of 39, none wrong either way."""
    p, q = (k if k in c.pairs else k[::-1] for k in (p, q))
    if p == q or c.pairs[p].free is None or c.pairs[q].free is None:
        return False
    (s,) = set(p) & set(q)
    scan = c.scans[s]
    pts = scan.points[::max(1, len(scan.points) // 2000)]
    bases = []
    for k in (p, q):
        moves = np.stack([(apply(slid_scan(c.pairs[k], s, c.spacing, v), pts) - pts).ravel()
                          for v in c.pairs[k].free.weak()], axis=1)
        basis, r = np.linalg.qr(moves)
        bases.append(basis[:, np.abs(np.diag(r)) > 1e-12 * max(float(np.abs(r).max()), 1e-300)])
    if not all(b.shape[1] for b in bases):
        return False
    return float(np.linalg.svd(bases[0].T @ bases[1], compute_uv=False).max()) >= ALONG_THE_FREE_MOTION


def slid_scan(pair: PairResult, s: int, step: float, motion: np.ndarray | None = None) -> np.ndarray:
    """(4, 4) scan s of ``pair`` moved against the pair's other scan by ``step`` units along the pair's free motion
    (or ``motion``, core.threshold.Constraint.slid), in s's own frame (s's points p go to M p)."""
    T = pair.T_i_j
    T_slid = pair.free.slid(T, np.array([step]), motion)[0]
    return invert(T) @ T_slid if s == pair.j else T @ invert(T_slid)


def weight(p: PairResult) -> float:
    """A trusted pair's weight in the pose graph's consensus: its matching share over its misfit (the pair
    threshold's, about 1 at the noise level), so a pair that fits at the noise level outweighs one the
    threshold passed near its bound (simulated turntable, crops: right pairs misfit 0.4-0.6, wrong ones
    the threshold trusted 1.8-4.4; bunny, right pairs 1.3-3.2)."""
    return max(p.overlap, 1e-3) / max(p.misfit if p.misfit is not None else 1.0, 0.25)


def edges(c: _Campaign, keys: list[tuple[int, int]]) -> list[Edge]:
    """The pose graph's edges of the pairs ``keys`` (their information matrices computed once per registration)."""
    out = []
    for i, j in keys:
        p = c.pairs[i, j]
        info_key = (i, j, c.tried[i, j])
        if info_key not in c.infos:
            c.infos[info_key] = information_matrix(c.scans[j].points, c.scans[i], 3 * c.spacing, p.T_i_j)
        out.append(Edge(i, j, p.T_i_j, weight(p), c.infos[info_key]))
    return out


def build(c: _Campaign) -> tuple[Graph, Screened]:
    """The pose graph of the usable pairs, in the reference's frame (module notes); sets ``c.reference``."""
    screened = screen(c)
    return _graph(c, screened.usable), screened


def vouched(c: _Campaign, g: Graph, screened: Screened) -> tuple[Graph, Screened]:
    """The final graph with the scans it cannot vouch for not placed (:func:`drift`). Where that leaves scans out
    and the pairs only a longer loop corroborates are among its pairs, the graph without them too, and whichever
    places more: a ring of weakly pinned pairs (the 5-stop simulated turntable, one pair 1 deg off) can leave every
    scan too uncertain, even those trusted pairs place (1 of 5 placed with the ring, 3 without it)."""
    d = drift(c, g, screened.usable)
    if not screened.rings or all(p is not None for p in d.poses):
        return d, screened
    loose, reference = dict(c.loose), c.reference
    keys = [k for k in screened.usable if k not in screened.rings]
    d2 = drift(c, _graph(c, keys), keys)
    if sum(p is not None for p in d2.poses) <= sum(p is not None for p in d.poses):
        c.loose, c.reference = loose, reference
        return d, screened
    why = dict(screened.why)
    for k in screened.rings:
        why[k] = (Rejection.NOT_TRUSTED, f"not trusted (misfit {c.pairs[k].misfit:.3g}); a loop closed through it, but "
                                         "with that loop's pairs the graph could vouch for fewer scans")
    return d2, Screened(keys, why, {k: v for k, v in screened.corroborated.items() if k not in screened.rings})


def _graph(c: _Campaign, keys: list[tuple[int, int]]) -> Graph:
    """The pose graph of the pairs ``keys``, in the reference's frame (the first scan's when its group is the
    largest); sets ``c.reference``."""
    es = edges(c, keys)
    tol = Tolerance(c.mc.cycle_rotation_deg, c.mc.cycle_translation * c.spacing)
    g = solve(c.n, es, c.centers, tol, 3 * c.spacing, c.config.seed)
    label = labels(c.n, [keys[k] for k in g.kept])
    size = {lab: label.count(lab) for lab in set(label)}
    best = max(size.values())
    c.reference = 0 if size[label[0]] == best else min(k for k in range(c.n) if size[label[k]] == best)
    if c.reference != 0:
        g = solve(c.n, es, c.centers, tol, 3 * c.spacing, c.config.seed, c.reference)
    return g


def plane_infos(c: _Campaign, keys: list[tuple[int, int]]) -> list[np.ndarray]:
    """Each pair's point-to-plane information (core.posegraph.plane_information, once per registration)."""
    out = []
    for i, j in keys:
        info_key = (i, j, c.tried[i, j])
        if info_key not in c.plane_infos:
            c.plane_infos[info_key] = plane_information(c.scans[j].points, c.scans[i], c.normals(i),
                                                        c.mc.polish_gate * c.spacing, c.pairs[i, j].T_i_j)
        out.append(c.plane_infos[info_key])
    return out


def drift(c: _Campaign, g: Graph, keys: list[tuple[int, int]]) -> Graph:
    """The graph with the scans whose pose it cannot vouch for not placed (their reason in ``c.loose``).

    The uncertainty the graph propagates to each scan (core.posegraph.covariances) from the kept pairs'
    point-to-plane information, each pair's scaled by how far its loops show it errs (the a posteriori
    variance factor of a least-squares adjustment, per pair: its chi^2 / 6 against the final poses,
    core.posegraph.disagreement, at least the median over the pairs on loops and at least 1; a pair on no
    loop, whose error nothing shows, takes that median). A scan is placed only where ``drift_sigmas``
    standard deviations of it lie within ``drift_rotation_deg`` and, at its centroid, ``drift_translation``
    x the campaign's size (:func:`extent`). A scan at the end of a long open chain (a ring that cannot
    close) has the chain's uncertainties added up; one on loops that close, or near the reference, is
    pinned. Measured (the constants: MergeConfig's notes): the pairs' information alone under-states their
    error; the median chi^2 / 6 of the pairs on loops is 2.5 / 4.0 / 2.9 on the 24-stop turntable's crops
    (no poses / axis / frame starts) and 1.6-3.8 on its whole scans, so each pair's is scaled by at least it."""
    c.loose = {}
    kept = [keys[e] for e in g.kept]
    placed = [k for k in range(c.n) if g.poses[k] is not None]
    if len(placed) < 2:
        return g
    es = [Edge(i, j, c.pairs[i, j].T_i_j) for i, j in kept]
    infos = plane_infos(c, kept)
    chi = disagreement(es, infos, g.poses)
    shown = [x for x in chi if x > 1e-9]
    floor = max(1.0, float(np.median(shown))) if shown else 1.0
    cov = covariances(c.n, es, [L / max(x, floor) for L, x in zip(infos, chi)], g.poses, c.reference)
    rot_tol, move_tol = c.mc.drift_rotation_deg, c.mc.drift_translation * extent(c, g.poses)
    poses = list(g.poses)
    for k in placed:
        if cov[k] is None:
            continue
        rot, move = (c.mc.drift_sigmas * x for x in spread(cov[k], apply(g.poses[k], c.centers[k][None])[0]))
        if rot > rot_tol or move > move_tol:
            poses[k] = None
            c.loose[k] = (f"joined, but too loosely to vouch for its pose: the pairs that join it, each as far off as "
                          f"its loops show, leave it uncertain by {rot:.2g} deg / {move:.3g} ({c.mc.drift_sigmas:g} "
                          f"standard deviations; tolerance {rot_tol:g} deg / {move_tol:.3g})")
    return replace(g, poses=poses)


def extent(c: _Campaign, poses: list) -> float:
    """The campaign's size (units): the diagonal of the box holding the middle 98 % of the placed scans'
    points (a sample of each) under ``poses``; stray points and outliers do not widen it."""
    pts = [apply(P, c.scans[k].points[::max(1, len(c.scans[k].points) // 500)])
           for k, P in enumerate(poses) if P is not None]
    allp = np.concatenate(pts)
    return float(np.linalg.norm(np.percentile(allp, 99, axis=0) - np.percentile(allp, 1, axis=0)))
