"""The scorer's distance matrix (``sinks.metrics._euclidean``) is scipy's ``cdist``, bit for
bit, and its assignment (``sinks.metric_checks.optimal_assignment``) is scipy's own
``linear_sum_assignment``, loaded without importing ``scipy.optimize``
(``tracker.numerics.scipy_extension``; docs/performance.md, start-up)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.distance import cdist

from bnptrack.sinks import metrics
from testkit import REPO_ROOT


@pytest.mark.parametrize("dim", [1, 2, 3, 4, 8, 9, 17])
def test_euclidean_is_cdist_bit_for_bit(dim: int) -> None:
    rng = np.random.default_rng(dim)
    for _ in range(60):
        m, n = rng.integers(0, 25, 2)
        scale = 10.0 ** rng.uniform(-3, 5)
        X = rng.normal(size=(m, dim)) * scale
        Y = rng.normal(size=(n, dim)) * scale + rng.normal() * scale
        a, b = metrics._euclidean(X, Y), cdist(X, Y)
        assert a.shape == b.shape and np.array_equal(a.view(np.int64), b.view(np.int64))


def test_euclidean_hand_checked() -> None:
    d = metrics._euclidean(np.array([[0.0, 0.0], [3.0, 4.0]]), np.array([[3.0, 0.0]]))
    assert d.tolist() == [[3.0], [4.0]]


_PROBE = """
import json, sys
import numpy as np
from bnptrack.sinks.metric_checks import optimal_assignment
from bnptrack.sinks.metrics import ospa
cost = np.array([[4.0, 1.0, 3.0], [2.0, 0.0, 5.0]])
pairs = [a.tolist() for a in optimal_assignment(cost)] + [a.tolist() for a in optimal_assignment(cost.T)]
total = ospa(np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([[0.0, 1.0]]), c=100.0, p=1.0).total
before = "scipy.optimize" in sys.modules
import scipy.optimize
import scipy.optimize._lsap as lsap
print(json.dumps([pairs, total, before, scipy.optimize.linear_sum_assignment is lsap.linear_sum_assignment,
                  scipy.optimize._lsap is sys.modules["scipy.optimize._lsap"]]))
"""


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
def test_assignment_is_scipys_solver_without_scipy_optimize() -> None:
    """Rows 0, 1 -> columns 1, 0 (total 3) and the transpose's pairs listed by row; OSPA of
    {(0,0), (10,0)} against {(0,1)}: (1 + 100) / 2 = 50.5.  scipy.optimize is not imported
    until asked for, and then is whole and holds the same solver."""
    env = dict(os.environ, PYTHONPATH=str(REPO_ROOT))
    out = subprocess.run([sys.executable, "-c", _PROBE], cwd=REPO_ROOT, env=env, capture_output=True, text=True,
                         timeout=120, check=True).stdout
    pairs, total, before, same, bound = json.loads(out.strip().splitlines()[-1])
    assert pairs == [[0, 1], [1, 0], [0, 1], [1, 0]]
    assert total == 50.5 and before is False and same and bound
