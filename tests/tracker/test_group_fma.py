"""tracker/bnp/group_fma.py: the fused multiply-add products of the partition kernel equal the
BLAS calls they replaced (numba's ``np.dot`` / ``@`` on 2x2 matrices and 2-vectors, and
numpy's), bit for bit, on a million random products of mixed magnitudes and on every
combination of special values (signed zeros, subnormals, huge, infinite, NaN)."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bnptrack.tracker._numerics import JIT, jit
from bnptrack.tracker.bnp.group_fma import dot2, exact_fma, gemv2, sum2

ROOT = Path(__file__).resolve().parents[2]


def _blas_products(A, X, Y, out_g, out_d) -> None:  # pragma: no cover - compiled
    """What the kernel computed before: numba's BLAS calls."""
    o = np.empty(2)
    for k in range(A.shape[0]):
        np.dot(A[k], X[k], o)
        out_g[k, 0], out_g[k, 1] = o[0], o[1]
        out_d[k] = X[k] @ Y[k]


def _fma_products(A, X, Y, out_g, out_d) -> None:  # pragma: no cover - compiled
    for k in range(A.shape[0]):
        gemv2(A[k], X[k], out_g[k])
        out_d[k] = dot2(X[k], Y[k])


_blas_products = jit(_blas_products)
_fma_products = jit(_fma_products)


def _bits_equal(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Same bits, or both NaN (a NaN's payload is not compared)."""
    return (a.view(np.int64) == b.view(np.int64)) | (np.isnan(a) & np.isnan(b))


def _both(A, X, Y):
    n = A.shape[0]
    g1, d1, g2, d2 = np.empty((n, 2)), np.empty(n), np.empty((n, 2)), np.empty(n)
    with np.errstate(all="ignore"):
        _blas_products(A, X, Y, g1, d1)
        _fma_products(A, X, Y, g2, d2)
    return g1, d1, g2, d2


@pytest.mark.skipif(not JIT, reason="compares numba's BLAS calls with the compiled formula")
def test_fma_products_equal_blas_on_a_million_random_products() -> None:
    rng = np.random.default_rng(20261202)
    n = 1_000_000
    A, X, Y = rng.normal(size=(n, 2, 2)), rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    half = n // 2  # the second half spans 17 decades, so that products of mixed size add up
    A[half:] *= np.exp(rng.uniform(-20, 20, size=(n - half, 2, 2)))
    X[half:] *= np.exp(rng.uniform(-20, 20, size=(n - half, 2)))
    Y[half:] *= np.exp(rng.uniform(-20, 20, size=(n - half, 2)))
    g1, d1, g2, d2 = _both(A, X, Y)
    assert _bits_equal(g1, g2).all() and _bits_equal(d1, d2).all()
    # not vacuous: the unfused formula differs in the last bit on a good share of them
    plain = A[:, 0, 0] * X[:, 0] + A[:, 0, 1] * X[:, 1]
    assert (plain != g1[:, 0]).mean() > 0.05
    # numpy's own BLAS rounds the same way (its gemv and dot on a sample)
    for k in range(0, n, 50_000):
        assert _bits_equal(np.dot(A[k], X[k]), g1[k]).all() and _bits_equal(np.float64(X[k] @ Y[k]), d1[k])


@pytest.mark.skipif(not JIT, reason="compares numba's BLAS calls with the compiled formula")
def test_fma_products_equal_blas_on_special_values() -> None:
    special = np.array([0.0, -0.0, 1.0, -1.0, 2.0, np.inf, -np.inf, np.nan, 1e308, -1e308, 5e-324, -5e-324])
    rng = np.random.default_rng(7)
    n = 200_000
    A, X, Y = rng.choice(special, (n, 2, 2)), rng.choice(special, (n, 2)), rng.choice(special, (n, 2))
    g1, d1, g2, d2 = _both(A, X, Y)
    assert _bits_equal(g1, g2).all() and _bits_equal(d1, d2).all()
    # the signed zeros are hit: BLAS gives +0.0 for -0.0 * 1 + -0.0 * 1 (gemv) ...
    A0, X0 = np.array([[[-0.0, -0.0], [1.0, 1.0]]]), np.array([[1.0, 1.0]])
    g1, d1, _, _ = _both(A0, X0, X0)
    assert math.copysign(1.0, g1[0, 0]) == 1.0
    # ... and keeps an underflowing negative dot product's sign
    _, d1, _, d2 = _both(A0, np.array([[-5e-324, -5e-324]]), np.array([[5e-324, 5e-324]]))
    assert math.copysign(1.0, d1[0]) == -1.0 and math.copysign(1.0, d2[0]) == -1.0


@pytest.mark.parametrize("a,b,c,want", [
    (0.1, 10.0, -1.0, 5.551115123125783e-17),  # 0.1 * 10 - 1 exactly: 2^-54 (the plain formula gives 0)
    (1.0 + 2.0**-52, 1.0 - 2.0**-53, -1.0, 2.0**-53 - 2.0**-105),
    (-0.0, 1.0, -0.0, -0.0), (0.0, -1.0, 0.0, 0.0), (1.0, -1.0, 1.0, 0.0),
    (-5e-324, 5e-324, 0.0, -0.0), (1e308, 10.0, 0.0, math.inf), (math.inf, 0.0, 1.0, math.nan),
])
def test_exact_fma_hand_values(a: float, b: float, c: float, want: float) -> None:
    got = exact_fma(a, b, c)
    if math.isnan(want):
        assert math.isnan(got)
    else:
        assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want)


def test_the_formula_in_exact_arithmetic_equals_numpys_blas() -> None:
    """What the interpreted path (``BNPTRACK_NO_JIT=1``) computes, :func:`exact_fma` in the
    same formula, against numpy's BLAS on random products."""
    rng = np.random.default_rng(3)
    for _ in range(2000):
        A, x, y = rng.normal(size=(2, 2)), rng.normal(size=2), rng.normal(size=2)
        ref = [exact_fma(A[i, 0], x[0], A[i, 1] * x[1]) + 0.0 for i in range(2)]
        assert np.array_equal(np.array(ref), np.dot(A, x))
        assert exact_fma(x[1], y[1], exact_fma(x[0], y[0], 0.0)) == x @ y


def test_interpreted_kernel_runs_the_same_formula() -> None:
    """Without numba the helpers are plain functions calling :func:`exact_fma`."""
    code = ("import numpy as np\n"
            "from bnptrack.tracker.bnp.group_fma import dot2, fma, gemv2, exact_fma\n"
            "assert fma is exact_fma\n"
            "A, x, out = np.array([[0.1, 0.7], [-0.3, 1e-9]]), np.array([10.0, 1.0 / 3.0]), np.empty(2)\n"
            "gemv2(A, x, out)\n"
            "print(out.tolist(), dot2(x, A[0]))\n")
    env = {**os.environ, "BNPTRACK_NO_JIT": "1", "PYTHONPATH": str(ROOT)}
    got = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True).stdout
    A, x = np.array([[0.1, 0.7], [-0.3, 1e-9]]), np.array([10.0, 1.0 / 3.0])
    assert got.split() == str(np.dot(A, x).tolist()).split() + [repr(float(x @ A[0]))]


def _matmul_formula(A, B) -> np.ndarray:  # pragma: no cover - compiled
    """``A @ B`` for ``(Q, n, 2) @ (Q, 2, m)``, each entry :func:`sum2`."""
    Q, n, m = A.shape[0], A.shape[1], B.shape[2]
    out = np.empty((Q, n, m))
    for q in range(Q):
        for i in range(n):
            for j in range(m):
                out[q, i, j] = sum2(A[q, i, 0], B[q, 0, j], A[q, i, 1], B[q, 1, j])
    return out


_matmul_formula = jit(_matmul_formula)


@pytest.mark.skipif(not JIT, reason="compares numpy's matmul with the compiled formula")
@pytest.mark.parametrize("special", [False, True])
def test_sum2_equals_numpys_stacked_matmul(special: bool) -> None:
    """share_velocity's gains: ``K = PHt @ Si`` (a fancy-indexed copy times a contiguous stack)
    and ``K @ swapaxes(PHt)`` (a transposed view), as numpy computes them."""
    rng = np.random.default_rng(11)
    Q = 200_000
    if special:
        values = np.array([0.0, -0.0, 1.0, -1.0, 2.0, np.inf, -np.inf, np.nan, 1e308, -1e308, 5e-324, -5e-324])
        P, Si, K = rng.choice(values, (Q, 5, 5)), rng.choice(values, (Q, 2, 2)), rng.choice(values, (Q, 5, 2))
    else:
        P = rng.normal(size=(Q, 5, 5)) * np.exp(rng.uniform(-8, 8, (Q, 5, 5)))
        Si = rng.normal(size=(Q, 2, 2)) * np.exp(rng.uniform(-8, 8, (Q, 2, 2)))
        K = rng.normal(size=(Q, 5, 2))
    PHt = P[:, :, [1, 3]]
    with np.errstate(all="ignore"):
        assert _bits_equal(PHt @ Si, _matmul_formula(PHt, Si)).all()
        PH = np.swapaxes(PHt, 1, 2)
        assert _bits_equal(K @ PH, _matmul_formula(K, np.ascontiguousarray(PH))).all()
