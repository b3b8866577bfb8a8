"""Everything a registration run needs, prepared once: surfaces, overlap, sample, error, scaling.

The pose search space of annealing and of error slices is the local step of
:func:`core.transforms.perturb` about the moving scan's overlap centroid, scaled so that one unit
of any coordinate is a comparable motion: translations are divided by ``scale`` (the RMS radius of
the sampled overlap points about their centroid) and rotations are in radians, so a unit rotation
also moves the points by about ``scale``.
"""

from __future__ import annotations

import threading
import weakref
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from .cut import overlap_cut
from .errors import InputError
from .frustum import KINDS, Overlap
from .guess import Guess
from .noise import NORMAL_NEIGHBOURS
from .robust_error import RobustError
from .scan import Scan, ScanKind, scale_mismatch
from .surface import PARALLEL_QUERY, Surface, pca_normals
from .transforms import apply, delta_between, invert, perturb


@dataclass(frozen=True)
class ProblemConfig:
    max_points: int = 300  # source overlap points the error uses (paper: 165-341)
    frustum: str = "convex"  # or "nonconvex"
    visibility: bool = True  # also drop points hidden behind the target's surface (beyond the paper)

    def validate(self) -> None:
        if self.max_points < 3:
            raise InputError(f"max_points must be at least 3, got {self.max_points}")
        if self.frustum not in KINDS:
            raise InputError(f"frustum must be one of {', '.join(KINDS)}, got {self.frustum!r}")


@dataclass(eq=False)
class Problem:
    """source, target: scans; guess: the pose the overlap was cut at and its stated uncertainty; points:
    (M, 3) sampled source overlap (source frame); center: (3,) their centroid (source frame); scale: units
    per search unit; rotation_uncertainty (radians), translation_uncertainty (units): the guess's."""

    source: Scan
    target: Scan
    surface: Surface
    guess: Guess
    overlap: Overlap
    used: np.ndarray  # (Ns,) bool: source points in the error's overlap set (frustum + visibility)
    points: np.ndarray
    center: np.ndarray
    scale: float
    rotation_uncertainty: float  # radians
    translation_uncertainty: float  # units
    cut: str = "frustum"  # which overlap cut the error uses (core.cut.CUTS)
    error: RobustError = field(init=False)

    def __post_init__(self):
        self.error = RobustError(self.points, self.surface)

    @property
    def T_init(self) -> np.ndarray:
        """(4, 4) T_target_source: the guess's pose (where the overlap was cut)."""
        return self.guess.T_target_source

    @property
    def steps(self) -> np.ndarray:
        """(6,) the initial uncertainty in search units (a simplex that covers it)."""
        return np.r_[np.full(3, self.translation_uncertainty / self.scale), np.full(3, self.rotation_uncertainty)]

    def pose(self, T_base: np.ndarray, x: np.ndarray) -> np.ndarray:
        """The pose at search coordinates x (6,) around T_base."""
        x = np.asarray(x, dtype=np.float64)
        return perturb(T_base, np.r_[x[:3] * self.scale, x[3:]], apply(T_base, self.center[None])[0])

    def coords(self, T: np.ndarray, T_base: np.ndarray) -> np.ndarray:
        """Search coordinates (6,) of pose T around T_base (inverse of :meth:`pose`)."""
        d = delta_between(T, T_base, apply(T_base, self.center[None])[0])
        return np.r_[d[:3] / self.scale, d[3:]]


# Fewer points than this in a scan leave its noise level unmeasured (core.noise: the normal floor needs two
# interleaved neighbourhoods of NORMAL_NEIGHBOURS points), and with it the threshold that says "trust".
MIN_POINTS = 2 * NORMAL_NEIGHBOURS


def check_registrable(*scans: Scan) -> None:
    """Raise InputError unless every scan has enough points and is not flat, and all are in one unit
    (each measured against the first)."""
    for s in scans:
        if len(s.points) < MIN_POINTS:
            raise InputError(f"{s.name}: only {len(s.points)} points; registering needs at least {MIN_POINTS} "
                             f"(the noise level is measured on neighbourhoods of 2 x {NORMAL_NEIGHBOURS} points)")
        if s.flatness < 1e-3:
            raise InputError(f"{s.name}: the scan is flat (a plane); a plane cannot fix all six degrees of freedom")
    first = scans[0]
    for other in scans[1:]:
        mismatch = scale_mismatch(other, first)
        if mismatch and not (other.units_stated and first.units_stated
                             and other.units == first.units):
            raise InputError(f"{mismatch}; no rigid pose joins scans in different units: scale one, or state the "
                             "same \"units\" in both sidecars if they are alike")


def prepare(source: Scan, target: Scan, guess: Guess | np.ndarray | None = None,
            config: ProblemConfig = ProblemConfig(), surface: Surface | None = None, seed: int = 0) -> Problem:
    """Triangulate the target, cut the overlap under ``guess`` (a Guess; a (4, 4) T_target_source with the
    default uncertainty; None: the identity) and sample the source points (the sample drawn with ``seed``:
    a registration passes its ``Config.seed``)."""
    config.validate()
    guess = Guess.of(guess)
    check_registrable(source, target)
    surface = surface if surface is not None else Surface.from_scan(target)
    r_unc, t_unc = guess.uncertainty(target.size)
    cut = overlap_cut(source, target, surface, guess.T_target_source, config.frustum, config.visibility, r_unc, t_unc)
    if cut is None:
        raise InputError(f"{source.name} and {target.name} do not overlap under the initial guess, even with "
                         f"its frustum opened by the rotation uncertainty ({guess.rotation_deg:g} deg)")
    return _sampled(source, target, surface, guess, cut.overlap, cut.used, cut.name, config.max_points, seed)


def resample(problem: Problem, max_points: int, seed: int | Sequence[int]) -> Problem:
    """``problem`` with a new sample of at most ``max_points`` source points drawn with ``seed`` from the same
    overlap cut (no cut is made again)."""
    if max_points < 3:
        raise InputError(f"a sample needs at least 3 points, got {max_points}")
    return _sampled(problem.source, problem.target, problem.surface, problem.guess, problem.overlap, problem.used,
                    problem.cut, max_points, seed)


def _sampled(source: Scan, target: Scan, surface: Surface, guess: Guess, overlap: Overlap, used: np.ndarray, cut: str,
             max_points: int, seed: int | Sequence[int]) -> Problem:
    """The Problem of the overlap cut ``used`` with its source sample drawn with ``seed``."""
    idx = np.flatnonzero(used)
    if len(idx) > max_points:
        idx = _sample(source, idx, max_points, np.random.default_rng(seed))
    points = source.points[idx]
    center = points.mean(0)
    scale = float(np.sqrt(np.mean(np.sum((points - center) ** 2, axis=1)))) or 1.0
    r_unc, t_unc = guess.uncertainty(target.size)
    return Problem(source, target, surface, guess, overlap, used, points, center, scale, r_unc, t_unc, cut)


# A scene's sample (a panorama, an unstructured cloud): normal-space sampling (Rusinkiewicz and Levoy, "Efficient
# variants of the ICP algorithm", 2001) over the three axes a normal leans to most, from this many candidates
# per point drawn, their normals fitted to NORMAL_NEIGHBOURS nearest points. A street or a room is mostly floor
# and walls along the motion: a uniform sample of the shared LiDAR frames is ~60 % road (normal ~z), which pins
# no horizontal motion, and point-to-point ICP from the identity then stopped 0.3-0.45 m short along the road
# (7 of 8 seeds x sample sizes); spread over the normals' axes it reached it.
CANDIDATES_PER_POINT = 20
# The candidates' normals are fitted in batches, in the draw's order, the first of FIRST_BATCH per point, each
# next twice the last, until every axis holds a third of the sample: the sample is then the first third of each
# axis in the draw's order, as from the whole draw (the same points when n splits in three, as the defaults' 300,
# 1500 and 6000 do; else which axis takes the remainder may differ). Measured (2026-12-06) on a 15-frame RGB-D
# fragment's legs on the whole scans (6000 points from 120k candidates): the first batch holds every axis's
# third, and the normals cost 0.06 s instead of 0.4 s.
FIRST_BATCH = 3


def _sample(source: Scan, idx: np.ndarray, n: int, rng: np.random.Generator) -> np.ndarray:
    """(n,) sorted indices drawn from ``idx`` (the cut): the paper's uniform draw for a single-view scan; for a
    scene (a panorama, an unstructured cloud) as many from each normal axis as it holds (module notes)."""
    if source.kind is ScanKind.SINGLE_VIEW:
        return np.sort(rng.choice(idx, n, replace=False))
    cand = rng.choice(idx, min(len(idx), CANDIDATES_PER_POINT * n), replace=False)
    axis, fitted, batch = np.empty(len(cand), dtype=np.int64), 0, FIRST_BATCH * n
    while fitted < len(cand):
        part = slice(fitted, min(len(cand), fitted + batch))
        axis[part] = np.argmax(np.abs(_normals_at(source, cand[part])), axis=1)
        fitted, batch = part.stop, 2 * batch
        if np.bincount(axis[:fitted], minlength=3).min() >= -(-n // 3):
            break
    cand, axis = cand[:fitted], axis[:fitted]
    groups = [cand[axis == a] for a in range(3)]
    share = np.zeros(3, dtype=np.int64)
    left = n
    for i, a in enumerate(np.argsort([len(g) for g in groups], kind="stable")):  # the rarest axes first: what
        share[a] = min(len(groups[a]), left // (3 - i))  # they lack goes to the others
        left -= share[a]
    chosen = np.concatenate([g[:m] for g, m in zip(groups, share)])  # cand is a random order already
    return np.sort(chosen)


# A scene's normals at the candidates, each point's fitted once while its scan lives: a registration draws a sample
# at every cut (the setup's, each refinement's, the converged ones, the whole scans' legs, the result's), and the
# draws share most of their points; the whole RGB-D fragments' legs draw 120k candidates a cut. A point's normal
# depends on its own neighbours only, so it is the same bits whichever draw fits it first.
_NORMALS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_NORMALS_LOCK = threading.Lock()


def _normals_at(scan: Scan, at: np.ndarray) -> np.ndarray:
    """(len(at), 3) unit normals (sign arbitrary) of ``scan`` at point indices ``at``, fitted to its
    NORMAL_NEIGHBOURS nearest points (core.surface.pca_normals)."""
    with _NORMALS_LOCK:
        if scan not in _NORMALS:
            _NORMALS[scan] = (np.empty((len(scan.points), 3)), np.zeros(len(scan.points), dtype=bool))
        normals, known = _NORMALS[scan]
    new = np.unique(at[~known[at]])
    if len(new):
        k = min(NORMAL_NEIGHBOURS, len(scan.points))
        nb = scan.tree.query(scan.points[new], k, workers=-1 if len(new) > PARALLEL_QUERY else 1)[1]
        normals[new] = pca_normals(scan.points, nb.reshape(len(new), k))
        known[new] = True  # after the values: a thread that sees it set reads them written
    return normals[at]


def relative_guess(source: Scan, target: Scan) -> np.ndarray:
    """T_target_source from the scans' stored rough poses (``guess``), else the identity."""
    if source.guess is not None and target.guess is not None:
        return invert(target.guess) @ source.guess
    return np.eye(4)
