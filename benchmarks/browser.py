"""Headless Chromium on the workbench, shared by the page benchmarks and scripts/screenshots.py.

Debian's /usr/bin/chromium driven by Playwright, software WebGL (no browser is downloaded).
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from rangereg.app.access import free_port

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking",
         "--disable-component-update", "--disable-sync"]
CHROMIUM = "/usr/bin/chromium"


def launch(playwright):
    """Chromium with FLAGS, from a ``sync_playwright()`` context."""
    return playwright.chromium.launch(executable_path=CHROMIUM, args=FLAGS)


@contextmanager
def served_page(viewport: tuple[int, int], source: str | None = None, target: str | None = None,
                ) -> Iterator[tuple[object, object, object]]:
    """(workbench, browser, page): a workbench in this process on a free port (``source`` -> ``target``
    files, else its bundled scene), opened in Chromium at ``viewport`` (width, height) pixels, once the
    page shows the initial E. The tabs and the server are closed afterwards."""
    from playwright.sync_api import sync_playwright
    from rangereg.app.workbench import ServeOptions, Workbench

    port = free_port()
    wb = Workbench(ServeOptions(source=source, target=target, port=port))
    try:
        with sync_playwright() as p:
            browser = launch(p)
            page = browser.new_page(viewport={"width": viewport[0], "height": viewport[1]})
            page.goto(f"http://127.0.0.1:{port}")
            page.get_by_text("Initial E =").wait_for(timeout=120_000)
            yield wb, browser, page
            browser.close()
    finally:
        for tab in list(wb.tabs.values()):
            tab.close()
        wb.server.stop()


@contextmanager
def bunny_page(folder: Path, viewport: tuple[int, int], pair: tuple[str, str] = ("bun045.ply", "bun000.ply"),
               ) -> Iterator[tuple[object, object, object]]:
    """:func:`served_page` on ``pair`` (source, target files; bun045 -> bun000) of ``folder``."""
    with served_page(viewport, str(folder / pair[0]), str(folder / pair[1])) as opened:
        yield opened
