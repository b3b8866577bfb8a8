"""The page on the shared sensor files: a spinning-LiDAR pair opened from the data folder, both panoramas drawn with
their sensors named, in view after Fit view, and the global run right and trusted from the page; a pair of Kinect
frames (250k points each) drawn by a subset at rest."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.conftest import wait_for
from tests.test_page_scene import in_view, open_tab, serving_folder, settled, show_tab

DATA = Path(__file__).resolve().parents[2] / "shared" / "data"
LIDAR, KINECT = DATA / "lidar", DATA / "kinect"

pytestmark = pytest.mark.browser


def serve(folder: Path, needs: str):
    """A workbench in this process on its bundled scene with --data-dir ``folder`` (skipped without ``needs``)."""
    if not (folder / needs).exists():
        pytest.skip(f"the shared files ({folder}) are absent")
    yield from serving_folder(folder)


@pytest.fixture(scope="module")
def lidar_bench():
    yield from serve(LIDAR, "251370668.pcd")


@pytest.fixture(scope="module")
def kinect_bench():
    yield from serve(KINECT, "capture0001.pcd")


def test_a_lidar_pair_opens_with_its_sensors_in_view_and_registers_trusted(lidar_bench, browser):
    from rangereg.core.scan import ScanKind
    from rangereg.core.transforms import invert, rotation_angle

    page, tab = open_tab(lidar_bench, browser)
    show_tab(page, "Scans")
    page.get_by_role("button", name="Open files", exact=True).click()
    wait_for(lambda: tab.state.source is not None and tab.state.source.kind is ScanKind.PANORAMA
             and tab.nodes is not None and tab.nodes.source.root.startswith(f"/pair{tab.state.pair}"), 120,
             what="the LiDAR pair")
    names = set(tab.client.scene._handle_from_node_name)
    for cloud in (tab.nodes.source, tab.nodes.target):
        assert f"{cloud.root}/viewpoint/axes" in names and f"{cloud.root}/viewpoint/label" in names
    page.get_by_role("button", name="Fit view", exact=True).click()
    settled(page, tab)
    pts = tab.state.display.points(tab.state.target.points[::50])
    wait_for(lambda: in_view(tab, pts)[0] > 0.95, 20, what="the framed pair")
    # the default method from the page's first button, from the identity: right and trusted
    show_tab(page, "Run")
    page.get_by_role("button", name="Run global", exact=True).click()
    wait_for(lambda: tab.state.result is not None and not tab.state.running, 300, what="the global run")
    truth = np.loadtxt(LIDAR / "relative.txt").reshape(4, 4)  # 251371071's points into 251370668's frame
    if tab.state.target.name != "251370668":
        truth = invert(truth)
    T = tab.state.result.T_target_source
    assert np.degrees(rotation_angle(T[:3, :3] @ truth[:3, :3].T)) < 1.0
    assert np.linalg.norm(T[:3, 3] - truth[:3, 3]) < 0.05
    assert tab.state.result.trusted
    page.close()


def test_kinect_frames_open_drawn_by_a_subset_and_in_view(kinect_bench, browser):
    from rangereg.app.tab import scene3d

    page, tab = open_tab(kinect_bench, browser)
    show_tab(page, "Scans")
    page.get_by_role("button", name="Open files", exact=True).click()
    wait_for(lambda: tab.state.source is not None and tab.state.source.name.startswith("capture")
             and tab.nodes is not None and tab.nodes.source.root.startswith(f"/pair{tab.state.pair}"), 120,
             what="the Kinect pair")
    for cloud, scan in ((tab.nodes.source, tab.state.source), (tab.nodes.target, tab.state.target)):
        assert len(scan.points) > scene3d.DRAW_POINTS  # every point is registered; a subset is drawn
        assert len(cloud.points.points) == scene3d.DRAW_POINTS
    page.get_by_role("button", name="Fit view", exact=True).click()
    settled(page, tab)
    pts = tab.state.display.points(tab.state.target.points[::100])
    wait_for(lambda: in_view(tab, pts)[0] > 0.95, 20, what="the framed pair")
    page.close()
