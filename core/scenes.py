"""Write the bundled default scenes (``assets/``) reproducibly from a seed; the lesson's scene and starts."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .io import save_scan
from .scan import Scan
from .simulate import SCENES, make_scene, true_transform
from .transforms import apply, perturb


def write_scenes(out: Path, seed: int = 0) -> list[Path]:
    """Simulate every scene into ``out/NAME/scan1.ply`` (target) and ``scan2.ply`` (source) + sidecars."""
    written = []
    for i, name in enumerate(SCENES):
        folder = Path(out) / name
        folder.mkdir(parents=True, exist_ok=True)
        for k, scan in enumerate(make_scene(name, seed + i), 1):
            path = folder / f"scan{k}.ply"
            save_scan(path, scan)
            written.append(path)
    return written


def scene_paths(assets: Path, name: str) -> tuple[Path, Path]:
    """(source, target) files of a bundled scene."""
    return assets / name / "scan2.ply", assets / name / "scan1.ply"


# ---- the lesson: the paper's Fig. 7 on the ribbed corner -----------------------------------------------------
@dataclass(frozen=True)
class Lesson:
    """The paper's story (Fig. 7, Table 2) on a bundled scene: starts where ICP alone stops in a local minimum,
    annealing alone reaches the truth slowly and the hybrid reaches it in a fraction of annealing's iterations.

    starts: (tx in mm, ry in degrees) each, the truth moved by that shift along the target's x axis and turned by
    that angle about its y axis through the source's centroid (core.transforms.perturb), run k with seed k;
    shown: the start the workbench's Lesson tab opens at; params, spans and steps: the slice of E through the truth
    (on the overlap cut there) that shows the small minima and covers every start (half-widths in mm and degrees,
    grid points a side).
    """

    scene: str = "ribbed"
    # 325 mm along tx and 3-15 deg about ry either way: ICP alone stops 5-10 deg and 50-85 mm off at each, with E
    # 26-53 x the threshold; the hybrid frees every one (docs/benchmarks.md, Lesson; benchmarks/lesson_minima.py)
    starts: tuple[tuple[float, float], ...] = ((325, -15), (325, -12), (325, -9), (325, -6), (325, -3), (325, 3),
                                               (325, 6), (325, 9), (325, 12), (325, 15))
    shown: int = 0
    params: tuple[str, str] = ("tx", "ry")
    # +-400 mm and +-24 deg take in every start (they lie 279-362 mm along tx on this slice, its centre being the
    # overlap's) and ICP's first legs (down to -22 deg); 51 steps show 11 minima on the bundled scans (41: 4)
    spans: tuple[float, float] = (400.0, 24.0)
    steps: int = 51

    def scans(self, assets: Path) -> tuple[Scan, Scan]:
        """(source, target) of the lesson's scene as bundled in ``assets`` (``rangereg scenes``), as the page
        shows them."""
        from .io import load_scan

        source, target = scene_paths(assets, self.scene)
        return load_scan(source), load_scan(target)

    def start(self, source: Scan, target: Scan, k: int) -> np.ndarray:
        """T_target_source of start ``k`` (4, 4)."""
        if not 0 <= k < len(self.starts):
            from .errors import InputError

            raise InputError(f"the lesson has starts 0 to {len(self.starts) - 1}, not {k}")
        T_true = true_transform(source, target)
        tx, ry = self.starts[k]
        c = apply(T_true, source.centroid[None])[0]
        return perturb(T_true, np.r_[tx, 0.0, 0.0, 0.0, np.radians(ry), 0.0], c)


LESSON = Lesson()
