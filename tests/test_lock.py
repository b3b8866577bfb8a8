"""Locked degrees of freedom (core.lock): the spec and its text, the allowed set, and registrations
under a lock that recover the truth while every event keeps the locked values, bit for bit."""

from __future__ import annotations

from functools import cache

import numpy as np
import pytest
from rangereg.core import Config, register
from rangereg.core.anneal import AnnealConfig
from rangereg.core.errors import InputError
from rangereg.core.guess import Guess
from rangereg.core.lock import Lock
from rangereg.core.transforms import PARAM_NAMES, apply, from_params, invert, perturb, pose_error

SHORT_SA = AnnealConfig(t_min_ratio=1e-5, cooling=0.93, moves_per_temperature=25, settle_below=1e-2,
                        max_evaluations=150)


@cache
def _bowl():
    from rangereg.core.simulate import SCENES, make_scene, true_transform

    target, source = make_scene("bowl", SCENES.index("bowl"))
    return source, target, true_transform(source, target)


AXIS = np.array([0.0, 0.0, 1.0])  # the bowl's turntable: vertical, through a point off its centre


def _turntable_case(angle_deg: float):
    source, target, Tt = _bowl()
    centre = apply(Tt, source.points.mean(0)[None])[0]
    point = centre + np.array([80.0, -50.0, 0.0])
    T0 = perturb(Tt, np.r_[0, 0, 0, np.radians(angle_deg) * AXIS], point)  # the truth turned on the table
    return source, target, Tt, T0, point


def _table(point) -> Lock:
    return Lock.parse("turntable:" + ",".join(repr(float(v)) for v in (*point, *AXIS)))


def _pose_from_coords(frame_T, x, pivot, scale):
    return perturb(frame_T, np.r_[x[:3] * scale, x[3:]], pivot)


# --- the spec ---------------------------------------------------------------------------------

@pytest.mark.parametrize("text, locked", [
    ("rx,ry,tz", ("tz", "rx", "ry")), ("RZ, tx", ("tx", "rz")), ("rotation", ("rx", "ry", "rz")),
    ("translation,rz", ("tx", "ty", "tz", "rz")), ("none", ()), ("", ()),
])
def test_a_lock_reads_the_locked_parameters_from_text(text, locked):
    lock = Lock.parse(text)
    assert lock.locked == locked and not lock.turntable
    assert lock.free == tuple(n for n in PARAM_NAMES if n not in locked)
    assert Lock.parse(str(lock)) == lock
    assert lock.active == bool(locked)


def test_a_turntable_lock_reads_its_axis_from_text():
    lock = Lock.parse("turntable:1,2,3,0,0,2")
    assert lock.axis_point == (1, 2, 3) and lock.axis_direction == (0, 0, 2) and not lock.translation
    assert lock.free == ("angle",) and lock.active
    loose = Lock.parse("turntable+translation:1,2,3,0,0,2")
    assert loose.translation and loose.free == ("angle", "tx", "ty", "tz")
    assert Lock.parse(str(loose)) == loose


@pytest.mark.parametrize("text, message", [
    ("rx,qq", "cannot lock qq"), ("rx,rx", "locked twice"), ("rotation,translation", "nothing is left"),
    ("turntable:1,2,3", "6 numbers"), ("turntable:1,2,3,0,0,0", "must not be zero"),
    ("turntable:1,2,3,0,0,nan", "3 finite numbers"), ("turntables:1,2,3,0,0,1", "turntable:px"),
    ("turntable:a,b,c,d,e,f", "6 numbers"), ("turntable:1e300,0,0,0,1,0", "axis point: 1e\\+300 is beyond"),
])
def test_a_nonsense_lock_is_refused_with_a_clear_message(text, message):
    with pytest.raises(InputError, match=message):
        Lock.parse(text)


@pytest.mark.parametrize("size", [1e300, 1e-300])
def test_a_turntable_direction_of_any_finite_length_is_its_unit_axis(size):
    frame = Lock.parse(f"turntable:0,0,0,0,{size},0").bind(np.eye(4), np.zeros(3), 1.0)
    np.testing.assert_allclose(frame.axis, [0, 1, 0])


def test_the_config_checks_its_lock():
    with pytest.raises(InputError, match="must be a core.lock.Lock"):
        Config(lock="rx").validate()
    with pytest.raises(InputError, match="both"):
        Config(lock=Lock(locked=("rx",), axis_point=(0, 0, 0), axis_direction=(0, 0, 1))).validate()
    with pytest.raises(InputError, match="tuple of names"):
        Config(lock=Lock(locked="rx")).validate()
    Config(lock=Lock.parse("rx")).validate()
    assert not Config().lock.active


# --- the allowed set ----------------------------------------------------------------------------

def test_project_puts_any_pose_on_the_allowed_set_and_keeps_one_already_there():
    rng = np.random.default_rng(3)
    T_ref = from_params(np.r_[rng.normal(0, 50, 3), rng.normal(0, 0.5, 3)])
    center = rng.normal(0, 10, 3)
    T = from_params(np.r_[rng.normal(0, 50, 3), rng.normal(0, 0.5, 3)]) @ T_ref
    lock = Lock.parse("rx,ry,tz")
    frame = lock.bind(T_ref, center, 7.0)
    P = lock.project(T, T_ref, center, 7.0)
    x = frame.coords_of(np.array(P))  # a fresh array: read back, not remembered
    assert np.all(np.abs(x[[2, 3, 4]]) < 1e-12)
    np.testing.assert_allclose(lock.project(P, T_ref, center, 7.0), P, atol=1e-12)
    # a turntable's projection turns about its axis only: points on the axis stay put
    table = Lock.parse("turntable:10,-20,5,0.3,0,1")
    Q = table.project(T, T_ref, center)
    D = Q @ invert(T_ref)
    on_axis = np.array([10, -20, 5.0]) + np.outer([-100, 0, 250], np.array([0.3, 0, 1]))
    np.testing.assert_allclose(apply(D, on_axis), on_axis, atol=1e-9)
    assert not np.allclose(D, np.eye(4))
    assert Lock().project(T, T_ref, center) is not None and np.array_equal(Lock().project(T, T_ref, center), T)


# --- registrations under a lock -----------------------------------------------------------------

def test_a_turntable_pair_registers_and_every_event_turns_about_the_axis_only():
    source, target, Tt, T0, point = _turntable_case(12.0)
    events = []
    res = register(source, target, T0, Config(method="hybrid", lock=_table(point)),
                   events.append)
    rot, tr = pose_error(res.transform, Tt, source.points.mean(0))
    assert res.below_threshold and rot < 0.5 and tr < 1.0, (rot, tr)
    assert pose_error(T0, Tt, source.points.mean(0))[0] > 11
    assert events and all(e.coords is not None for e in events)
    on_axis = point + np.outer([-300.0, 0.0, 300.0], AXIS)
    for e in events:
        assert np.all(e.coords[:3] == 0.0)  # translation locked: exactly zero
        assert np.all(e.coords[3:5] == 0.0)  # the rotation vector is angle x (0, 0, 1): exactly along the axis
        assert np.array_equal(e.T, _pose_from_coords(T0, e.coords, point, 1.0))  # made from them, bit for bit
        np.testing.assert_allclose(apply(e.T @ invert(T0), on_axis), on_axis, atol=1e-9)


def test_a_translation_only_lock_recovers_a_pure_shift_and_never_turns():
    source, target, Tt = _bowl()
    c = apply(Tt, source.points.mean(0)[None])[0]
    T0 = perturb(Tt, np.r_[60.0, -40.0, 30.0, 0, 0, 0], c)
    events = []
    res = register(source, target, T0, Config(method="hybrid", lock=Lock.parse("rotation")), events.append)
    rot, tr = pose_error(res.transform, Tt, source.points.mean(0))
    assert rot == 0.0 and tr < 0.5, (rot, tr)
    assert np.array_equal(res.transform[:3, :3], T0[:3, :3])
    for e in events:
        assert np.all(e.coords[3:] == 0.0)
        assert np.array_equal(e.T[:3, :3], T0[:3, :3])  # the rotation is T0's, bit for bit


@pytest.mark.parametrize("method, options", [
    ("hybrid", dict(anneal=AnnealConfig(max_evaluations=80))),
    ("icp", {}),
    ("sa", dict(sa_alone=SHORT_SA)),
    ("icp-restarts", dict(restarts=3)),
    ("basin-hopping", dict(hops=3)),
    ("hybrid", dict(recut_rounds=2, coarse_to_fine=True, polish=True, anneal=AnnealConfig(max_evaluations=60))),
    ("global", dict(rotation_deg=60.0)),  # candidates moved onto the allowed set
])
def test_every_method_keeps_the_locked_parameters_in_every_event(method, options):
    from rangereg.core.problem import prepare

    source, target, Tt = _bowl()
    c = apply(Tt, source.points.mean(0)[None])[0]
    T0 = perturb(Tt, np.r_[40.0, -20.0, 0, 0, 0, 0.06], c)  # the truth moved in free parameters only
    guess = Guess(T0, options.pop("rotation_deg", 15.0))
    config = Config(method=method, seed=2, lock=Lock.parse("rx,ry,tz"), **options)
    problem = prepare(source, target, guess, config.problem, seed=config.seed)
    pivot = apply(T0, problem.center[None])[0]
    events = []
    res = register(source, target, guess, config, events.append, problem=problem)
    assert events
    locked = [PARAM_NAMES.index(n) for n in ("tz", "rx", "ry")]
    for e in events:
        assert np.all(e.coords[locked] == 0.0), (e.phase, e.coords)
        # the pose is the one made from these coordinates around the start, bit for bit
        assert np.array_equal(e.T, _pose_from_coords(T0, e.coords, pivot, problem.scale))
    assert any(np.array_equal(e.T, res.transform) for e in events)
    if method != "sa":  # annealing alone with a short budget need not get closer
        assert problem.error(res.transform) < problem.error(T0)


def test_the_global_pipeline_registers_a_turntable_pair_from_far_round_the_table():
    # 100 deg round the table, no guess worth the name: candidates (rotation samples, feature matches)
    # are moved onto the turntable before they are scored, and every refinement turns about the axis only
    source, target, Tt, T0, point = _turntable_case(100.0)
    events = []
    res = register(source, target, Guess(T0, 180.0), Config(method="global", lock=_table(point)), events.append)
    rot, tr = pose_error(res.transform, Tt, source.points.mean(0))
    assert rot < 1.0 and tr < 1.0, (rot, tr)
    assert res.method == "global" and res.iterations.candidates >= 1
    on_axis = point + np.outer([-300.0, 0.0, 300.0], AXIS)
    for e in events:
        assert np.all(e.coords[:3] == 0.0) and np.all(e.coords[3:5] == 0.0)
        np.testing.assert_allclose(apply(e.T @ invert(T0), on_axis), on_axis, atol=1e-9)


def test_a_locked_trace_reads_back_with_its_coordinates():
    import json

    from rangereg.core.events import Event

    source, target, Tt, T0, point = _turntable_case(6.0)
    events = []
    register(source, target, T0, Config(method="icp", lock=_table(point)),
             events.append)
    back = [Event.from_json(json.loads(json.dumps(e.to_json()))) for e in events]
    assert all(np.array_equal(b.coords, e.coords) and np.array_equal(b.T, e.T) for b, e in zip(back, events))
    free = []
    register(source, target, T0, Config(method="icp"), free.append)
    assert all(e.coords is None and "coords" not in e.to_json() for e in free)


def test_the_search_state_projects_a_stage_s_own_poses_onto_the_allowed_set():
    from rangereg.core.problem import prepare
    from rangereg.core.search import SearchState

    source, target, Tt = _bowl()
    problem = prepare(source, target, Tt)
    T = from_params(np.r_[5.0, -3.0, 2.0, 0.02, -0.01, 0.03]) @ Tt
    assert SearchState(problem, Config(), None).project(T) is T
    state = SearchState(problem, Config(lock=Lock.parse("tx,rx,ry")), None)
    P = state.project(T)
    x = state.frame.coords_of(P)
    assert np.all(x[[0, 3, 4]] == 0.0) and np.array_equal(P, state.frame.pose(state.frame.free(P)))
    assert not np.allclose(x, 0)
