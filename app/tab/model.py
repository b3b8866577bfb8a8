"""The Model panel: fuse the two scans at the current pose into one mesh (core.fuse), or merge a campaign
of the --data-dir's scans (core.merge, as ``rangereg merge`` does: the same progress lines, every round)."""

from __future__ import annotations

import threading
from dataclasses import dataclass

import numpy as np
import viser
from rangereg.app.tab import scene3d
from rangereg.app.tab.residuals import ResidualsPanel
from rangereg.app.tab.state import TabState
from rangereg.core.errors import InputError


@dataclass(eq=False)
class CampaignHandles:
    scans: viser.GuiTextHandle  # a pattern of --data-dir's files (e.g. "bun*.ply"), "" every scan file
    rotation: viser.GuiNumberHandle  # degrees each stored rough pose may be off
    merge: viser.GuiButtonHandle
    progress: viser.GuiMarkdownHandle


@dataclass(eq=False)
class ModelHandles:
    merge: viser.GuiButtonHandle
    show: viser.GuiCheckboxHandle
    campaign: CampaignHandles | None  # None: the workbench has no --data-dir


FUSE_PAIR = "Fuse this pair"  # beside "Merge scans" (rangereg merge: register every scan, then fuse)


class ModelPanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        gui = tab.gui
        self.h = ModelHandles(gui.add_button(FUSE_PAIR, hint="fuse the two scans at the current pose into one mesh"),
                              gui.add_checkbox("Show model", False, disabled=True), self._campaign(gui, tab.wb))
        self.residuals = ResidualsPanel(tab)
        self.h.merge.on_click(tab.action(self.start))
        self.h.show.on_update(lambda e: tab.guarded(tab.apply_visibility))
        if self.h.campaign is not None:
            self.h.campaign.merge.on_click(tab.action(self.start_campaign))

    @staticmethod
    def _campaign(gui: viser.GuiApi, wb) -> CampaignHandles | None:
        if getattr(wb, "data_dir", None) is None:
            return None
        with gui.add_folder("Campaign"):
            # the progress, then the report, first in the folder: at 1280 x 720 the report's headline is in view
            # without scrolling the panel (under the fields and the button it was below the fold)
            progress = gui.add_markdown("")
            return CampaignHandles(
                gui.add_text("Scans", "", hint="a pattern of the data folder's files, e.g. bun*.ply (empty: all)"),
                gui.add_number("Rotation uncertainty (deg)", 15.0, min=0.1, max=180.0, step=0.1,
                               hint="how far each scan's stored rough pose may be off (scans with none: no guess)"),
                gui.add_button("Merge scans", hint="register the scans' pairs, keep those that close, fuse the model"),
                progress)

    def start(self) -> None:
        from rangereg.core.fuse import fuse

        st = self.state
        st.require_scans()
        st.require_idle()
        with st.lock:
            if st.campaign_busy:  # its end sets the model: one merge at a time
                raise InputError("a campaign merge is working: wait for its report")
            source, target, T, surfaces, pair = st.source, st.target, st.T, st.surfaces, st.pair
        self.h.merge.disabled = True

        def work() -> None:
            try:
                model = fuse([target, source], [np.eye(4), T], [surfaces[1], surfaces[0]])
            except Exception as exc:  # said on the page; the tab lives on
                self.tab.notify("Merge failed", str(exc))
                self.state.hand(lambda st: None, lambda: setattr(self.h.merge, "disabled", False))
                return

            def apply(st: TabState) -> None:
                if st.pair == pair:
                    st.model = model

            self.state.hand(apply, lambda: self._show(model))

        threading.Thread(target=work, daemon=True, name="rangereg-merge").start()

    def start_campaign(self) -> None:
        """Merge the chosen data files on a worker thread; its progress lines and report go to the panel."""
        from fnmatch import fnmatch

        from rangereg.app.options import Settings, to_config, to_guess

        c = self.h.campaign
        st = self.state
        st.require_idle()
        pattern = c.scans.value.strip() or "*"
        files = [f for f in self.tab.wb.data_files() if fnmatch(f, pattern)]
        if len(files) < 2:
            raise InputError(f"the pattern {pattern!r} matches {len(files)} scan file(s) of the data folder; "
                             "a campaign needs two or more")
        seed = self.tab.run_panel.settings().seed
        stated = Settings(method="global", seed=seed, rotation_uncertainty=c.rotation.value)
        config, per_scan = to_config(stated), to_guess(stated)
        with st.lock:
            if st.campaign_busy:
                raise InputError("a campaign merge is working: wait for its report")
            st.campaign_busy = True
            pair = st.pair
        c.merge.disabled = self.h.merge.disabled = True
        lines = CampaignLines()

        def say(event) -> None:  # from the worker: the newest lines, shown by the refresher
            lines.add(event)
            text = lines.text()
            self.state.hand(lambda st: None, lambda: setattr(c.progress, "content", text))

        def work() -> None:
            from rangereg.app.distributed import TaskRunner
            from rangereg.core.merge import merge

            try:
                scans = [self.tab.wb.load_data_file(f) for f in files]
                # the plain loop: a cluster started from the page would outlive its work in the server
                with TaskRunner(1, progress=say) as runner:
                    res = merge(scans, None, config, progress=say, map_tasks=runner.map, stated=per_scan)
            except Exception as exc:  # said on the page; the tab lives on
                self.tab.notify("Campaign merge failed", str(exc))
                self.state.hand(_campaign_over, self._unlock)
                return

            def apply(st: TabState) -> None:
                _campaign_over(st)
                if st.pair == pair and st.display is not None:
                    st.model = res.model

            report = lines.report(campaign_text(res))
            self.state.hand(apply, lambda: self._campaign_done(res, report))

        threading.Thread(target=work, daemon=True, name="rangereg-campaign").start()

    def _unlock(self) -> None:
        self.h.merge.disabled = self.state.running
        if self.h.campaign is not None:
            self.h.campaign.merge.disabled = self.state.running

    def _campaign_done(self, res, report: str) -> None:
        self._unlock()
        self.h.campaign.progress.content = report
        if self.state.model is res.model and self.tab.nodes is not None:
            # the campaign's model is in its reference scan's frame and units, not the open pair's: its own place
            self._draw(res.model, own_frame=True)
            self.tab.fit_view()
        placed = sum(res.placed)
        self.tab.notify("Campaign", f"{placed} of {len(res.poses)} scans placed", error=placed < len(res.poses))

    def _show(self, model) -> None:
        self.h.merge.disabled = self.state.running or self.state.campaign_busy
        if self.state.model is not model:
            return
        self._draw(model, own_frame=False)  # the pair fused in the target's frame: drawn where the scans are
        self.tab.notify("Model", f"{len(model.vertices)} vertices, {len(model.faces)} triangles", error=False)

    def _draw(self, model, own_frame: bool) -> None:
        """Draw ``model`` (core.fuse's) and show it; ``own_frame``: a campaign's model (:func:`scene3d.model_on_page`)."""
        vertices = scene3d.model_on_page(model.vertices, None if own_frame else self.state.display)
        with self.tab.client.atomic():
            scene3d.show_model(self.tab.client.scene, self.tab.nodes, vertices, model.faces)
        self.h.show.disabled = False
        self.h.show.value = True
        self.tab.apply_visibility()

    def forget(self) -> None:
        """A new pair: no model yet."""
        self.h.show.value, self.h.show.disabled = False, True

    def lock(self, running: bool) -> None:
        busy = running or self.state.campaign_busy  # a run's end must not free a campaign's buttons
        self.h.merge.disabled = busy
        if self.h.campaign is not None:
            self.h.campaign.merge.disabled = busy


def _campaign_over(st: TabState) -> None:
    """On the refresher, under the lock: the campaign's buttons may be given back."""
    st.campaign_busy = False


class CampaignLines:
    """A campaign's progress as the panel shows it: the overall line (the newest count of the pairs registered, over
    every round) leads and stays first; the newest other lines (the steps' counts and notes) follow it."""

    KEEP = 5  # other lines shown under the overall one

    def __init__(self):
        self.overall: str = ""
        self.others: list[str] = []

    def add(self, event) -> None:
        """One progress event of core.merge (a MergeProgress) or a line of the task runner's (a str)."""
        from rangereg.core.merge_progress import MergeProgress, Step

        if isinstance(event, MergeProgress) and event.step is Step.PAIRS and not event.note:
            self.overall = str(event)
        else:
            self.others.append(str(event))

    def text(self) -> str:
        """The panel's markdown while the campaign works."""
        return "  \n".join(([self.overall] if self.overall else []) + self.others[-self.KEEP:])

    def report(self, result: str) -> str:
        """The panel's markdown at the end: the overall line, then ``result`` (campaign_text: headline, per scan)."""
        return "  \n".join(([self.overall] if self.overall else []) + [result])


def campaign_text(res) -> str:
    """A campaign's result for the panel: the counts, then per scan placed or why not."""
    names = [s.name for s in res.scans]
    lines = [f"**{sum(res.placed)} of {len(names)} scans placed** · {len(res.used)} of {len(res.pairs)} pairs used · "
             f"{res.rounds} round(s) · {res.seconds:.1f} s"]
    for s in res.scans:
        if s.placed:
            cyc = "on no cycle" if s.cycle is None else f"cycle {s.cycle[0]:.2g} deg"
            lines.append(f"{s.name}: placed ({len(s.trusted)} trusted pairs, {cyc})")
        else:
            lines.append(f"{s.name}: **not placed**: {s.why}")
    return "  \n".join(lines)
