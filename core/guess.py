"""The initial guess: a pose ``T_target_source`` and how wrong the user says it may be.

    pose         (4, 4) float64 T_target_source (core.transforms), rigid and finite
    rotation     the stated bound in degrees, in (0, 180], about the scan frame's origin (as a 4x4 applies it)
    translation  the stated bound in the target's units, or None: DEFAULT_TRANSLATION_SHARE of the target's size
    no guess     rotation 180 and no translation stated: any pose (``Guess.none()``)

One value gives what each consumer needs of it: the ``global`` method's stated region
(:meth:`Guess.region`, core.region), the search units of the paper's methods (:meth:`Guess.uncertainty`:
section 2.1's initial uncertainty, which sizes annealing's simplex and the frustum's opening), the
uncertainty left once a registration has converged (:meth:`Guess.converged`: the overlap cut again at the
pose found), and a pair's guess from two scans' rough poses (:meth:`Guess.between`: twice the per-scan
uncertainty, as two poses each off by it may be off from each other by their sum).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .region import Region
from .transforms import check_rigid, invert

DEFAULT_ROTATION_DEG = 15.0  # the paper's starts lie within this of the truth (section 3)
# a translation not stated: this share of the target's size (core.scan.Scan.size); the simulated scenes'
# starts (25 mm on objects ~0.2 m across, core.simulate) lie within it
DEFAULT_TRANSLATION_SHARE = 0.15
ANY_ROTATION_DEG = 180.0


def _rotation(value, what: str = "rotation uncertainty") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a number of degrees in (0, 180], got {value!r}") from None
    if not (np.isfinite(v) and 0 < v <= ANY_ROTATION_DEG):
        raise InputError(f"{what} must be in (0, 180] degrees, got {value}")
    return v


def _translation(value, what: str = "translation uncertainty") -> float | None:
    if value is None:
        return None
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what} must be a positive number of units or None, got {value!r}") from None
    if not (np.isfinite(v) and v > 0):
        raise InputError(f"{what} must be positive, got {value}")
    return v


@dataclass(frozen=True, eq=False)
class Guess:
    """T_target_source: (4, 4) float64 pose; rotation_deg: degrees in (0, 180]; translation: units, or None
    (DEFAULT_TRANSLATION_SHARE of the target's size). Validated on construction (InputError)."""

    T_target_source: np.ndarray
    rotation_deg: float = DEFAULT_ROTATION_DEG
    translation: float | None = None

    def __post_init__(self):
        try:
            T = check_rigid(self.T_target_source, "the guess's pose").copy()
        except InputError:
            raise
        except ValueError as exc:
            raise InputError(str(exc)) from None
        T.flags.writeable = False
        object.__setattr__(self, "T_target_source", T)
        object.__setattr__(self, "rotation_deg", _rotation(self.rotation_deg))
        object.__setattr__(self, "translation", _translation(self.translation))

    # ---- making one ----

    @classmethod
    def identity(cls, rotation_deg: float = DEFAULT_ROTATION_DEG, translation: float | None = None) -> Guess:
        """The identity pose (scans already in one frame, or odometry's "no motion") with this uncertainty."""
        return cls(np.eye(4), rotation_deg, translation)

    @classmethod
    def none(cls, T_target_source: np.ndarray | None = None) -> Guess:
        """No guess: any rotation, any translation. The pose only says where the first overlap is cut
        (default the identity)."""
        return cls(np.eye(4) if T_target_source is None else T_target_source, ANY_ROTATION_DEG, None)

    @classmethod
    def of(cls, value) -> Guess:
        """``value`` as a Guess: a Guess as it is, a (4, 4) pose with the default uncertainty, None: the identity."""
        if isinstance(value, Guess):
            return value
        return cls.identity() if value is None else cls(value)

    @classmethod
    def converged(cls, T_target_source: np.ndarray, search, target_size: float) -> Guess:
        """The uncertainty left once a registration has converged at this pose (``search``: a
        core.config.SearchConfig, its ``resegment_*``): the overlap is cut again there with it."""
        return cls(T_target_source, search.resegment_rotation_deg, search.resegment_translation * target_size)

    @staticmethod
    def between(a: Guess, b: Guess) -> Guess:
        """The pair's guess T_a_b from two rough poses ``a``, ``b`` (each T_world_scan) and their per-scan
        uncertainty: the sum of the two (twice the per-scan one when alike), at most any rotation; a
        translation left unstated by either stays unstated (the target's default share, not doubled)."""
        translation = None if a.translation is None or b.translation is None else a.translation + b.translation
        return Guess(invert(a.T_target_source) @ b.T_target_source,
                     min(ANY_ROTATION_DEG, a.rotation_deg + b.rotation_deg), translation)

    def at(self, T_target_source: np.ndarray) -> Guess:
        """The same uncertainty about another pose."""
        return Guess(T_target_source, self.rotation_deg, self.translation)

    def narrowed(self, rotation_deg: float) -> Guess:
        """This guess with its rotation bound at most ``rotation_deg`` (the translation as stated)."""
        return Guess(self.T_target_source, min(self.rotation_deg, rotation_deg), self.translation)

    # ---- what it says ----

    @property
    def T(self) -> np.ndarray:
        """(4, 4) the pose (T_target_source)."""
        return self.T_target_source

    @property
    def is_none(self) -> bool:
        """No guess: any rotation and no translation stated (any pose)."""
        return self.rotation_deg >= ANY_ROTATION_DEG and self.translation is None

    def translation_for(self, target_size: float) -> float:
        """The translation bound in units: as stated, or DEFAULT_TRANSLATION_SHARE of the target's size."""
        return self.translation if self.translation is not None else DEFAULT_TRANSLATION_SHARE * target_size

    def uncertainty(self, target_size: float) -> tuple[float, float]:
        """(rotation in radians, translation in units): the initial uncertainty the paper's methods search
        in (section 2.1; core.problem divides the translation by its scale to make search units)."""
        return np.radians(self.rotation_deg), self.translation_for(target_size)

    def region(self, source, target) -> Region:
        """The ``global`` method's stated region for this pair (core.region.Region)."""
        return Region.of(self, source, target)

    def describe(self, units: str = "units") -> str:
        """In the user's words: "15 deg, translation 15 % of the target's size", "no guess"."""
        if self.is_none:
            return "no guess (any rotation, any translation)"
        t = (f"{self.translation:g} {units}" if self.translation is not None
             else f"{DEFAULT_TRANSLATION_SHARE:.0%} of the target's size")
        return f"{self.rotation_deg:g} deg, translation {t}"

    def __repr__(self) -> str:
        R, t = self.T_target_source[:3, :3], self.T_target_source[:3, 3]
        angle = float(np.degrees(np.arccos(np.clip((np.trace(R) - 1) / 2, -1.0, 1.0))))
        pose = "identity" if np.array_equal(self.T_target_source, np.eye(4)) else \
            f"rotation {angle:.3g} deg, translation [{', '.join(f'{v:.4g}' for v in t)}]"
        return f"Guess({pose}; {self.describe()})"

    def to_json(self) -> dict:
        return {"T_target_source": self.T_target_source.tolist(), "rotation_deg": self.rotation_deg,
                "translation": self.translation, "no_guess": self.is_none}
