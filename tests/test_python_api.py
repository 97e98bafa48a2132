"""The Python API (docs/python.md): its worked example runs as written, and the facade is the
same library as the command line."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import bnptrack

ROOT = Path(__file__).resolve().parents[1]


def _doc_example() -> str:
    text = (ROOT / "docs" / "python.md").read_text()
    blocks = re.findall(r"```python\n(.*?)```", text, re.S)
    assert len(blocks) == 1, "docs/python.md has one worked example"
    return blocks[0]


@pytest.mark.slow  # three 100-frame runs; the fast subset keeps the README snippet of the same API
def test_the_worked_example_in_docs_runs(tmp_path, capsys):
    code = _doc_example().replace("/tmp/bnptrack-example.mcap", str(tmp_path / "example.mcap"))
    exec(compile(code, "docs/python.md", "exec"), {})
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("100 bearing_range")
    assert re.fullmatch(r"mean OSPA \d+\.\d\d m, final tracks \d+", out[1])
    ospa = [float(re.search(r"(\d+\.\d\d) m", line).group(1)) for line in out[1:4]]
    assert 15 < ospa[0] < 40 and ospa[0] != ospa[1] and ospa[0] != ospa[2]  # three different runs
    assert ospa[1] > ospa[0]  # vo2017's births are in its regions: knowing them helps
    assert re.fullmatch(r"\['[^']+'(, '[^']+')*\]", out[4])  # the GLMB's labels after 10 frames
    assert out[5] == "vo2017 100"
    assert out[6] == "20.0 0.98"


def test_the_readme_snippet_prints_names_and_positions(capsys):
    """README's "From Python" snippet: the mean OSPA, then one line per final track with its
    display name and position (vo2017 seed 1, tracker seed 0: the 5 tracks `track` names)."""
    text = (ROOT / "README.md").read_text()
    code = text.split("**From Python**")[1].split("```python\n")[1].split("```")[0]
    exec(compile(code, "README.md", "exec"), {})
    out = capsys.readouterr().out.splitlines()
    assert out[0] == "mean OSPA 24.57 m"
    assert [line.split()[0] for line in out[1:]] == ["T1.4", "T8.7", "T9.4", "T40.13", "T37.11"]
    for line in out[1:]:
        assert re.fullmatch(r"T\S+ -?\d+\.\d -?\d+\.\d", line), line  # no TrackEstimate repr


def test_track_gives_what_the_cli_gives(tmp_path):
    """The facade and ``bnptrack track`` run the same tracker on the same frames."""
    from click.testing import CliRunner

    from bnptrack.pipeline.cli import main

    log = tmp_path / "s3.mcap"
    res = CliRunner().invoke(main, ["simulate", "--scenario", "vo2017", "--seed", "3", "--out", str(log)])
    assert res.exit_code == 0, res.output
    out = tmp_path / "tracks.mcap"
    res = CliRunner().invoke(main, ["track", str(log), "--tracker", "ddp", "--seed", "2", "--out", str(out), "-q"])
    assert res.exit_code == 0, res.output
    cli_tracks = bnptrack.read_log(out).tracks
    api = bnptrack.track(log, tracker="ddp", seed=2)
    assert len(api.estimates) == len(cli_tracks) == 100
    for a, b in zip(api.estimates, cli_tracks):
        assert [t.label for t in a.tracks] == [t.label for t in b.tracks]
        np.testing.assert_allclose([t.state for t in a.tracks], [t.state for t in b.tracks], rtol=0, atol=1e-9)


def test_mistakes_raise_one_line_config_errors():
    with pytest.raises(ValueError, match="ddpp"):
        bnptrack.make_tracker("ddpp")
    with pytest.raises(ValueError, match="p_detec"):
        bnptrack.load_params("vo2017", ["p_detec=0.9"])
    with pytest.raises(ValueError, match="scenario= is for a list of frames"):
        bnptrack.track("some.mcap", scenario="vo2017")
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        bnptrack.nope  # noqa: B018


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_importing_bnptrack_imports_no_library():
    """``import bnptrack`` (which the CLI's entry point also runs) loads none of the packages."""
    code = "import sys, bnptrack; print(sorted(m for m in sys.modules if m.startswith(('bnptrack.', 'numpy'))))"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout
    assert out.strip() == "[]"
