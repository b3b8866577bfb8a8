"""The Pose panel: the six parameters of the initial pose, typed or dragged with the gizmo."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import viser
from rangereg.app.figures import axis_label
from rangereg.app.tab import scene3d
from rangereg.app.tab.fields import parse_number, show_number
from rangereg.core.errors import InputError
from rangereg.core.transforms import PARAM_NAMES, from_params, to_params


@dataclass(eq=False)
class PoseHandles:
    params: list[viser.GuiTextHandle]  # tx ty tz in the scans' units, rx ry rz in degrees
    apply: viser.GuiButtonHandle
    reset_file: viser.GuiButtonHandle
    reset_truth: viser.GuiButtonHandle


def label(param: str, units: str = "") -> str:
    """The field's label: rotations in degrees, translations in the scans' own units once known."""
    if param.startswith("r"):
        return f"{param} (deg)"
    return axis_label(param, units) if units else param


def build(gui: viser.GuiApi) -> PoseHandles:
    return PoseHandles(
        params=[gui.add_text(label(n), "0") for n in PARAM_NAMES],
        apply=gui.add_button("Apply pose"),
        reset_file=gui.add_button("Reset to file pose"),
        reset_truth=gui.add_button("Reset to ground truth"))


class PosePanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        self.h = h = build(tab.gui)
        self.units = ""
        h.apply.on_click(lambda e: tab.guarded(self.apply_typed))
        h.reset_file.on_click(lambda e: tab.guarded(lambda: tab.set_initial(self.state.T_file)))
        h.reset_truth.on_click(lambda e: tab.guarded(self.reset_truth))

    def typed(self) -> np.ndarray:
        """T_target_source from the six fields."""
        p = np.array([float(parse_number(f.value, label(n, self.units))) for f, n in zip(self.h.params, PARAM_NAMES)])
        return from_params(np.r_[p[:3], np.radians(p[3:])])

    def apply_typed(self) -> None:
        self.tab.set_initial(self.typed())

    def reset_truth(self) -> None:
        if self.state.T_truth is None:
            raise InputError("these scans carry no ground-truth pose")
        self.tab.set_initial(self.state.T_truth)

    def dragged(self) -> None:
        """The gizmo moved: its pose becomes the initial pose (ignored while a run holds the scans)."""
        st, nodes = self.state, self.tab.nodes
        if st.running or st.source is None or nodes is None:
            return
        T = st.display.pose_from_node(nodes.gizmo.wxyz, nodes.gizmo.position)
        with st.lock:
            st.T_init = T
            st.reset_run(T)
            st.E0 = float(st.problem.error(T))
        scene3d.move_source(nodes, st, T, gizmo=False)
        self.tab.clear_run_views()
        self.show(T)
        self.tab.update_status()

    def name_units(self, units: str) -> None:
        """A new pair: the translation fields say its units."""
        self.units = units
        for f, n in zip(self.h.params, PARAM_NAMES):
            f.label = label(n, units)

    def show(self, T: np.ndarray) -> None:
        p = to_params(T)
        for f, v in zip(self.h.params, np.r_[p[:3], np.degrees(p[3:])]):
            f.value = show_number(v)

    def lock(self, running: bool) -> None:
        self.h.apply.disabled = self.h.reset_file.disabled = running
        self.h.reset_truth.disabled = running or self.state.T_truth is None
