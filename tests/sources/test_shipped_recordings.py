"""The logs in recordings/ are what their README's commands write (recordings/README.md):
the same frames, stamps, sensors, measurement counts, order and metadata; the values equal to
4 units in the last place, a bearing to 4 units in the last place of pi (numpy's vectorised
arctan2, sin and cos depend on the CPU, and a bearing is wrapped through [0, 2 pi);
docs/models.md, "The generator")."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
from click.testing import CliRunner

from bnptrack.pipeline.cli import main
from bnptrack.sources.mcap_log import iter_frames, read_metadata
from bnptrack.tracker.models.measurement import measurement_kind

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "recordings" / "README.md"


def _commands() -> list[tuple[str, list[str]]]:
    """``(file name, simulate arguments)`` of every row of the README's table."""
    rows = re.findall(r"^\| `([\w.-]+\.mcap)` \|.*\| `bnptrack (simulate [^`]+)` \|$", README.read_text(), re.M)
    return [(name, cmd.split()) for name, cmd in rows]


def test_the_readme_lists_a_command_for_every_shipped_log():
    shipped = sorted(p.name for p in (ROOT / "recordings").glob("*.mcap"))
    assert sorted(name for name, _ in _commands()) == shipped


@pytest.mark.parametrize(("name", "args"), _commands(), ids=[n for n, _ in _commands()])
def test_simulating_again_gives_the_shipped_log(tmp_path, name, args):
    shipped = ROOT / "recordings" / name
    assert args[args.index("--out") + 1] == f"recordings/{name}"
    args[args.index("--out") + 1] = str(tmp_path / name)
    res = CliRunner().invoke(main, [*args, "-q"])
    assert res.exit_code == 0, res.output
    new, old = list(iter_frames(tmp_path / name)), list(iter_frames(shipped))
    assert read_metadata(tmp_path / name) == read_metadata(shipped)
    assert [(f.frame, f.stamp_ns, f.sensor, f.kind, f.z.shape) for f in new] == \
        [(f.frame, f.stamp_ns, f.sensor, f.kind, f.z.shape) for f in old]
    for a, b in zip(new, old):
        angle = np.isin(np.arange(a.z.shape[1]), measurement_kind(a.kind).wrapped)
        np.testing.assert_allclose(a.z[:, angle], b.z[:, angle], rtol=0, atol=4 * np.spacing(np.pi))
        np.testing.assert_array_max_ulp(a.z[:, ~angle], b.z[:, ~angle], maxulp=4)
        assert a.truth.ids == b.truth.ids
        np.testing.assert_array_max_ulp(a.truth.states, b.truth.states, maxulp=4)
