"""The sink stage imports before it declares itself alive, while
the tracker starts, what its sinks' first ``open`` would import (mcap.writer and its
importlib.metadata; pyarrow.compute, numpy.ma and dateutil, which the Rerun SDK imports on its
first annotation context).  Opened between the tracker's readiness and the first frame, they
cost 0.3-0.5 s there on a loaded machine (docs/pipeline.md, "Latency").  In a fresh
interpreter: after the stage's warm-up, opening its sinks imports only the sinks' own factory
modules."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from testkit import REPO_ROOT, bnptrack_env

_SCRIPT = r"""
import json, sys
from pathlib import Path
from bnptrack.pipeline.membus import MemoryNetwork
from bnptrack.pipeline.stages import StageContext
from bnptrack.pipeline.stages.sink import SinkStage
sys.path.insert(0, sys.argv[2])
from testkit import mem_cfg

cfg = mem_cfg(Path(sys.argv[1]), frames=2, **{"sink.rerun": "true"})
stage = SinkStage(StageContext(cfg, MemoryNetwork().bus(cfg.run, "sink"), name="sink"))
stage._warm_up()
before = set(sys.modules)
stage._open(force=True, meta_if_unknown={"run": cfg.run})
new = sorted(set(sys.modules) - before)
stage.sinks.close()
print(json.dumps({"files": [Path(f).name for f in stage.files], "new": new}))
"""


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_after_the_warm_up_opening_the_sinks_imports_only_their_factories(tmp_path):
    out = subprocess.run([sys.executable, "-c", _SCRIPT, str(tmp_path), str(REPO_ROOT / "tests")],
                         env=bnptrack_env(), cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["files"] == ["tracks.mcap", "run.rrd"]  # both sinks were built and opened
    # without the warm-up: mcap.writer, importlib.metadata, pyarrow.compute, numpy.ma, ... here
    assert [m for m in doc["new"] if not m.startswith("bnptrack.sinks.")] == [], doc["new"]
