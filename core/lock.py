"""Locked degrees of freedom: search only some of the six pose parameters, or a turntable's one angle.

A :class:`Lock` says what may move; bound to a reference pose (:meth:`Lock.bind`) it becomes a
:class:`LockFrame`, the coordinates every optimiser then works in:

    subset     any of tx, ty, tz, rx, ry, rz locked, in the search's own coordinates
               (:meth:`core.problem.Problem.pose`): about the moving scan's overlap centroid,
               translations in units of the problem's ``scale``, rotations in radians.
    turntable  rotation about ONE axis, a line (point, direction) in the target's frame; the
               translation locked too (1 free angle) or free (the angle and tx, ty, tz).

A pose of the frame is ``perturb(T_ref, (scale * t, w), pivot)``: rotate by the rotation vector w
about ``pivot`` (target frame), then translate by ``scale * t``. The six coordinates (t, w) are
built from the k free ones z by placing them into a vector of exact zeros (subset) or as w = angle
* direction (turntable), so locked values are the reference's, bit for bit, in every pose the
search visits. Locking is not zeros in a 6-D simplex: a flat direction breaks annealing's
convergence test and its start temperature, so annealing gets a k-D simplex over z.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InputError
from .scan import check_coordinates
from .transforms import PARAM_NAMES, apply, delta_between, invert, perturb, rotation_matrix

GROUPS = {"translation": ("tx", "ty", "tz"), "rotation": ("rx", "ry", "rz")}
TURNTABLE = "turntable"


@dataclass(frozen=True)
class Lock:
    """What the search may not move. ``locked``: names among tx ty tz rx ry rz (subset mode); or a
    turntable: ``axis_point`` (3,) and ``axis_direction`` (3,) in the target's frame (units), with
    ``translation`` True when tx, ty, tz stay free besides the angle. The default locks nothing."""

    locked: tuple[str, ...] = ()
    axis_point: tuple[float, ...] | None = None
    axis_direction: tuple[float, ...] | None = None
    translation: bool = False

    @property
    def turntable(self) -> bool:
        return self.axis_point is not None or self.axis_direction is not None

    @property
    def active(self) -> bool:
        """Whether anything is locked (if not, every optimiser runs exactly as without a lock)."""
        return self.turntable or bool(self.locked)

    @property
    def free(self) -> tuple[str, ...]:
        """The names of the free coordinates z, in order."""
        if self.turntable:
            return ("angle", "tx", "ty", "tz") if self.translation else ("angle",)
        return tuple(n for n in PARAM_NAMES if n not in self.locked)

    def validate(self) -> None:
        if not isinstance(self.locked, tuple):
            raise InputError(f"locked must be a tuple of names such as ('rx', 'ry'), got {self.locked!r}")
        if self.turntable:
            if self.locked:
                raise InputError("a lock is either a turntable axis or a set of locked parameters, not both")
            for what, v in (("point", self.axis_point), ("direction", self.axis_direction)):
                if v is None or len(v) != 3 or not np.all(np.isfinite(np.asarray(v, dtype=float))):
                    raise InputError(f"the turntable axis needs a {what} of 3 finite numbers, got {v}")
            if not np.abs(np.asarray(self.axis_direction, dtype=float)).max() > 0:
                raise InputError("the turntable axis direction must not be zero")
            beyond = check_coordinates(self.axis_point)
            if beyond:
                raise InputError(f"the turntable axis point: {beyond}")
            return
        unknown = [n for n in self.locked if n not in PARAM_NAMES]
        if unknown:
            raise InputError(f"cannot lock {', '.join(unknown)}: the parameters are {', '.join(PARAM_NAMES)}")
        if len(set(self.locked)) != len(self.locked):
            raise InputError(f"a parameter is locked twice: {','.join(self.locked)}")
        if len(self.locked) == 6:
            raise InputError("all six parameters are locked: nothing is left to search")
        if self.translation:
            raise InputError("translation=True only applies to a turntable lock")

    @classmethod
    def parse(cls, text: str | None) -> Lock:
        """A lock from text: ``rx,ry,tz`` (the locked parameters; ``rotation`` and ``translation``
        name three at once), ``turntable:px,py,pz,dx,dy,dz`` (rotation about that line in the
        target's frame only), ``turntable+translation:...`` (and free translation), or ``none``."""
        s = (text or "").strip().lower().replace(" ", "")
        if s in ("", "none"):
            return cls()
        if s.startswith(TURNTABLE):
            head, _, numbers = s.partition(":")
            if head not in (TURNTABLE, TURNTABLE + "+translation"):
                raise InputError(f"lock {text!r}: write turntable:px,py,pz,dx,dy,dz or turntable+translation:...")
            try:
                v = [float(a) for a in numbers.split(",")]
            except ValueError:
                v = []
            if len(v) != 6:
                raise InputError(f"lock {text!r}: a turntable axis is 6 numbers px,py,pz,dx,dy,dz (a point and a direction)")
            lock = cls(axis_point=tuple(v[:3]), axis_direction=tuple(v[3:]), translation=head != TURNTABLE)
        else:
            names: list[str] = []
            for part in s.split(","):
                names.extend(GROUPS.get(part, (part,)))
            cls(locked=tuple(names)).validate()  # unknown or repeated names
            lock = cls(locked=tuple(n for n in PARAM_NAMES if n in names))
        lock.validate()
        return lock

    def __str__(self) -> str:
        if self.turntable:
            head = TURNTABLE + ("+translation" if self.translation else "")
            return f"{head}:{','.join(repr(float(v)) for v in (*self.axis_point, *self.axis_direction))}"
        return ",".join(self.locked) or "none"

    def bind(self, T_ref: np.ndarray, center: np.ndarray, scale: float) -> LockFrame:
        """The lock's coordinates around ``T_ref`` (4, 4) T_target_source; ``center`` (3,): the
        source's overlap centroid (source frame, the subset mode's pivot); ``scale``: units per
        search unit of translation (``Problem.scale``)."""
        self.validate()
        if not (np.isfinite(scale) and scale > 0):
            raise InputError(f"a lock's translation scale must be > 0, got {scale}")
        return LockFrame(self, np.asarray(T_ref, dtype=np.float64), np.asarray(center, dtype=np.float64), float(scale))

    def project(self, T: np.ndarray, T_ref: np.ndarray, center: np.ndarray, scale: float = 1.0) -> np.ndarray:
        """The pose (4, 4) of the allowed set around ``T_ref`` nearest to T in the lock's own
        coordinates (see :meth:`LockFrame.free`). For candidates, hops and pair alignment."""
        if not self.active:
            return np.asarray(T, dtype=np.float64)
        frame = self.bind(T_ref, center, scale)
        return frame.pose(frame.free(T))


class LockFrame:
    """A lock bound to a reference pose: z (k,) free coordinates <-> poses (4, 4) on the allowed set.

    Every pose made by :meth:`pose` is remembered with its z, so that :meth:`coords_of` reports
    the exact coordinates a visited pose was made from (the trace's locked values, bit for bit).
    """

    def __init__(self, lock: Lock, T_ref: np.ndarray, center: np.ndarray, scale: float):
        self.lock, self.T_ref, self.scale = lock, T_ref, scale
        if lock.turntable:
            self.pivot = np.asarray(lock.axis_point, dtype=np.float64)
            d = np.asarray(lock.axis_direction, dtype=np.float64)
            d = d / np.abs(d).max()  # first: the norm of (1e300, 0, 0) or (1e-300, 0, 0) is inf or 0
            self.axis = d / np.linalg.norm(d)
            free = [3, 0, 1, 2] if lock.translation else [3]
            A = np.zeros((3, len(free)))
            A[:, 0] = self.axis
        else:
            self.pivot = apply(T_ref, center[None])[0]
            self.axis = None
            free = [PARAM_NAMES.index(n) for n in lock.free]
            A = np.eye(6)[3:, free]
        self.free_index = np.array(free, dtype=int)
        self.k = len(free)
        self.A = A  # (3, k): d(rotation vector)/dz
        self.B = np.eye(6)[:3, free]  # (3, k): d(translation)/dz (the turntable's angle: 0)
        self._made: dict[bytes, np.ndarray] = {}
        self.pose(np.zeros(self.k))  # T_ref itself, bit for bit: its z is exactly 0

    def full(self, z: np.ndarray) -> np.ndarray:
        """The six coordinates (t (3) in search units, rotation vector (3)) of z (k,)."""
        z = np.asarray(z, dtype=np.float64)
        x = np.zeros(6)
        if self.axis is None:
            x[self.free_index] = z
        else:
            x[3:] = z[0] * self.axis
            if self.lock.translation:
                x[:3] = z[1:4]
        return x

    def delta(self, z: np.ndarray) -> np.ndarray:
        """(4, 4) the motion D with pose(z) = D @ T_ref."""
        x = self.full(z)
        return perturb(np.eye(4), np.r_[x[:3] * self.scale, x[3:]], self.pivot)

    def pose(self, z: np.ndarray) -> np.ndarray:
        """(4, 4) T_target_source at free coordinates z (k,)."""
        z = np.array(z, dtype=np.float64)
        x = self.full(z)
        T = perturb(self.T_ref, np.r_[x[:3] * self.scale, x[3:]], self.pivot)
        self._made[T.tobytes()] = z
        return T

    def free(self, T: np.ndarray) -> np.ndarray:
        """z (k,) of pose T: exactly the z it was made from, if :meth:`pose` made it; otherwise T
        projected onto the allowed set (subset: its search coordinates with the locked ones dropped;
        turntable: the twist of its rotation about the axis, and where it moves the axis point)."""
        z = self._made.get(np.asarray(T, dtype=np.float64).tobytes())
        if z is not None:
            return z.copy()
        if self.axis is None:
            d = delta_between(T, self.T_ref, self.pivot)
            return np.r_[d[:3] / self.scale, d[3:]][self.free_index]
        D = T @ invert(self.T_ref)
        qx, qy, qz, qw = Rotation.from_matrix(D[:3, :3]).as_quat()
        angle = 2.0 * np.arctan2(np.array([qx, qy, qz]) @ self.axis, qw)  # swing-twist: the twist about the axis
        angle = (angle + np.pi) % (2 * np.pi) - np.pi
        if not self.lock.translation:
            return np.array([angle])
        return np.r_[angle, (apply(D, self.pivot[None])[0] - self.pivot) / self.scale]

    def coords_of(self, T: np.ndarray) -> np.ndarray:
        """The six coordinates of pose T (exact for a pose :meth:`pose` made)."""
        return self.full(self.free(T))

    def steps(self, translation: float, rotation: float) -> np.ndarray:
        """(k,) a first simplex / step size per free coordinate: ``translation`` in search units,
        ``rotation`` in radians."""
        return np.array([rotation if self.A[:, j].any() else translation for j in range(self.k)])

    def random_step(self, rng: np.random.Generator, translation: float, rotation: float) -> np.ndarray:
        """(k,) a random step of z: a uniform direction in the free translations of length up to
        ``translation`` and one in the free rotations of up to ``rotation`` (as ``random_step``)."""
        rot = np.array([self.A[:, j].any() for j in range(self.k)])
        dz = np.zeros(self.k)
        for mask, size in ((~rot, translation), (rot, rotation)):
            n = int(mask.sum())
            if n:
                u = rng.normal(size=n)
                dz[mask] = u / np.linalg.norm(u) * rng.uniform(0, size)
        return dz

    def motion(self, z: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Points y (N, 3) at T_ref moved to z: (m (N, 3), dm/dz (N, 3, k))."""
        x = self.full(z)
        R = rotation_matrix(x[3:])
        v = (y - self.pivot) @ R.T
        m = v + self.pivot + self.scale * x[:3]
        # d(R(w) u)/dw = -[R(w) u]x J_l(w), J_l the left Jacobian of SO(3)
        J = -_skew(v) @ (_left_jacobian(x[3:]) @ self.A) + self.scale * self.B
        return m, J


def _skew(v: np.ndarray) -> np.ndarray:
    """(N, 3) -> (N, 3, 3) cross-product matrices."""
    S = np.zeros((len(v), 3, 3))
    S[:, 0, 1], S[:, 0, 2], S[:, 1, 2] = -v[:, 2], v[:, 1], -v[:, 0]
    S[:, 1, 0], S[:, 2, 0], S[:, 2, 1] = v[:, 2], -v[:, 1], v[:, 0]
    return S


def _left_jacobian(w: np.ndarray) -> np.ndarray:
    theta = float(np.linalg.norm(w))
    K = _skew(w[None])[0]
    if theta < 1e-8:
        return np.eye(3) + 0.5 * K
    return (np.eye(3) + (1 - np.cos(theta)) / theta**2 * K + (theta - np.sin(theta)) / theta**3 * (K @ K))
