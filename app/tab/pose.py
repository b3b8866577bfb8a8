"""The Pose panel: the six parameters of the initial pose (where runs start), typed or dragged with the gizmo, and
the pose the last run ended at, read-only beside them.

The fields show 4 significant digits, as every number on the page; a field left as shown applies the exact value
it stands for (a pose dragged or set from pairs is not rounded by pressing Apply), a field typed in applies what
was typed."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import viser
from rangereg.app.figures import axis_label, fmt, unit_label
from rangereg.app.tab import scene3d
from rangereg.app.tab.fields import parse_number
from rangereg.app.tab.status import E_LABEL, outcome
from rangereg.core.errors import InputError
from rangereg.core.transforms import PARAM_NAMES, from_params, to_params


@dataclass(eq=False)
class PoseHandles:
    params: list[viser.GuiTextHandle]  # the initial pose: tx ty tz in the scans' units, rx ry rz in degrees
    apply: viser.GuiButtonHandle
    reset_file: viser.GuiButtonHandle
    reset_truth: viser.GuiButtonHandle
    result: viser.GuiMarkdownHandle  # the last run's pose, read-only
    from_result: viser.GuiButtonHandle


def label(param: str, units: str = "") -> str:
    """The field's label: rotations in degrees, translations in the scans' own units once known."""
    if param.startswith("r"):
        return f"{param} (deg)"
    return axis_label(param, units) if units else param


NO_RESULT = "No run yet: a run starts from the initial pose above and its pose shows here."


def build(gui: viser.GuiApi) -> PoseHandles:
    with gui.add_folder("Initial pose (where runs start)"):
        params = [gui.add_text(label(n), "0", hint="the initial pose: typed, dragged with the gizmo or set from "
                               "point pairs; Apply pose to use what is typed") for n in PARAM_NAMES]
        apply = gui.add_button("Apply pose", hint="the six fields become the initial pose")
        reset_file = gui.add_button("Reset to file pose")
        reset_truth = gui.add_button("Reset to ground truth")
    with gui.add_folder("Result of the last run (read-only)"):
        result = gui.add_markdown(NO_RESULT)
        from_result = gui.add_button("Start from the result", disabled=True,
                                     hint="the last run's pose becomes the initial pose")
    return PoseHandles(params, apply, reset_file, reset_truth, result, from_result)


def pose_text(T: np.ndarray, units: str) -> str:
    """The six parameters of ``T`` in 4 significant digits with their units, for a read-only line."""
    p = to_params(T)
    values = np.r_[p[:3], np.degrees(p[3:])]
    return " · ".join(f"{n} {fmt(_clean(v))} {unit_label(n, units)}" for n, v in zip(PARAM_NAMES, values))


def _clean(v: float) -> float:
    return 0.0 if abs(float(v)) < 1e-12 else float(v)  # round-off (a rotation of -2.8e-17 degrees) is 0


class PosePanel:
    def __init__(self, tab):
        self.tab, self.state = tab, tab.state
        self.h = h = build(tab.gui)
        self.units = ""
        self.shown: list[tuple[str, float]] = [("0", 0.0)] * len(PARAM_NAMES)  # (text shown, exact value) per field
        self.result_shown = None  # the run result the read-only line shows
        h.apply.on_click(tab.action(self.apply_typed))
        h.from_result.on_click(tab.action(self.start_from_result))
        h.reset_file.on_click(tab.action(lambda: tab.set_initial(self.state.T_file)))
        h.reset_truth.on_click(tab.action(self.reset_truth))

    def typed(self) -> np.ndarray:
        """T_target_source from the six fields (a field as shown stands for its exact value)."""
        p = np.array([exact if f.value.strip() == text else float(parse_number(f.value, label(n, self.units)))
                      for f, n, (text, exact) in zip(self.h.params, PARAM_NAMES, self.shown)])
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
        """The initial pose ``T`` in the fields, 4 significant digits."""
        p = to_params(T)
        self.shown = [(fmt(_clean(v)), _clean(v)) for v in np.r_[p[:3], np.degrees(p[3:])]]
        for f, (text, _) in zip(self.h.params, self.shown):
            f.value = text

    def show_result(self, result) -> None:
        """The read-only line: the last run's pose (core.register.Result, or None: no run since the pair or the
        initial pose changed). Cheap when unchanged: the status calls it on every push."""
        if result is self.result_shown:
            return
        self.result_shown = result
        if result is None:
            self.h.result.content = NO_RESULT
        else:
            kind = outcome(result)  # a cancelled run's pose is not a result: the best it had found, or the initial one
            self.h.result.content = f"**{pose_text(result.transform, self.units)}**" + (
                "" if kind == "result" else f" ({E_LABEL[kind].replace('not a result', 'not trusted')})")
        self.h.from_result.disabled = result is None or self.state.running

    def start_from_result(self) -> None:
        result = self.state.result
        if result is None:
            raise InputError("no run has ended yet: there is no result to start from")
        self.tab.set_initial(result.transform)

    def lock(self, running: bool) -> None:
        self.h.apply.disabled = self.h.reset_file.disabled = running
        self.h.from_result.disabled = running or self.state.result is None
        self.h.reset_truth.disabled = running or self.state.T_truth is None
