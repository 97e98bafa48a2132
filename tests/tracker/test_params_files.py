"""Params files name only what they change."""

from __future__ import annotations

import pytest

from bnptrack.tracker.config import ConfigError, apply_overrides
from bnptrack.tracker.models.params import BirthComponent, load_params


def _write(tmp_path, name, text):
    f = tmp_path / name
    f.write_text(text)
    return str(f)


def test_extends_builtin_names_only_the_change(tmp_path):
    p = load_params(_write(tmp_path, "mine.toml", 'extends = "vo2017"\np_detect = 0.9\n'))
    vo = load_params("vo2017")
    assert p.name == "mine" and p.p_detect == 0.9
    assert p.clutter_rate == vo.clutter_rate and p.sigma_range == vo.sigma_range
    # paper differs from the struct defaults: extends picks up its values
    q = load_params(_write(tmp_path, "q.toml", 'extends = "paper"\nclutter_rate = 3.0\n'))
    assert q.sigma_accel == load_params("paper").sigma_accel == 15.0 and q.clutter_rate == 3.0
    # no extends, no name: the struct defaults and the file's stem
    assert load_params(_write(tmp_path, "bare.toml", "clutter_rate = 2.0\n")).name == "bare"


def test_birth_regions_inherited_unless_replaced(tmp_path):
    _write(tmp_path, "base.toml", 'name = "b"\n[[birth]]\nr = 0.1\nmean = [0.0, 0.0, 500.0, 0.0, 0.0]\n'
                  'std = [50.0, 10.0, 50.0, 10.0, 0.1]\n[sensors.radar]\nx = 5.0\nheading_deg = 90.0\n')
    child = load_params(_write(tmp_path, "child.toml", 'extends = "base.toml"\nclutter_rate = 4.0\n'
                               '[sensors.radar]\ny = 7.0\n'))
    assert child.birth == [BirthComponent(0.1, [0.0, 0.0, 500.0, 0.0, 0.0], [50.0, 10.0, 50.0, 10.0, 0.1])]
    assert child.name == "child" and child.clutter_rate == 4.0
    s = child.sensors["radar"]
    assert (s.x, s.y, s.heading_deg) == (5.0, 7.0, 90.0)  # sensor tables merge per key
    replaced = load_params(_write(tmp_path, "r.toml", 'extends = "base.toml"\nbirth = []\n'))
    assert replaced.birth == []


@pytest.mark.parametrize("text, fragment", [
    ("p_detet = 0.9\n", "unknown key 'p_detet' (did you mean 'p_detect'?)"),
    ("clutter_rat = 3.0\n", "did you mean 'clutter_rate'?"),
    ('[sensors.radar]\nheadng_deg = 10.0\n', "unknown key 'sensors.radar.headng_deg' (did you mean 'heading_deg'?)"),
    ('extends = "vo2018"\n', "extends 'vo2018': not a built-in set"),
])
def test_unknown_key_did_you_mean(tmp_path, text, fragment):
    with pytest.raises(ConfigError) as ei:
        load_params(_write(tmp_path, "bad.toml", text))
    assert fragment in str(ei.value)


@pytest.mark.parametrize("item", ["sigma_bearing_deg=1e308", "sigma_range=inf", "range_max=inf", "T=inf",
                                  "sigma_accel=nan", "sigma_accel=-inf"])
def test_a_setting_must_be_finite(item):
    """Every non-negative or positive setting is finite and at most 1e12 (its square stays
    finite): an infinite, NaN or overflowing value is an error naming the item."""
    with pytest.raises(ConfigError, match=rf"^--set '{item}': expected `float` (<= 1000000000000.0|>= 0.0)$"):
        apply_overrides(load_params("vo2017"), [item])
    key = item.partition("=")[0]
    assert apply_overrides(load_params("vo2017"), [f"{key}=1e12"]).__getattribute__(key) == 1e12


@pytest.mark.parametrize(("item", "message"), [
    ("clutter_rate=1e300", "expected `float` <= 1000000.0"),
    ("clutter_rate=1e9", "expected `float` <= 1000000.0"),
    ("range_clutter_rate=2e6", "expected `float` <= 1000000.0"),
])
def test_a_clutter_rate_is_at_most_a_million_a_scan(item, message):
    """The simulator draws every clutter point: a billion a scan would fill the machine's memory."""
    with pytest.raises(ConfigError, match=rf"^--set '{item}': {message}$"):
        apply_overrides(load_params("vo2017"), [item])
    key = item.partition("=")[0]
    assert getattr(apply_overrides(load_params("vo2017"), [f"{key}=1e6"]), key) == 1e6


def test_set_did_you_mean():
    with pytest.raises(ConfigError, match="did you mean 'sigma_range'"):
        apply_overrides(load_params("vo2017"), ["sigma_rang=3"])


def test_extends_cycle(tmp_path):
    _write(tmp_path, "a.toml", 'extends = "b.toml"\n')
    _write(tmp_path, "b.toml", 'extends = "a.toml"\n')
    with pytest.raises(ConfigError, match="extends cycle"):
        load_params(str(tmp_path / "a.toml"))


@pytest.mark.parametrize(("tracker", "item"), [("ddp", "sweeps=1000000000"), ("ddp-mb", "sweeps=10001"),
                                               ("ddp", "objects.sweeps=20000"), ("glmb", "chain_length=100000")])
def test_sweeps_per_frame_are_at_most_ten_thousand(tracker, item):
    """Each sweep's random numbers are drawn before it: a billion sweeps would fill the memory."""
    from bnptrack.tracker.registry import kind

    preset = kind(tracker).presets[tracker]
    with pytest.raises(ConfigError, match=rf"^--set '{item}': expected `int` <= 10000$"):
        apply_overrides(preset, [item])
    key = item.partition("=")[0]
    done = apply_overrides(preset, [f"{key}=10000"])
    for part in key.split("."):
        done = getattr(done, part)
    assert done == 10000


@pytest.mark.parametrize("item, message", [
    ("sensors.radar0.headng_deg=90", "^--set 'sensors.radar0.headng_deg=90': unknown key 'sensors.radar0.headng_deg' "
                                     r"\(did you mean 'sensors.radar0.heading_deg'\?\) \(known here: .*\bx, y\)$"),
    ('sensors.radar0.x="abc"', "^--set 'sensors.radar0.x=\"abc\"': expected `float`, got `str`$"),
    ("sensors.radar0=5", r"^--set 'sensors.radar0=5': 'sensors.radar0' is a table of keys, not a value: set one of "
                         r"its keys, e.g. --set 'sensors.radar0.x=5' \(its keys: kind, x, y, heading_deg, .*\)$"),
    ("sensors.radar0.kind='rnge'", "^--set \"sensors.radar0.kind='rnge'\": \\[sensors.radar0\\] kind = 'rnge' is not a "
                                   r"measurement kind \(did you mean 'range'\?\) \(known: bearing_range, range, xy\)$"),
])
def test_a_bad_sensor_item_names_the_item_the_sensor_and_the_close_key(item, message):
    with pytest.raises(ConfigError, match=message):
        load_params("vo2017", [item])


def test_a_bad_value_in_a_sensor_table_of_a_file_names_the_sensor(tmp_path):
    path = _write(tmp_path, "p.toml", 'extends = "vo2017"\n[sensors.radar0]\nx = 1.0\n[sensors.radar1]\nx = "abc"\n')
    with pytest.raises(ConfigError, match=r"^.*p\.toml: Expected `float`, got `str` - at `\$\.sensors\.radar1\.x`$"):
        load_params(path)


def test_a_sensor_table_set_whole_is_a_table():
    p = load_params("vo2017", ["sensors.radar0={x=1500.0, heading_deg=30.0}"])
    assert (p.sensors["radar0"].x, p.sensors["radar0"].heading_deg) == (1500.0, 30.0)


@pytest.mark.parametrize("item", ["max_hypotheses=1000000000", "max_hypotheses_after=100001"])
def test_glmb_hypotheses_per_frame_are_at_most_a_hundred_thousand(item):
    """Every requested hypothesis is sampled and held: a billion would fill the memory."""
    from bnptrack.tracker.registry import kind

    preset = kind("glmb").presets["glmb"]
    with pytest.raises(ConfigError, match=rf"^--set '{item}': expected `int` <= 100000$"):
        apply_overrides(preset, [item])
    key = item.partition("=")[0]
    assert getattr(apply_overrides(preset, [f"{key}=100000"]), key) == 100000
