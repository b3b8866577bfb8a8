"""Write the bundled default scenes (``assets/``) reproducibly from a seed."""

from __future__ import annotations

from pathlib import Path

from .io import save_scan
from .simulate import SCENES, make_scene


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
