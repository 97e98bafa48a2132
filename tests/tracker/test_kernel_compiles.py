"""What a first run (an empty kernel cache) compiles: each kernel once, and none of numba's string
code (docs/performance.md, cold start).

numba compiles a kernel a kernel calls once per distinct argument type, and a constant argument
or a counter that starts at a constant is typed ``Literal[int](0)`` first: a whole extra
compilation that the run never calls.  An array assigned into a slice of another one
(``a[i] = b``) compiles numba's shape-mismatch message, and with it ``str``, ``repr`` and
string joining, about a tenth of the first run's compile time.  The kernels avoid both; this
checks it in a fresh process with an empty cache (loaded kernels would not show it)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

#: compile machinery: fresh interpreters compiling and loading kernels (docs/testing.md, markers)
pytestmark = pytest.mark.slow

from bnptrack.tracker import numerics
from tests.testkit import REPO_ROOT, bnptrack_env

_PROBE = textwrap.dedent("""
    import json
    import numpy as np
    from numba.core import event
    from bnptrack.tracker.bnp import _kernels, gibbs, gibbs_setup, group_theta, swap_moves

    compiled = []

    class Listener(event.Listener):
        def on_start(self, ev):
            pass

        def on_end(self, ev):
            py = getattr((ev.data or {}).get("dispatcher"), "py_func", None)
            compiled.append(f"{py.__module__}.{py.__qualname__}" if py is not None else "?")

    event.register("numba:compile", Listener())
    rng = np.random.default_rng(0)
    N, M = 4, 5
    dense = np.where(rng.random((N, M)) < 0.7, rng.normal(-3.0, 1.0, (N, M)), -np.inf)
    prob = gibbs.GibbsProblem(log_first=dense + 0.5, log_lik=dense, log_clutter=rng.normal(-2, 1, M),
                              log_new=rng.normal(-4, 1, M), popularity=np.ones(N), alpha=0.5, d=0.1,
                              d_bar=2.0, mass=3.0)
    gibbs.run_gibbs(prob, np.random.default_rng(1), 30, 5, chains=2)
    z, ids = np.array([0, 2, 0, 1]), np.arange(3)
    v, R = rng.normal(size=(4, 2)), np.tile(np.eye(2), (4, 1, 1))
    g_ids, count, *moments = group_theta._transition_kernel(z, ids, v, R, np.eye(2), np.zeros(2), v, R, np.eye(2),
                                                            np.zeros(2), 1)
    kernels = {"_greedy": gibbs_setup._greedy, "exchange_pairs": swap_moves.exchange_pairs, "np_sum": _kernels.np_sum,
               "_pairwise_block": _kernels._pairwise_block, "theta_sums": group_theta.theta_sums}
    print(json.dumps({"compiled": compiled, "signatures": {k: [str(s) for s in f.signatures]
                                                           for k, f in kernels.items()},
                      "count": count.tolist()}))
""")


@pytest.fixture(scope="module")
def cold_run(tmp_path_factory) -> dict:
    if not numerics.JIT:
        pytest.fail("numba is a core dependency: the kernels must compile here")
    env = bnptrack_env({"NUMBA_CACHE_DIR": str(tmp_path_factory.mktemp("numba"))})
    out = subprocess.run([sys.executable, "-c", _PROBE], cwd=REPO_ROOT, env=env, capture_output=True, text=True,
                         timeout=900)
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_each_called_kernel_compiles_once_without_literal_arguments(cold_run):
    sigs = cold_run["signatures"]
    assert {k: len(v) for k, v in sigs.items()} == {"_greedy": 1, "exchange_pairs": 1, "np_sum": 1,
                                                    "_pairwise_block": 1, "theta_sums": 1}
    assert not [s for v in sigs.values() for s in v if "Literal" in s]
    assert "int64, int64" in sigs["np_sum"][0]  # (array, lo, n): both counts plain int64
    assert cold_run["count"] == [2.0, 1.0, 1.0]  # the kernels ran: members of tables 0, 1, 2


def test_no_string_code_is_compiled(cold_run):
    compiled = cold_run["compiled"]
    assert "bnptrack.tracker.bnp.gibbs_setup._setup_kernel" in compiled  # the listener saw the kernels
    assert [c for c in compiled if "unicode" in c or "raise_with_shape_context" in c or ".ol_str" in c] == []
