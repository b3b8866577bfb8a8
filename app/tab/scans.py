"""The Scans panel: a bundled scene, files under --data-dir, uploads, the sensors' viewpoints, what is shown.

An E57 holds many scans: under --data-dir each of its scans is offered as ``FILE.e57#NAME`` (``#K`` when
the names do not tell them apart); an uploaded E57 of several scans opens its scans #1 onto #0 and
lists them all in "Source in E57" / "Target in E57" to choose another pair."""

from __future__ import annotations

import re
import tempfile
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import viser
from rangereg.app.tab.fields import parse_vector, show_vector
from rangereg.app.tab.scene3d import Visibility
from rangereg.core.e57 import SUFFIX as E57_SUFFIX
from rangereg.core.e57 import list_scans, read_e57_all, selector_for
from rangereg.core.errors import InputError
from rangereg.core.io import load_scan
from rangereg.core.scan import Scan
from rangereg.core.viewpoint import check_viewpoint


@dataclass(eq=False)
class ShowHandles:
    frustums: viser.GuiCheckboxHandle
    overlap: viser.GuiCheckboxHandle
    surfaces: viser.GuiCheckboxHandle
    path: viser.GuiCheckboxHandle


@dataclass(eq=False)
class E57Handles:
    """The scans of the last uploaded E57 (hidden until one of several scans is uploaded)."""

    source: viser.GuiDropdownHandle
    target: viser.GuiDropdownHandle
    open: viser.GuiButtonHandle


@dataclass(eq=False)
class ScansHandles:
    scene: viser.GuiDropdownHandle
    open_scene: viser.GuiButtonHandle
    file_source: viser.GuiDropdownHandle | None  # None: started without --data-dir
    file_target: viser.GuiDropdownHandle | None
    open_files: viser.GuiButtonHandle | None
    upload_source: viser.GuiUploadButtonHandle
    upload_target: viser.GuiUploadButtonHandle
    vp_source: viser.GuiTextHandle  # "x y z" in the scan's own frame and units
    vp_target: viser.GuiTextHandle
    apply_vp: viser.GuiButtonHandle
    show: ShowHandles
    e57: E57Handles

    def held_by_a_run(self) -> list:
        return [b for b in (self.open_scene, self.open_files, self.upload_source, self.upload_target, self.apply_vp,
                            self.e57.open) if b is not None]


def build(gui: viser.GuiApi, wb) -> ScansHandles:
    served = wb.options.source is not None  # files were served: no bundled scene is open
    scene = gui.add_dropdown("Scene", ["-", *wb.scene_names], initial_value="-" if served else wb.options.scene,
                             hint="the bundled scene open ('-': files); choose one and Open scene")
    open_scene = gui.add_button("Open scene")
    files = data_choices(wb.data_dir, wb.data_files())
    file_source = file_target = open_files = None
    if files:
        file_source = gui.add_dropdown("Source file", files, initial_value=files[min(1, len(files) - 1)])
        file_target = gui.add_dropdown("Target file", files, initial_value=files[0])
        open_files = gui.add_button("Open files")
    upload_source = gui.add_upload_button("Upload source", hint=f"up to {wb.upload_cap_mb:g} MB")
    upload_target = gui.add_upload_button("Upload target", hint=f"up to {wb.upload_cap_mb:g} MB")
    e57 = E57Handles(gui.add_dropdown("Source in E57", ["-"], visible=False),
                     gui.add_dropdown("Target in E57", ["-"], visible=False),
                     gui.add_button("Open these scans", visible=False))
    hint = "the sensor's origin: three numbers (x y z) in the scan's frame and units"
    vp_source = gui.add_text("Source viewpoint", "0 0 0", hint=hint)
    vp_target = gui.add_text("Target viewpoint", "0 0 0", hint=hint)
    apply_vp = gui.add_button("Apply viewpoints")
    with gui.add_folder("Show"):
        show = ShowHandles(gui.add_checkbox("Frustums", True), gui.add_checkbox("Overlap points", True),
                           gui.add_checkbox("Surfaces", False), gui.add_checkbox("Path", True))
    return ScansHandles(scene, open_scene, file_source, file_target, open_files, upload_source, upload_target,
                        vp_source, vp_target, apply_vp, show, e57)


def data_choices(folder: Path | None, files: list[str]) -> list[str]:
    """The --data-dir files as the dropdowns offer them: each scan of an E57 as ``FILE#NAME`` (``FILE#K``
    when the name would not pick it alone, core.e57.selector_for); an E57 that cannot be read stays as itself, so
    opening it says why."""
    out = []
    for rel in files:
        if folder is None or Path(rel).suffix.lower() != E57_SUFFIX:
            out.append(rel)
            continue
        try:
            entries = list_scans(folder / rel)
        except InputError:
            out.append(rel)
            continue
        out += [f"{rel}#{selector_for(e, entries)}" for e in entries]
    return out


def choice_labels(scans: list[Scan]) -> list[str]:
    """Dropdown labels of an E57's scans, in the file's order: ``#K NAME (N points)``."""
    return [f"#{k} {s.name} ({len(s.points)} points)" for k, s in enumerate(scans)]


def load_upload(name: str, content: bytes) -> Scan:
    """A scan from an upload's bytes. Only the name's suffix reaches the disk, and no message names a server path."""
    return _uploaded(_read_upload(name, content, load_scan), f"upload:{name}")


def load_upload_all(name: str, content: bytes) -> list[Scan]:
    """Every scan of an uploaded E57, in the file's order (see :func:`load_upload`)."""
    return [_uploaded(s, f"upload:{name}#{k}") for k, s in enumerate(_read_upload(name, content, read_e57_all))]


def _uploaded(scan: Scan, source: str) -> Scan:
    # the upload's temporary file is gone: nothing may later read the scan's records from it (core.e57_write)
    return replace(scan, source=source, e57=None)


def _read_upload(name: str, content: bytes, read):
    stem = re.sub(r"[^A-Za-z0-9_-]", "_", Path(name.replace("\\", "/")).stem).strip("_") or "upload"
    suffix = Path(name).suffix.lower()
    suffix = suffix if re.fullmatch(r"\.[a-z0-9]{1,8}", suffix) else ""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{stem}{suffix}"
        try:
            path.write_bytes(content)
            return read(path)
        except Exception as exc:  # whatever went wrong, the message names the upload, never the server's folder
            text = str(exc).replace(str(path), name).replace(tmp, "")
            if not isinstance(exc, InputError):
                text = f"{name}: could not be read as a scan ({type(exc).__name__}: {text})"
            raise InputError(text) from None


def with_viewpoint(scan: Scan, value) -> Scan:
    """``scan`` seen from ``value`` (3,), checked; the scan itself when unchanged."""
    v = np.asarray(value, dtype=np.float64)
    if np.allclose(v, scan.viewpoint):
        return scan
    moved = scan.with_viewpoint(v)
    check_viewpoint(moved.points, moved.viewpoint, moved.grid, moved.faces, moved.name)
    return moved


class ScansPanel:
    def __init__(self, tab):
        self.tab, self.state, self.wb = tab, tab.state, tab.wb
        self.h = h = build(tab.gui, tab.wb)
        action = tab.action
        h.open_scene.on_click(action(self.open_scene))
        if h.open_files is not None:
            h.open_files.on_click(action(self.open_files))
        h.upload_source.on_upload(action(self.uploaded, "source", event=lambda e: (e.target.value,)))
        h.upload_target.on_upload(action(self.uploaded, "target", event=lambda e: (e.target.value,)))
        h.apply_vp.on_click(action(self.apply_viewpoints))
        h.e57.open.on_click(action(self.open_e57_pair))
        self.e57_scans: list[Scan] = []  # the last uploaded E57's scans (under the tab's lock)
        self.vp_shown: dict[int, tuple[str, np.ndarray]] = {}  # per viewpoint field: (text shown, exact viewpoint)
        for box in (h.show.frustums, h.show.surfaces, h.show.path):
            box.on_update(lambda e: tab.guarded(tab.apply_visibility))
        h.show.overlap.on_update(lambda e: tab.guarded(tab.recolour))

    def visibility(self, model: bool) -> Visibility:
        s = self.h.show
        # the gizmo sits on the source's middle, where point pairs are clicked, and would take those clicks
        gizmo = not (self.state.running or self.tab.run_drawing or self.tab.pairs.picking)
        return Visibility(bool(s.frustums.value), bool(s.overlap.value), bool(s.surfaces.value), bool(s.path.value),
                          model, gizmo)

    def open_scene(self) -> None:
        name = str(self.h.scene.value)
        if name == "-":
            raise InputError("choose a scene to open ('-' stands for the files open)")
        self.tab.load_pair(*self.wb.scene_pair(name), scene=name)

    def name_scene(self, name: str) -> None:
        """The Scene dropdown says which bundled scene is open ("-": files, uploads or a scene it does not offer):
        with the bunny's files opened it still read 'corner', the scene the page opened on."""
        name = name if name in self.h.scene.options else "-"
        if self.h.scene.value != name:
            self.h.scene.value = name

    def open_files(self) -> None:
        self.tab.load_pair(self.wb.load_data_file(self.h.file_source.value),
                           self.wb.load_data_file(self.h.file_target.value))

    def uploaded(self, which: str, upload) -> None:
        if len(upload.content) > self.wb.upload_cap:
            raise InputError(f"{upload.name}: {len(upload.content) / 1e6:.0f} MB is over the upload cap "
                             f"({self.wb.upload_cap_mb:g} MB)")
        if Path(upload.name).suffix.lower() == E57_SUFFIX:
            scans = load_upload_all(upload.name, upload.content)
            if len(scans) > 1:
                self.offer_e57(scans)
                self.tab.load_pair(scans[1], scans[0])
                self.tab.notify("Loaded", f"{upload.name}: {len(scans)} scans, #1 onto #0; choose others under "
                                "'Source in E57' and 'Target in E57'", error=False)
                return
            scan = scans[0]
        else:
            scan = load_upload(upload.name, upload.content)
        st = self.state
        if which == "source":
            self.tab.load_pair(scan, st.target)
        else:
            self.tab.load_pair(st.source, scan)
        estimated = "; no sidecar came with it, so its viewpoint is estimated (Scans: Source/Target viewpoint)" if (
            scan.viewpoint_estimated) else ""
        self.tab.notify("Loaded", f"{upload.name}: {len(scan.points)} points{estimated}", error=False)

    def offer_e57(self, scans: list[Scan]) -> None:
        """List an uploaded E57's scans in the two dropdowns (source #1, target #0) and show them."""
        labels = choice_labels(scans)
        with self.state.lock:
            self.e57_scans = scans
        e = self.h.e57
        e.source.options, e.target.options = labels, labels
        e.source.value, e.target.value = labels[1], labels[0]
        for handle in (e.source, e.target, e.open):
            handle.visible = True

    def open_e57_pair(self) -> None:
        e = self.h.e57
        with self.state.lock:
            scans = self.e57_scans
        labels = choice_labels(scans)
        if e.source.value not in labels or e.target.value not in labels:
            raise InputError("upload an E57 file to choose among its scans")
        source, target = scans[labels.index(e.source.value)], scans[labels.index(e.target.value)]
        if source is target:
            raise InputError(f"choose two different scans (both are {e.source.value})")
        self.tab.load_pair(source, target)

    def apply_viewpoints(self) -> None:
        st = self.state
        st.require_scans()
        self.tab.load_pair(with_viewpoint(st.source, self._viewpoint(self.h.vp_source, "source viewpoint")),
                           with_viewpoint(st.target, self._viewpoint(self.h.vp_target, "target viewpoint")),
                           keep_pose=True, scene=None)

    def _viewpoint(self, field, what: str) -> np.ndarray:
        """A viewpoint field as (3,): the exact viewpoint while it reads as shown, else the numbers typed."""
        shown = self.vp_shown.get(id(field))
        if shown is not None and str(field.value).strip() == shown[0]:
            return shown[1]
        return np.asarray(parse_vector(field.value, what), dtype=np.float64)

    def show_viewpoints(self, source: Scan, target: Scan) -> None:
        """Both viewpoints in 4 significant digits, as every number on the page (the exact ones kept for Apply)."""
        for field, scan in ((self.h.vp_source, source), (self.h.vp_target, target)):
            exact = np.asarray(scan.viewpoint, dtype=np.float64).copy()
            text = show_vector(exact)
            self.vp_shown[id(field)] = (text, exact)
            field.value = text

    def lock(self, running: bool) -> None:
        for b in self.h.held_by_a_run():
            b.disabled = running
