"""rangereg.app.options: the one path from plain settings (CLI text, page fields) to a core Config."""

from __future__ import annotations

import json

import numpy as np
import pytest
from rangereg.app.options import KNOBS, Settings, parse_init, parse_numbers, parse_value, to_config
from rangereg.core.errors import InputError
from rangereg.core.register import Config


@pytest.mark.parametrize("name, text, value", [
    ("seed", "42", 42), ("seed", " 7 ", 7), ("seed", 3.0, 3), ("seed", np.int64(5), 5),
    ("threshold", "2.5e-3", 2.5e-3), ("threshold", "0", 0.0), ("cooling", "0.9", 0.9),
    ("steps", "201", 201), ("port", "8080", 8080), ("rotation_uncertainty", "180", 180.0),
])
def test_a_good_value_parses_as_typed(name, text, value):
    v = parse_value(name, text)
    assert v == value and type(v) is KNOBS[name].kind


@pytest.mark.parametrize("name, text, fragment", [
    ("seed", "-1", "must be >= 0"), ("seed", "1e30", "expected a whole number"), ("seed", "1.5", "whole number"),
    ("seed", 1.5, "whole number"), ("seed", "12,5", "whole number"), ("seed", True, "expected a whole number"),
    ("seed", str(2**40), "<= 4294967295"), ("max_points", "2", ">= 3"), ("steps", "1000000", "<= 201"),
    ("threshold", "nan", "finite"), ("threshold", "inf", "finite"), ("threshold", "-3", ">= 0"),
    ("threshold", "12,5", "expected a number"), ("t_start", "inf", "finite"), ("t_start", "0", "> 0"),
    ("cooling", "1", "< 1"), ("t_min_ratio", "0", "> 0"), ("rotation_uncertainty", "0", ">= 0.01"),
    ("translation_uncertainty", "-1", "> 0"), ("port", "99999", "<= 65535"), ("hops", "-1", ">= 0"),
    ("recut_rounds", "0", ">= 1"), ("upload_cap_mb", "0", "> 0"),
])
def test_a_bad_value_is_one_message_naming_the_setting(name, text, fragment):
    with pytest.raises(InputError) as e:
        parse_value(name, text)
    assert str(e.value).startswith(KNOBS[name].flag) and fragment in str(e.value)


def test_the_page_can_name_its_own_field():
    with pytest.raises(InputError, match="^Seed: expected a whole number"):
        parse_value("seed", "1e30", label="Seed")


def test_settings_from_page_text_reach_the_config():
    s = Settings(method="sa", seed="3", threshold="auto", max_points="120", t_start="auto", t_min_ratio="0.001",
                 cooling="0.8", icp_max_iterations="50", sa_max_evaluations="5000", frustum="nonconvex")
    cfg = to_config(s)
    assert isinstance(cfg, Config) and cfg.method == "sa" and cfg.threshold is None
    assert cfg.seed == 3  # one seed: Config.seed, passed down to prepare()
    assert cfg.problem.max_points == 120 and cfg.problem.frustum == "nonconvex"
    assert cfg.icp.max_iterations == 50
    for a in (cfg.anneal, cfg.sa_alone):  # the annealing knobs reach annealing alone too
        assert (a.t_min_ratio, a.cooling, a.max_evaluations, a.t_start) == (0.001, 0.8, 5000, None)


def test_settings_left_out_keep_the_cores_defaults():
    cfg, base = to_config(Settings()), Config()
    assert cfg.problem == base.problem and cfg.anneal == base.anneal and cfg.sa_alone == base.sa_alone
    assert (cfg.hops, cfg.restarts, cfg.recut_rounds, cfg.icp) == (base.hops, base.restarts, base.recut_rounds, base.icp)


def test_settings_from_argparse_vars_ignore_unknown_keys():
    s = Settings.from_mapping({"seed": 4, "method": "icp", "png": "x.png", "command": "slice"}, hops=9)
    assert (s.seed, s.method, s.hops) == (4, "icp", 9)


@pytest.mark.parametrize("kw, fragment", [
    ({"method": "magic"}, "unknown method"), ({"frustum": "round"}, "--frustum"), ({"seed": "-2"}, "--seed"),
    ({"seed": None}, "--seed"), ({"sa_max_evaluations": "3"}, ">= 7"),
])
def test_bad_settings_are_refused(kw, fragment):
    with pytest.raises(InputError, match=fragment):
        Settings(**kw)


def test_init_takes_16_numbers_inline_or_a_file(tmp_path):
    T = np.eye(4)
    T[:3, 3] = (1, 2, 3)
    text = " ".join(map(str, T.ravel()))
    assert np.array_equal(parse_init(text), T)
    assert np.array_equal(parse_init(",".join(map(str, T.ravel()))), T)
    (tmp_path / "T.txt").write_text(text)
    (tmp_path / "T.json").write_text(json.dumps({"transform": T.tolist()}))
    assert np.array_equal(parse_init(str(tmp_path / "T.txt")), T)
    assert np.array_equal(parse_init(str(tmp_path / "T.json")), T)


@pytest.mark.parametrize("text, fragment", [
    ("1 2 3", "16 numbers"), ("left a bit", "not 16 numbers"), ("nope.txt", "no such file"), ("", "nothing"),
    (" ".join(["1"] * 16), "last row"), ("2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1", "not rigid"),
])
def test_a_bad_init_is_one_message(text, fragment):
    with pytest.raises(InputError, match=fragment):
        parse_init(text)


def test_an_init_folder_or_binary_file_is_one_message(tmp_path):
    with pytest.raises(InputError, match="is a folder"):
        parse_init(str(tmp_path))
    (tmp_path / "b.bin").write_bytes(bytes(range(256)))
    with pytest.raises(InputError, match="not a text file"):
        parse_init(str(tmp_path / "b.bin"))


def test_parse_numbers():
    assert parse_numbers("1, 2.5", "--span", 2) == (1.0, 2.5)
    for bad in ("1", "a,b", "1,nan", "0,1", "-1,1"):
        with pytest.raises(InputError, match="--span"):
            parse_numbers(bad, "--span", 2)


def test_a_lock_reaches_the_config_and_a_bad_one_is_one_message():
    from rangereg.core.lock import Lock

    assert to_config(Settings(lock="rx, ry,tz")).lock == Lock(locked=("tz", "rx", "ry"))
    assert to_config(Settings(lock="turntable:0,0,0,0,1,0")).lock.free == ("angle",)
    assert not to_config(Settings()).lock.active and not to_config(Settings(lock="none")).lock.active
    with pytest.raises(InputError, match="^--lock: cannot lock qq"):
        Settings(lock="rx,qq")
    with pytest.raises(InputError, match="^--lock: expected text"):
        Settings(lock=3)


def test_an_init_of_sixteen_long_numbers_is_read_as_numbers_not_a_file_name():
    import numpy as np
    from rangereg.app.options import parse_init
    from rangereg.core.transforms import rotation_matrix

    T = np.eye(4)
    T[:3, :3] = rotation_matrix(np.array([0.3, -0.2, 0.5]))
    T[:3, 3] = [-0.048564374008218336, 0.008956121399062985, -0.010020339583596436]
    text = " ".join(repr(float(v)) for v in T.ravel())  # longer than a file name may be
    assert len(text) > 255
    assert np.allclose(parse_init(text), T)
