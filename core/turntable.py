"""A simulated scanning campaign: the range sensor of :mod:`core.simulate` round an object on a turntable.

The object is closed and asymmetric (a lumpy ellipsoid whose lumps come from the seed), so every
turntable angle sees a different surface and no rotation about the axis maps it onto itself. The
turntable axis is the world z axis through the object's centre; scan k is taken after the table
turned by ``360 k / n`` degrees, from a sensor whose elevation is jittered about its nominal value.
Points are in the sensor frame, millimetres; the truth is ``T_world_sensor`` per scan.

Initial poses, as a user of a real turntable would have them:

- ``perturbed``: each scan at its nominal angle and nominal elevation, then moved by an independent
  seeded perturbation (errors do not add up);
- ``chain``: the nominal step from the previous scan's initial pose, each step perturbed (odometry:
  consecutive scans are close, but the errors add up round the table).

And the families of :func:`rough_poses`, each from the truth (``FAMILIES``): ``frame``, each true pose
turned by an offset about its scan frame's origin (the sensor, where a 4x4 pose's rotation acts) on a
seeded random axis, plus a seeded shift; ``axis``, turned about the turntable's axis through the
object by the offset either way, plus the shift; ``identity``, every pose the identity (no poses).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from .errors import InputError
from .simulate import Scanner, look_at, scan_mesh
from .transforms import apply, from_params, invert


@dataclass(frozen=True)
class TurntableConfig:
    """scans: number of turntable stops; distance: sensor to axis (mm); elevation_deg: nominal sensor
    elevation above the object's centre; elevation_jitter_deg: uniform +- jitter of the true elevation;
    size: the object's largest diameter (mm); perturb_deg / perturb_frac: the initial poses' error,
    a rotation of that many degrees and a translation of that fraction of ``size``."""

    scans: int = 24
    distance: float = 700.0
    elevation_deg: float = 20.0
    elevation_jitter_deg: float = 4.0
    size: float = 240.0
    lumps: int = 30
    scanner: Scanner = Scanner(rows=64, cols=64, fov_deg=(24.0, 24.0), noise=0.3, outliers=0.02, jitter=0.35)
    perturb_deg: float = 3.0
    perturb_frac: float = 0.02

    def validate(self) -> None:
        if not 3 <= self.scans <= 720:
            raise InputError(f"a turntable campaign needs 3 to 720 scans, got {self.scans}")
        if not self.distance > self.size:
            raise InputError(f"the sensor must stand outside the object: distance {self.distance} <= size {self.size}")
        if not -80 <= self.elevation_deg <= 80 or not 0 <= self.elevation_jitter_deg <= 30:
            raise InputError("elevation must be within +-80 degrees and its jitter within 0-30 degrees")
        if self.perturb_deg < 0 or self.perturb_frac < 0:
            raise InputError("the initial poses' perturbation must be >= 0")


@dataclass(frozen=True, eq=False)
class Campaign:
    """scans: with ``pose`` = true T_world_sensor; perturbed / chain: initial T_world_sensor per scan."""

    scans: list
    perturbed: list
    chain: list
    vertices: np.ndarray  # (V, 3) mm, the object
    faces: np.ndarray  # (F, 3)
    config: TurntableConfig
    seed: int

    @property
    def size(self) -> float:
        """The object's bounding-box diagonal (mm): the scene size accuracy targets refer to."""
        return float(np.linalg.norm(self.vertices.max(0) - self.vertices.min(0)))

    def __repr__(self) -> str:
        pts = [len(s.points) for s in self.scans]
        return (f"Campaign({len(self.scans)} scans, seed {self.seed}, object {self.size:.0f} mm, "
                f"{min(pts)}-{max(pts)} points per scan)")


def lumpy_object(rng: np.random.Generator, size: float = 240.0, lumps: int = 30) -> tuple[np.ndarray, np.ndarray]:
    """A closed, asymmetric triangle mesh ((V, 3) mm, (F, 3)): an ellipsoid with seeded lumps and dents."""
    import trimesh

    sphere = trimesh.creation.icosphere(subdivisions=5)
    u = np.asarray(sphere.vertices, dtype=np.float64)
    r = np.ones(len(u))
    centres = rng.normal(size=(lumps, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    heights = rng.uniform(0.08, 0.25, lumps) * rng.choice([-1.0, 1.0], lumps, p=[0.3, 0.7])
    widths = rng.uniform(0.12, 0.35, lumps)
    for c, h, w in zip(centres, heights, widths):
        r += h * np.exp(-np.sum((u - c) ** 2, axis=1) / (2 * w * w))
    axes = np.array([1.0, 0.75, 0.9]) * rng.uniform(0.9, 1.1, 3)
    verts = u * r[:, None] * axes
    verts -= verts.mean(0)
    verts *= size / np.ptp(verts, axis=0).max()
    return verts, np.asarray(sphere.faces, dtype=np.int64)


def _sensor_pose(cfg: TurntableConfig, angle_deg: float, elevation_deg: float) -> np.ndarray:
    """T_world_sensor of the sensor when the table has turned by ``angle_deg`` (sensor frame of look_at)."""
    e = np.radians(elevation_deg)
    eye = cfg.distance * np.array([np.cos(e), 0.0, np.sin(e)])
    T0 = look_at(eye, np.zeros(3))
    # The table turning by +a moves the object; in the object's (world) frame the sensor turns by -a.
    return from_params(np.r_[0, 0, 0, 0, 0, -np.radians(angle_deg)]) @ T0


def _perturbation(rng: np.random.Generator, deg: float, dist: float, centre: np.ndarray) -> np.ndarray:
    """A seeded rigid motion: rotation of ``deg`` about a random axis through ``centre`` (world), then a
    translation of length ``dist``."""
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    move = rng.normal(size=3)
    move *= dist / np.linalg.norm(move)
    R = from_params(np.r_[0, 0, 0, axis * np.radians(deg)])
    about = from_params(np.r_[centre, 0, 0, 0]) @ R @ from_params(np.r_[-centre, 0, 0, 0])
    return from_params(np.r_[move, 0, 0, 0]) @ about


def make_campaign(seed: int = 0, config: TurntableConfig | None = None) -> Campaign:
    """Simulate the campaign: object, scans with their true poses, and the two sets of initial poses."""
    cfg = config or TurntableConfig()
    cfg.validate()
    ss = np.random.SeedSequence(seed)
    rng_obj, rng_scan, rng_init, rng_chain = (np.random.default_rng(s) for s in ss.spawn(4))
    verts, faces = lumpy_object(rng_obj, cfg.size, cfg.lumps)
    step = 360.0 / cfg.scans
    scans, nominal = [], []
    for k in range(cfg.scans):
        elev = cfg.elevation_deg + rng_scan.uniform(-cfg.elevation_jitter_deg, cfg.elevation_jitter_deg)
        T = _sensor_pose(cfg, k * step, elev)
        scans.append(scan_mesh(verts, faces, T, cfg.scanner, rng_scan, name=f"scan{k:02d}"))
        nominal.append(_sensor_pose(cfg, k * step, cfg.elevation_deg))
    centre = np.zeros(3)
    dist = cfg.perturb_frac * cfg.size
    perturbed = [_perturbation(rng_init, cfg.perturb_deg, dist, centre) @ T for T in nominal]
    chain = [perturbed[0]]
    for k in range(1, cfg.scans):
        step_k = invert(nominal[k - 1]) @ nominal[k]  # T_prev_k, the nominal motion between stops
        chain.append(chain[-1] @ step_k @ _perturbation(rng_chain, cfg.perturb_deg / 2, dist / 2,
                                                        apply(invert(nominal[k]), centre[None])[0]))
    return Campaign(scans, perturbed, chain, verts, faces, cfg, seed)


FAMILIES = ("frame", "axis", "identity")


def rough_poses(truth: list[np.ndarray], family: str, offset_deg: float, shift: float, seed: int,
                center: np.ndarray | None = None, axis: np.ndarray | None = None) -> list[np.ndarray]:
    """Rough T_world_scan per true pose (FAMILIES, module notes): ``offset_deg`` degrees and a shift of
    length ``shift`` (units), one generator per scan (``[seed, k]``); ``center`` and ``axis``: the
    turntable's axis (default the world z axis through the origin)."""
    if family not in FAMILIES:
        raise InputError(f"family must be one of {', '.join(FAMILIES)}, got {family!r}")
    if family == "identity":
        return [np.eye(4) for _ in truth]
    center = np.zeros(3) if center is None else np.asarray(center, dtype=np.float64)
    axis = np.array([0.0, 0.0, 1.0]) if axis is None else np.asarray(axis, dtype=np.float64) / np.linalg.norm(axis)
    out = []
    for k, T in enumerate(truth):
        rng = np.random.default_rng([seed, k])
        if family == "frame":
            turn = rng.normal(size=3)
            R = from_params(np.r_[0, 0, 0, turn / np.linalg.norm(turn) * np.radians(offset_deg)])
            rough = T @ R  # about the scan frame's origin
        else:
            R = from_params(np.r_[0, 0, 0, axis * np.radians(offset_deg) * rng.choice([-1.0, 1.0])])
            rough = from_params(np.r_[center, 0, 0, 0]) @ R @ from_params(np.r_[-center, 0, 0, 0]) @ T
        move = rng.normal(size=3)
        rough = rough.copy()
        rough[:3, 3] += move / np.linalg.norm(move) * shift
        out.append(rough)
    return out


def conf_line(name: str, T_world_scan: np.ndarray) -> str:
    """A Stanford ``bmesh`` line for ``T_world_scan``, in the convention :func:`core.io.load_conf` reads
    (``x_world = R(q*) x_scan + t``: the stored quaternion is the conjugate of the rotation's)."""
    x, y, z, w = Rotation.from_matrix(T_world_scan[:3, :3]).as_quat()
    t = T_world_scan[:3, 3]
    return f"bmesh {name} {t[0]:.9g} {t[1]:.9g} {t[2]:.9g} {-x:.12g} {-y:.12g} {-z:.12g} {w:.12g}"


def write_conf(path: Path, names: list[str], poses: list[np.ndarray]) -> None:
    lines = ["camera 0 0 1500 0 0 0 1"] + [conf_line(n, T) for n, T in zip(names, poses)]
    Path(path).write_text("\n".join(lines) + "\n")


def write_campaign(out: str | Path, seed: int = 0, config: TurntableConfig | None = None) -> Campaign:
    """Write the campaign into folder ``out``: ``scanNN.ply`` (Stanford range-grid PLY) with a JSON sidecar
    (viewpoint, units), the truth as ``campaign.conf`` beside them, and the initial poses as
    ``init/perturbed.conf`` and ``init/chain.conf`` (in a subfolder, so that they are never taken
    for the truth beside the scans)."""
    from .io import save_scan

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: is a file, not a folder")
    camp = make_campaign(seed, config)
    (out / "init").mkdir(parents=True, exist_ok=True)
    names = [f"{s.name}.ply" for s in camp.scans]
    for s, name in zip(camp.scans, names):
        save_scan(out / name, replace(s, pose=None, guess=None))  # the truth lives in campaign.conf
    write_conf(out / "campaign.conf", names, [s.pose for s in camp.scans])
    write_conf(out / "init" / "perturbed.conf", names, camp.perturbed)
    write_conf(out / "init" / "chain.conf", names, camp.chain)
    return camp


def shared_axis(rotations: list[np.ndarray], min_turn_deg: float = 10.0,
                tolerance_deg: float = 20.0) -> np.ndarray | None:
    """The unit axis (in the rotations' frame) about which the relative rotations ``R_k R_0^T`` of a
    group of scans all turn, as a turntable's do; None when they do not share one, or turn by less than
    ``min_turn_deg`` (too little to tell). ``tolerance_deg``: how far a turn's axis may lean off the
    shared one (the simulated turntable's sensor elevation jitters by +-4 deg, which leans the relative
    rotation of two stops 24 deg apart by up to ~18 deg)."""
    if len(rotations) < 2:
        return None
    vecs = np.array([Rotation.from_matrix(R @ rotations[0].T).as_rotvec() for R in rotations[1:]])
    turn = np.degrees(np.linalg.norm(vecs, axis=1))
    big = vecs[turn >= min_turn_deg]
    if len(big) == 0:
        return None
    w, v = np.linalg.eigh(big.T @ big)
    axis = v[:, -1]
    lean = np.degrees(np.arccos(np.clip(np.abs(big @ axis) / np.linalg.norm(big, axis=1), 0.0, 1.0)))
    return axis if bool(np.all(lean <= tolerance_deg)) else None


def arc_ends(rotations: list[np.ndarray]) -> tuple[int, int] | None:
    """The indices of the two scans at the ends of the arc a group of turntable scans covers (either side
    of the largest gap between their angles about the shared axis): where a group missing its
    neighbours meets the rest of the ring. One scan: itself twice; None when they share no axis."""
    if len(rotations) == 1:
        return 0, 0
    axis = shared_axis(rotations)
    if axis is None:
        return None
    angle = np.array([0.0] + [float(Rotation.from_matrix(R @ rotations[0].T).as_rotvec() @ axis)
                              for R in rotations[1:]])
    angle = np.degrees(angle) % 360.0
    order = np.argsort(angle, kind="stable")
    ring = angle[order]
    gaps = np.diff(np.r_[ring, ring[0] + 360.0])
    g = int(np.argmax(gaps))
    return int(order[g]), int(order[(g + 1) % len(order)])
