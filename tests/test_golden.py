"""Golden traces: seeded runs of the paper's methods on two bundled scenes, pinned draw for draw.

Each run in ``RUNS`` registers a simulated scene (``core.simulate.make_scene`` with the bundled
scenes' seeds, as the bench does) from a seeded start and is compared with its record in
``tests/golden/NAME.json``: the number of events, the counts per phase, a sha256 of the event stream's
skeleton (phase, iteration, leg, accepted, local minimum of every event: the run's draws and decisions),
the first and last few events and the final result. The skeleton must match exactly; the floats (poses,
E, temperatures, the threshold) to ``RTOL``: Embree (float32) picks each query's triangle and the point on it is
worked out in float64 (core.surface.closest_on_triangles), so E no longer follows the processor's float32
kernels (it did: 1e-4 apart and an ICP leg 7 iterations shorter on another machine), but a tie between two
triangles may still go either way. (``sha256`` in a record hashes every float to 10 digits on the machine that
wrote it: information, not compared.) Such a tie did go the other way on 2026-12-07's processors (two AMD EPYCs,
one with AVX-512 and one with AVX2 only, alike; the code of the day before, whose records passed on the earlier
machine: the corner's E 0.22374 against 0.22370, and the basin hopping's path parted). So a trace passes where it
matches the common record (``tests/golden/``) or the one made on those processors (``tests/golden/other-ties/``):
either way a refactor that changes behaviour parts from both. The order Embree visits the faces decides such ties:
the same faces handed to it in another order (their indices mapped back) end the corner's trace at E 0.223727 on one
processor. Asking, where a closest point lies on the picked face's edge or corner, every face there in float64
(ties to the least vertex indices) made all ten records the same whatever the order, but cost 0.2-0.6 s more on the
shared Kinect pair (2026-12-07: ~40 % of a leg's queries lie beyond an edge or a corner), so it was not taken. A
refactor must leave every record as it is; a commit that changes behaviour on purpose regenerates them and says why
(on a processor of each kind, or says which kind it could not):

    PYTHONPATH=. .venv/bin/python tests/test_golden.py                 # rewrites the common records
    PYTHONPATH=. .venv/bin/python tests/test_golden.py --other-ties    # ... or the other processors' ones

Annealing runs with small evaluation budgets so that the whole file stays quick.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from functools import cache
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import ESCAPE

GOLDEN = Path(__file__).resolve().parent / "golden"
SCENE_START_MM = {"corner": 250.0, "bowl": 250.0 * 600 / 1219.2}  # app.bench's 5-degree starts
EDGE = 3  # events kept verbatim at each end of a trace
# Floats agree to this between machines: measured 1.8e-5 (E on the corner, ICP) between two processors with
# the same code; a change of behaviour moves a pose or an E by far more, or changes the skeleton.
RTOL = 1e-4
ATOL = 1e-6  # for entries that are ~0 (rotation entries, temperatures at the end)
SA_SHORT = dict(t_min_ratio=1e-5, cooling=0.93, moves_per_temperature=25, settle_below=1e-2, max_evaluations=120)


@dataclass(frozen=True)
class Run:
    name: str
    scene: str
    rot_deg: float
    trans_mm: float
    start_seed: int
    options: dict = field(default_factory=dict)  # Config fields; "anneal"/"sa_alone" as AnnealConfig kwargs


RUNS = (
    Run("corner-hybrid", "corner", 5.0, SCENE_START_MM["corner"], 0, dict(method="hybrid", seed=0)),
    Run("corner-icp", "corner", 5.0, SCENE_START_MM["corner"], 0, dict(method="icp", seed=0)),
    Run("corner-sa", "corner", 5.0, SCENE_START_MM["corner"], 0, dict(method="sa", seed=0, sa_alone=SA_SHORT)),
    Run("bowl-hybrid", "bowl", 5.0, SCENE_START_MM["bowl"], 0, dict(method="hybrid", seed=0,
                                                                    anneal=dict(max_evaluations=60))),
    Run("bowl-icp", "bowl", 5.0, SCENE_START_MM["bowl"], 0, dict(method="icp", seed=0)),
    Run("bowl-sa", "bowl", 5.0, SCENE_START_MM["bowl"], 0, dict(method="sa", seed=0, sa_alone=SA_SHORT)),
    # ICP stuck, annealing gets it out; and the options beyond the paper, so that a refactor of the
    # driver is pinned where they branch
    Run("escape-hybrid", *ESCAPE, dict(method="hybrid", seed=4, anneal=dict(max_evaluations=200))),
    Run("escape-hybrid-options", *ESCAPE, dict(method="hybrid", seed=4, recut_rounds=2, coarse_to_fine=True, polish=True,
                                               anneal=dict(max_evaluations=100))),
    Run("escape-basin-hopping", *ESCAPE, dict(method="basin-hopping", seed=4, hops=2)),
    Run("bowl-icp-restarts", "bowl", 5.0, SCENE_START_MM["bowl"], 0, dict(method="icp-restarts", seed=0, restarts=3)),
)


@cache
def _case(scene: str, rot_deg: float, trans_mm: float, start_seed: int):
    from rangereg.core.simulate import SCENES, make_scene, true_transform
    from rangereg.core.transforms import perturb, random_perturbation

    target, source = make_scene(scene, SCENES.index(scene))  # the bundled scenes' seeds
    T_true = true_transform(source, target)
    t, r = random_perturbation(np.random.default_rng(start_seed), rot_deg, trans_mm)
    c = T_true[:3, :3] @ source.centroid + T_true[:3, 3]
    return source, target, perturb(T_true, np.r_[t, r], c)


def _config(run: Run):
    from rangereg.core.anneal import AnnealConfig
    from rangereg.core.register import Config

    kw = dict(run.options)
    for key in ("anneal", "sa_alone"):
        if key in kw:
            kw[key] = AnnealConfig(**kw[key])
    return Config(**kw)


def _round(x: float) -> float:
    return float(f"{x:.10g}")


def _event_record(e) -> dict:
    return {"phase": e.phase, "iteration": e.iteration, "phase_iteration": e.phase_iteration, "leg": e.leg,
            "T": [_round(v) for v in np.asarray(e.T).ravel()], "error": _round(e.error),
            "temperature": None if e.temperature is None else _round(e.temperature),
            "accepted": bool(e.accepted), "local_minimum": bool(e.local_minimum)}


RESULT_KEYS = ("error", "iterations", "local_minima", "evaluations", "method", "threshold", "stop_reason")


def record(run: Run) -> dict:
    """Register ``run`` and describe its trace and result (every float rounded to 10 digits)."""
    from rangereg.core.register import register

    source, target, T0 = _case(run.scene, run.rot_deg, run.trans_mm, run.start_seed)
    events = []
    res = register(source, target, T0, _config(run), events.append)
    trace = [_event_record(e) for e in events]
    blob = json.dumps(trace, sort_keys=True, separators=(",", ":")).encode()
    out = res.to_json()
    result = {k: out[k] for k in RESULT_KEYS}
    result["error"], result["threshold"] = _round(result["error"]), _round(result["threshold"])
    result["transform"] = [_round(v) for v in res.transform.ravel()]
    phases = {p: sum(e.phase == p and not e.local_minimum for e in events) for p in ("icp", "sa")}
    phases["local_minimum"] = sum(e.local_minimum for e in events)
    return {"events": len(events), "phases": phases, "sha256": hashlib.sha256(blob).hexdigest(),
            "skeleton_sha256": _skeleton_sha(trace), "first": trace[:EDGE], "last": trace[-EDGE:], "result": result}


SKELETON = ("phase", "iteration", "phase_iteration", "leg", "accepted", "local_minimum")


def _skeleton_sha(trace: list[dict]) -> str:
    skeleton = [[e[k] for k in SKELETON] for e in trace]
    return hashlib.sha256(json.dumps(skeleton, separators=(",", ":")).encode()).hexdigest()


def _close(got, expected, where: str = "") -> None:
    """``got`` equals ``expected`` exactly but for floats, which agree to RTOL / ATOL (recursively)."""
    if isinstance(expected, dict):
        assert got.keys() == expected.keys(), where
        for k in expected:
            _close(got[k], expected[k], f"{where}.{k}")
    elif isinstance(expected, list):
        assert len(got) == len(expected), where
        for i, (g, e) in enumerate(zip(got, expected)):
            _close(g, e, f"{where}[{i}]")
    elif isinstance(expected, float) and not isinstance(expected, bool):
        assert got == pytest.approx(expected, rel=RTOL, abs=ATOL), where
    else:
        assert got == expected, where


# Where the records are: the common ones, and those of processors whose Embree breaks the ties between equally near
# triangles the other way (module notes)
KINDS = ("", "other-ties")


def _path(run: Run, kind: str = "") -> Path:
    return GOLDEN / kind / f"{run.name}.json"


def _check(got: dict, expected: dict) -> None:
    # the coarse claims first, so that a failure says where the run departs
    _close(got["result"], expected["result"], "result")
    assert (got["events"], got["phases"]) == (expected["events"], expected["phases"])
    _close(got["first"], expected["first"], "first")
    _close(got["last"], expected["last"], "last")
    assert got["skeleton_sha256"] == expected["skeleton_sha256"]


@pytest.mark.parametrize("run", RUNS, ids=[r.name for r in RUNS])
def test_trace_is_unchanged(run):
    got = record(run)
    failures = []
    for kind in KINDS:
        if _path(run, kind).exists():
            try:
                return _check(got, json.loads(_path(run, kind).read_text()))
            except AssertionError as exc:
                failures.append(f"{kind or 'common'} record: {exc}")
    pytest.fail("the trace matches no record (" + "; ".join(failures) + ")")


def test_a_trace_read_back_gives_the_same_poses_and_final_pose():
    # register -> events -> JSON lines -> Event.from_json: what `register --trace` and `slice --trace` do
    from rangereg.core.events import Event
    from rangereg.core.register import register

    run = next(r for r in RUNS if r.name == "escape-hybrid")  # ICP and annealing events, a local minimum
    source, target, T0 = _case(run.scene, run.rot_deg, run.trans_mm, run.start_seed)
    events = []
    res = register(source, target, T0, _config(run), events.append)
    lines = [json.dumps(e.to_json()) for e in events]
    back = [Event.from_json(json.loads(line)) for line in lines]
    assert [(b.phase, b.iteration, b.phase_iteration, b.leg, b.error, b.temperature, b.accepted, b.local_minimum)
            for b in back] == [(e.phase, e.iteration, e.phase_iteration, e.leg, e.error, e.temperature, e.accepted,
                                e.local_minimum) for e in events]
    assert all(np.array_equal(b.T, e.T) for b, e in zip(back, events))
    assert np.array_equal(back[-1].T, events[-1].T)
    assert any(np.array_equal(b.T, res.transform) for b in back)  # the answer is a pose the trace shows


def write_all(kind: str) -> None:
    (GOLDEN / kind).mkdir(parents=True, exist_ok=True)
    for run in RUNS:
        rec = record(run)
        _path(run, kind).write_text(json.dumps(rec, indent=1) + "\n")
        print(f"{run.name}: {rec['events']} events, {rec['result']['stop_reason']}")


if __name__ == "__main__":
    import sys

    write_all("other-ties" if "--other-ties" in sys.argv[1:] else "")
