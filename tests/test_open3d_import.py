"""Open3D without its plotly drawing on the engine's path (core.open3d_import): the CLI's register loads neither
plotly, dash nor viser, and whoever draws with Open3D's plotly functions still gets them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _run(code: str) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert out.returncode == 0, out.stderr
    return out.stdout.strip().splitlines()[-1]


def test_register_on_the_command_line_imports_neither_plotly_dash_nor_viser():
    corner = ROOT / "assets" / "corner"
    code = ("import sys, contextlib, io\n"
            "from rangereg.app.cli import main\n"
            "with contextlib.redirect_stdout(io.StringIO()):\n"
            f"    status = main(['register', {str(corner / 'scan2.ply')!r}, {str(corner / 'scan1.ply')!r}, '--json'])\n"
            "print(status, 'open3d' in sys.modules, sorted(m for m in ('plotly', 'dash', 'viser') if m in sys.modules))")
    assert _run(code) == "0 True []"


def test_open3d_s_plotly_functions_load_their_module_when_called():
    code = ("import sys\n"
            "from rangereg.core.open3d_import import defer_plotly\n"
            "defer_plotly()\n"
            "import open3d as o3d\n"
            "before = 'dash' in sys.modules\n"
            "pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector([[0, 0, 0.0], [1, 0, 0], [0, 1, 0]]))\n"
            "fig = o3d.visualization.get_plotly_fig([pc])\n"
            "module = sys.modules['open3d.visualization.draw_plotly']\n"
            "print(before, 'dash' in sys.modules, type(fig).__name__, hasattr(module, 'get_point_object'),\n"
            "      o3d.visualization.get_plotly_fig is module.get_plotly_fig)")
    assert _run(code) == "False True Figure True True"
