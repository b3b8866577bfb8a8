"""A pose slid along the walls of a scene of planes (core.global_search.slide): walked along its weakest matched
translation, refined from the best slide, and a pinned pose left alone."""

from __future__ import annotations

import numpy as np
from rangereg.core.config import Config
from rangereg.core.global_search.setup import prepare_setup
from rangereg.core.global_search.slide import MAX_SLIDE_SHARE, MAX_SLIDES, slides
from rangereg.core.register import register
from rangereg.core.scenes_sensor import lidar_pair
from rangereg.core.threshold import constraint
from rangereg.core.transforms import invert, rotation_angle


def room():
    source, target = lidar_pair("room", 2)  # from the identity ICP alone slides 0.24 m along the room and fits
    return source, target, invert(target.pose) @ source.pose


def test_slides_walk_the_pose_along_its_weakest_translation_one_cap_apart_within_reach():
    source, target, T_true = room()
    setup = prepare_setup(source, target, np.eye(4), Config(method="global", seed=0))
    T_slid = T_true.copy()
    T_slid[0, 3] += 0.24  # where ICP from the identity ends, along the room's length
    P = slides(setup, T_slid)
    assert 0 < len(P) <= 2 * MAX_SLIDES
    assert np.allclose(P[:, :3, :3], T_true[:3, :3])  # translations only
    moves = P[:, :3, 3] - T_slid[:3, 3]
    d = constraint(setup.basis, T_slid).weakest[:3]
    d /= np.linalg.norm(d)
    assert np.allclose(np.abs(moves @ d), np.linalg.norm(moves, axis=1))  # along the weakest translation
    reach = min(setup.region.translation + setup.region.slack_translation, MAX_SLIDE_SHARE * target.size)
    steps = np.sort(np.abs(moves @ d))
    assert steps.max() <= reach + 1e-9 and steps[0] >= np.sqrt(setup.basis.cap) - 1e-12
    assert (moves @ d > 0).sum() == (moves @ d < 0).sum()  # both ways


def test_a_room_slid_from_the_identity_comes_back_to_the_truth_and_is_trusted():
    source, target, T_true = room()
    res = register(source, target, np.eye(4), Config(method="global", seed=0))
    T = res.T_target_source
    assert np.degrees(rotation_angle(T[:3, :3] @ T_true[:3, :3].T)) < 1.0
    assert np.linalg.norm(T[:3, 3] - T_true[:3, 3]) < 0.05
    assert res.trusted


def test_at_the_truth_the_pose_comes_back_unchanged_and_nothing_is_refined():
    import pytest
    from rangereg.core.global_search.slide import along_the_free_motion
    from rangereg.core.global_search.stream import EventStream

    source, target, T_true = room()
    setup = prepare_setup(source, target, np.eye(4), Config(method="global", seed=0))
    run = EventStream(None, None, setup.budget())
    T, last = along_the_free_motion(setup, run, T_true, None, lambda T0: pytest.fail("refined from a slide"))
    assert T is T_true and last is None and run.total() == 0


def test_where_the_whole_score_is_flat_along_a_fused_room_the_points_facing_the_slide_walk_it_home():
    # sim-fragments-0: slid along the room the whole score is as low as at the truth (86 % of the source matches
    # both ways); the end walls and furniture facing the slide are what pin it (core.global_search.slide: facing)
    from rangereg.app.sweep_sensors import SensorPair
    from rangereg.core.candidates import for_search
    from rangereg.core.global_search.refinement import refine
    from rangereg.core.global_search.slide import along_the_free_motion
    from rangereg.core.global_search.stream import EventStream
    from rangereg.core.guess import Guess
    from rangereg.core.transforms import pose_error

    source, target, T_true = SensorPair("sim-fragments", "sim-fragments-0", seed=0).load()
    source, target = for_search(source), for_search(target)
    setup = prepare_setup(source, target, Guess(T_true, 30.0, 0.5), Config(method="global", seed=1))
    d = constraint(setup.basis, T_true).weakest[:3]
    T_slid = T_true.copy()
    T_slid[:3, 3] += 0.216 * d / np.linalg.norm(d)  # where KISS-Matcher's pose refined ended from a 30-degree start
    assert not setup.trusted(T_slid) and setup.score(T_slid) < 1.05 * setup.score(T_true)  # the score cannot tell
    run = EventStream(None, None, setup.budget())

    def refine_from(T0, at=None):
        return refine(source, target, setup.surface, setup.guess.at(T0), setup.config, lambda *a: None, setup.frame,
                      at, setup.settled_somewhere)

    T, last = along_the_free_motion(setup, run, T_slid, None, refine_from)
    rot, move = pose_error(T, T_true)
    assert setup.trusted(T) and rot < 1.0 and move < 0.05 and last is not None
