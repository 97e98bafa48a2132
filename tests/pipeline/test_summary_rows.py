"""The ``key  value`` rows every command's summary prints: one column of values."""

from bnptrack.pipeline.cli.common import rows_text


def test_values_line_up_under_the_longest_key():
    text = rows_text([("record.seed", "1"), ("record.tracker_seed", "0"), ("record.tracker_params", "vo2017")])
    assert text.splitlines() == [
        "record.seed            1",
        "record.tracker_seed    0",
        "record.tracker_params  vo2017",
    ]


def test_short_keys_keep_the_sixteen_character_column():
    assert rows_text([("run", "r1"), ("frames", "20")]).splitlines() == [
        "run               r1",
        "frames            20",
    ]
