"""The stated region: where the user says the true pose lies, in the user's terms (method "global").

A user states a guess (core.guess.Guess): a pose ``T_target_source`` (a 4x4 ``--init``, or two scans'
stored rough poses) and how wrong it may be, a rotation bound in degrees and, optionally, a translation
bound in units. The rotation of a 4x4 acts about the scan frame's origin, which may lie far from the
scans (a sensor's frame, a turntable's axis): a guess wrong by theta there moves the source's centroid
by up to 2 r sin(theta / 2), r the centroid's distance from that origin. So, measured at the centroid,
the region adds that move to the translation bound:

    rotation     the angle between the pose's rotation and the guess's <= the stated bound
    translation  |T c - T_guess c| <= stated (or the default share of the target's size)
                 + 2 r sin(theta / 2),  c the source centroid, r = max(|c|, |T_guess c|)
                 (about the source frame's origin, or the target's: whichever moves it more)
                 free (any) from FREE_FROM_DEG up when no translation is stated
    no guess     rotation 180 deg and no translation stated: any pose (core.guess.Guess.none)

Every stage, candidate, result and the page ask this one object whether a pose is inside and how far
beyond it lies. The paper's methods (hybrid, icp, sa, ...) keep their own search region (core.search:
twice the stated uncertainty about the guess, section 2.1); this region is the ``global`` method's.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rows import norms
from .scan import Scan

# From this stated rotation up a translation bound says little (a rotation that large about an origin
# the user did not pick moves the centroid by about the scan's distance from it): free unless stated.
FREE_FROM_DEG = 90.0
# A pose a little beyond the bound is inside: a truth on the boundary (the sweep's starts lie exactly at
# the stated offset) has refined hypotheses up to 1.7 deg and 1.5 mm beyond it (measured on
# bun090->bun000: RANSAC and KISS-Matcher hypotheses refined, against the truth)
SLACK_ROTATION_DEG = 3.0
SLACK_TRANSLATION = 0.03  # share of the target's size


def offsets(Ts: np.ndarray, T_ref: np.ndarray, center: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(P,) rotation angle (radians) and (P,) move of the source point ``center`` (3,) (units) from the
    (4, 4) pose ``T_ref`` to each of the (P, 4, 4) poses ``Ts``."""
    Ts = np.asarray(Ts, dtype=np.float64).reshape(-1, 4, 4)
    moved = Ts[:, :3, :3] @ center + Ts[:, :3, 3] - (T_ref[:3, :3] @ center + T_ref[:3, 3])
    cos = (np.einsum("pij,ij->p", Ts[:, :3, :3], T_ref[:3, :3]) - 1.0) / 2.0  # trace(R G^T)
    return np.arccos(np.clip(cos, -1.0, 1.0)), norms(moved)


@dataclass(frozen=True, eq=False)
class Region:
    """T_guess: (4, 4) T_target_source; rotation: the bound (radians); translation: the bound on the
    centroid's move (units, inf: free); center: (3,) the source centroid (source frame); stated_rotation_deg,
    stated_translation (units or None): what the user said; no_guess: the user stated nothing."""

    T_guess: np.ndarray
    rotation: float
    translation: float
    center: np.ndarray
    slack_rotation: float
    slack_translation: float
    stated_rotation_deg: float
    stated_translation: float | None
    units: str = "units"

    @classmethod
    def of(cls, guess: Guess, source: Scan, target: Scan) -> Region:  # noqa: F821 (core.guess imports this module)
        """The region ``guess`` (a core.guess.Guess) states for this pair (module notes)."""
        T_guess = guess.T_target_source
        theta = np.radians(guess.rotation_deg)
        c = source.centroid
        r = max(float(np.linalg.norm(c)), float(np.linalg.norm(T_guess[:3, :3] @ c + T_guess[:3, 3])))
        if guess.translation is None and guess.rotation_deg >= FREE_FROM_DEG:
            translation = np.inf
        else:
            translation = guess.translation_for(target.size) + 2 * r * np.sin(theta / 2)
        return cls(T_guess, float(theta), float(translation), np.array(c, dtype=np.float64),
                   float(np.radians(SLACK_ROTATION_DEG)), SLACK_TRANSLATION * target.size,
                   float(guess.rotation_deg), guess.translation, target.units)

    @property
    def no_guess(self) -> bool:
        """The user stated no guess: any rotation, any translation."""
        return self.stated_rotation_deg >= 180.0 and self.stated_translation is None

    @property
    def translation_free(self) -> bool:
        return not np.isfinite(self.translation)

    def offsets(self, Ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P,) rotation (radians) and (P,) centroid move (units) of the (P, 4, 4) poses from the guess."""
        return offsets(Ts, self.T_guess, self.center)

    def contains(self, Ts: np.ndarray) -> np.ndarray:
        """(P,) bool: each of the (P, 4, 4) poses lies inside (the bounds plus the slack)."""
        rot, move = self.offsets(Ts)
        return (rot <= self.rotation + self.slack_rotation + 1e-9) & (move <= self.translation + self.slack_translation)

    def inside(self, T: np.ndarray) -> bool:
        return bool(self.contains(np.asarray(T)[None])[0])

    def beyond(self, T: np.ndarray) -> tuple[float, float]:
        """How far pose T (4, 4) lies beyond the bounds: (degrees, units), 0 where within."""
        rot, move = self.offsets(np.asarray(T)[None])
        return (float(np.degrees(max(0.0, rot[0] - self.rotation))),
                float(max(0.0, move[0] - self.translation)) if np.isfinite(self.translation) else 0.0)

    def describe(self) -> str:
        """The region in the user's words, e.g. "15 deg, 0.0229 m at the centroid" or "no guess"."""
        if self.no_guess:
            return "no guess (any rotation, any translation)"
        t = "translation free" if self.translation_free else f"{self.translation:.4g} {self.units} at the centroid"
        return f"{self.stated_rotation_deg:g} deg, {t}"

    def beyond_text(self, T: np.ndarray) -> str:
        """'found 41 deg / 0.12 m beyond the stated uncertainty' ('' when T is inside)."""
        if self.inside(T):
            return ""
        deg, move = self.beyond(T)
        parts = ([f"{deg:.3g} deg"] if deg > 0 else []) + ([f"{move:.3g} {self.units}"] if move > 0 else [])
        return f"found {' / '.join(parts) or 'just'} beyond the stated uncertainty ({self.describe()})"

    def to_json(self) -> dict:
        return {"rotation_deg": self.stated_rotation_deg, "translation": self.stated_translation,
                "translation_at_centroid": self.translation if np.isfinite(self.translation) else None,
                "no_guess": self.no_guess}

