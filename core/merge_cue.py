"""Which scans are likely neighbours when nothing is known of their poses (core.merge, no guess): the
share of mutually nearest FPFH features of two scans. On the 15-stop turntable (seed 0) each scan's best
2 by it are within 2 stops for 28 of 30.

The share costs two nearest-neighbour searches a pair; among many scans it is measured for each scan's
``SHORTLIST`` nearest by a summary of its features (their mean histogram), so the cue's cost grows with
the scans, not with the pairs of them."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy.spatial import cKDTree

from .posegraph import components

# a scan's partners scored by the share: every other scan up to this many, else its nearest this many by the
# features' mean histogram (so campaigns of up to 25 scans score every pair)
SHORTLIST = 24


class NeighbourCue:
    """Scores pairs of ``n`` scans by their features, made by ``features()`` (a list of (M, 33) arrays)
    when first asked; each pair's score is kept."""

    def __init__(self, n: int, features: Callable[[], list[np.ndarray]]):
        self.n, self._make = n, features
        self._features: list[np.ndarray] | None = None
        self._trees: list[cKDTree] = []
        self._scores: dict[tuple[int, int], float] = {}
        self._summary: np.ndarray | None = None

    def score(self, i: int, j: int) -> float:
        """The share of mutually nearest features of scans i and j, in [0, 1] (higher: likelier neighbours)."""
        if self._features is None:
            self._features = self._make()
            self._trees = [cKDTree(f) for f in self._features]
        key = (min(i, j), max(i, j))
        if key not in self._scores:
            a, b = self._features[key[0]], self._features[key[1]]
            if len(a) == 0 or len(b) == 0:
                self._scores[key] = 0.0
            else:
                ab = self._trees[key[1]].query(a)[1]
                ba = self._trees[key[0]].query(b)[1]
                self._scores[key] = float((ba[ab] == np.arange(len(a))).sum() / min(len(a), len(b)))
        return self._scores[key]

    def summary(self) -> np.ndarray:
        """(n, 33) each scan's mean feature histogram, unit length (zeros for a scan with no features)."""
        if self._features is None:
            self.score(0, 1 if self.n > 1 else 0)
        if self._summary is None:
            rows = [f.mean(0) if len(f) else np.zeros(33) for f in self._features]
            m = np.array(rows, dtype=np.float64)
            self._summary = m / np.maximum(np.linalg.norm(m, axis=1, keepdims=True), 1e-12)
        return self._summary

    def shortlist(self, u: int) -> list[int]:
        """The scans whose pairs with scan u the share is measured for (module notes)."""
        if self.n - 1 <= SHORTLIST:
            return [m for m in range(self.n) if m != u]
        d = np.linalg.norm(self.summary() - self.summary()[u], axis=1)
        d[u] = np.inf
        return [int(m) for m in np.argsort(d, kind="stable")[:SHORTLIST]]

    def rank(self, u: int, among: list[int] | None = None) -> list[int]:
        """The other scans (or those of ``among``), likeliest neighbours of scan u first; among many scans,
        only its shortlist is scored, the rest follow by the summary's distance."""
        pool = [m for m in (range(self.n) if among is None else among) if m != u]
        near = set(self.shortlist(u))
        scored = sorted((m for m in pool if m in near), key=lambda m: (-self.score(u, m), m))
        if len(near) >= self.n - 1:
            return scored
        rest = [m for m in pool if m not in near]
        d = np.linalg.norm(self.summary()[rest] - self.summary()[u], axis=1) if rest else np.zeros(0)
        return scored + [rest[k] for k in np.argsort(d, kind="stable")]

    def pairs(self, partners: int) -> list[tuple[int, int]]:
        """Each scan's ``partners`` best partners, joined into one group by the best links between groups
        (among the shortlists' pairs; the nearest summaries where none crosses)."""
        chosen = {(min(u, m), max(u, m)) for u in range(self.n) for m in self.rank(u)[:partners]}
        listed = sorted({(min(u, m), max(u, m)) for u in range(self.n) for m in self.shortlist(u)})
        while True:
            label = components(self.n, list(chosen))
            if len(set(label)) == 1:
                return sorted(chosen)
            links = [(self.score(i, j), i, j) for i, j in listed if label[i] != label[j]]
            if links:
                _, i, j = max(links)
            else:
                S = self.summary()
                _, i, j = min((float(np.linalg.norm(S[i] - S[j])), i, j) for i in range(self.n)
                              for j in range(i + 1, self.n) if label[i] != label[j])
            chosen.add((i, j))
