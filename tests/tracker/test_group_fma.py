"""tracker/bnp/group_fma.py: the fused multiply-add products of the partition kernel are their
formula in exact arithmetic, bit for bit, on every CPU (random products of mixed magnitudes and
every combination of special values: signed zeros, subnormals, huge, infinite, NaN), and the
BLAS calls they replaced (numba's ``np.dot`` / ``@`` on 2x2 matrices and 2-vectors, numpy's)
agree within a two-term dot product's error bound.  Bit for bit against BLAS holds with
OpenBLAS's Haswell kernels and not with an AMD EPYC's (its ``ddot`` rounds otherwise), so no
test depends on the CPU's BLAS kernels."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from bnptrack.tracker.numerics import JIT, jit
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


U = 2.0**-53  # unit round-off
TINY = 2.0**-1074  # the smallest subnormal: underflow's absolute slack


def _formula(A, X, Y):
    """The formula in exact arithmetic (:func:`exact_fma`), element by element: what the
    compiled products must equal on every CPU."""
    n = A.shape[0]
    g, d = np.empty((n, 2)), np.empty(n)
    for k in range(n):
        for i in range(2):
            g[k, i] = exact_fma(A[k, i, 0], X[k, 0], A[k, i, 1] * X[k, 1]) + 0.0
        d[k] = exact_fma(X[k, 1], Y[k, 1], exact_fma(X[k, 0], Y[k, 0], 0.0))
    return g, d


def _within_dot_bound(got, ref, a0b0, a1b1) -> np.ndarray:
    """Both are two-term dot products rounded by some correct summation: each is within
    gamma_2 (|a0 b0| + |a1 b1|) of the exact value, so they differ by at most twice that."""
    return np.abs(got - ref) <= 4.0 * U * (np.abs(a0b0) + np.abs(a1b1)) * (1 + 4 * U) + 4 * TINY


def _mixed(rng, n):
    A, X, Y = rng.normal(size=(n, 2, 2)), rng.normal(size=(n, 2)), rng.normal(size=(n, 2))
    half = n // 2  # the second half spans 17 decades, so that products of mixed size add up
    A[half:] *= np.exp(rng.uniform(-20, 20, size=(n - half, 2, 2)))
    X[half:] *= np.exp(rng.uniform(-20, 20, size=(n - half, 2)))
    Y[half:] *= np.exp(rng.uniform(-20, 20, size=(n - half, 2)))
    return A, X, Y


@pytest.mark.skipif(not JIT, reason="compares the compiled products")
def test_fma_products_equal_the_exact_formula_and_blas_within_its_error_bound() -> None:
    """The compiled :func:`gemv2` / :func:`dot2` are the formula, bit for bit, on every CPU.
    BLAS rounds the same two-term sums in a CPU-dependent way (an Intel CPU with
    OpenBLAS's Haswell kernels: the same bits; an AMD EPYC: ``ddot`` differs in the last bits), so against BLAS only the dot product's error bound holds."""
    A, X, Y = _mixed(np.random.default_rng(20261202), 200_000)
    g1, d1, g2, d2 = _both(A, X, Y)
    sample = np.r_[0:3_000, 100_000:103_000]  # the exact formula, element by element in Python
    rg, rd = _formula(A[sample], X[sample], Y[sample])
    assert _bits_equal(g2[sample], rg).all() and _bits_equal(d2[sample], rd).all()
    with np.errstate(all="ignore"):
        for i in range(2):
            assert _within_dot_bound(g1[:, i], g2[:, i], A[:, i, 0] * X[:, 0], A[:, i, 1] * X[:, 1]).all()
        assert _within_dot_bound(d1, d2, X[:, 0] * Y[:, 0], X[:, 1] * Y[:, 1]).all()
    # numpy's own BLAS calls agree with numba's (the same library)
    for k in range(0, 200_000, 10_000):
        assert _bits_equal(np.dot(A[k], X[k]), g1[k]).all() and _bits_equal(np.float64(X[k] @ Y[k]), d1[k])


@pytest.mark.skipif(not JIT, reason="compares the compiled products")
def test_fma_products_equal_the_exact_formula_on_special_values() -> None:
    special = np.array([0.0, -0.0, 1.0, -1.0, 2.0, np.inf, -np.inf, np.nan, 1e308, -1e308, 5e-324, -5e-324])
    rng = np.random.default_rng(7)
    n = 20_000
    A, X, Y = rng.choice(special, (n, 2, 2)), rng.choice(special, (n, 2)), rng.choice(special, (n, 2))
    _, _, g2, d2 = _both(A, X, Y)
    with np.errstate(all="ignore"):
        rg, rd = _formula(A, X, Y)
    assert _bits_equal(g2, rg).all() and _bits_equal(d2, rd).all()
    # the signed zeros: +0.0 for -0.0 * 1 + -0.0 * 1 (gemv, as BLAS's accumulator gives) ...
    A0, X0 = np.array([[[-0.0, -0.0], [1.0, 1.0]]]), np.array([[1.0, 1.0]])
    _, _, g2, _ = _both(A0, X0, X0)
    assert math.copysign(1.0, g2[0, 0]) == 1.0
    # ... and an underflowing negative dot product keeps its sign
    _, _, _, d2 = _both(A0, np.array([[-5e-324, -5e-324]]), np.array([[5e-324, 5e-324]]))
    assert math.copysign(1.0, d2[0]) == -1.0


@pytest.mark.parametrize("a,b,c,want", [
    (0.1, 10.0, -1.0, 5.551115123125783e-17),  # 0.1 * 10 - 1 exactly: 2^-54 (the plain formula gives 0)
    (1.0 + 2.0**-52, 1.0 - 2.0**-53, -1.0, 2.0**-53 - 2.0**-105),
    (-0.0, 1.0, -0.0, -0.0), (0.0, -1.0, 0.0, 0.0), (1.0, -1.0, 1.0, 0.0),
    (-5e-324, 5e-324, 0.0, -0.0), (1e308, 10.0, 0.0, math.inf), (math.inf, 0.0, 1.0, math.nan),
    # an exact product beyond the largest double plus an infinity: no overflow first (was nan)
    (2.0, -1e308, math.inf, math.inf), (1e308, 10.0, -math.inf, -math.inf), (1.0, 1.0, math.nan, math.nan),
])
def test_exact_fma_hand_values(a: float, b: float, c: float, want: float) -> None:
    got = exact_fma(a, b, c)
    if math.isnan(want):
        assert math.isnan(got)
    else:
        assert got == want and math.copysign(1.0, got) == math.copysign(1.0, want)


def test_the_formula_in_exact_arithmetic_is_within_blas_error_bound() -> None:
    """What the interpreted path (``BNPTRACK_NO_JIT=1``) computes, :func:`exact_fma` in the
    same formula, against numpy's BLAS on random products: within the two-term dot product's
    error bound (bit for bit where the BLAS rounds this way, e.g. OpenBLAS's Haswell kernels)."""
    rng = np.random.default_rng(3)
    for _ in range(2000):
        A, x, y = rng.normal(size=(2, 2)), rng.normal(size=2), rng.normal(size=2)
        ref = np.array([exact_fma(A[i, 0], x[0], A[i, 1] * x[1]) + 0.0 for i in range(2)])
        assert _within_dot_bound(ref, np.dot(A, x), A[:, 0] * x[0], A[:, 1] * x[1]).all()
        d = exact_fma(x[1], y[1], exact_fma(x[0], y[0], 0.0))
        assert _within_dot_bound(d, x @ y, x[0] * y[0], x[1] * y[1])


@pytest.mark.slow  # a fresh interpreter: start-up and import machinery
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
    want = [exact_fma(A[i, 0], x[0], A[i, 1] * x[1]) + 0.0 for i in range(2)]
    assert got.split() == str(want).split() + [repr(exact_fma(x[1], A[0, 1], exact_fma(x[0], A[0, 0], 0.0)))]


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


def _matmul_exact(A, B) -> np.ndarray:
    """``A @ B`` entry by entry in :func:`sum2`'s formula, exact arithmetic."""
    Q, n, m = A.shape[0], A.shape[1], B.shape[2]
    out = np.empty((Q, n, m))
    for q in range(Q):
        for i in range(n):
            for j in range(m):
                out[q, i, j] = exact_fma(A[q, i, 1], B[q, 1, j], exact_fma(A[q, i, 0], B[q, 0, j], 0.0))
    return out


@pytest.mark.skipif(not JIT, reason="compares numpy's matmul with the compiled formula")
@pytest.mark.parametrize("special", [False, True])
def test_sum2_is_the_formula_and_numpys_stacked_matmul_within_its_bound(special: bool) -> None:
    """share_velocity's gains: ``K = PHt @ Si`` (a fancy-indexed copy times a contiguous stack)
    and ``K @ swapaxes(PHt)`` (a transposed view): the compiled :func:`sum2` is the formula bit
    for bit; numpy's ``matmul`` (BLAS, CPU-dependent rounding) is within the dot product's error
    bound on finite values."""
    rng = np.random.default_rng(11)
    Q = 20_000 if not special else 4_000
    if special:
        values = np.array([0.0, -0.0, 1.0, -1.0, 2.0, np.inf, -np.inf, np.nan, 1e308, -1e308, 5e-324, -5e-324])
        P, Si, K = rng.choice(values, (Q, 5, 5)), rng.choice(values, (Q, 2, 2)), rng.choice(values, (Q, 5, 2))
    else:
        P = rng.normal(size=(Q, 5, 5)) * np.exp(rng.uniform(-8, 8, (Q, 5, 5)))
        Si = rng.normal(size=(Q, 2, 2)) * np.exp(rng.uniform(-8, 8, (Q, 2, 2)))
        K = rng.normal(size=(Q, 5, 2))
    PHt = P[:, :, [1, 3]]
    PH = np.ascontiguousarray(np.swapaxes(PHt, 1, 2))
    with np.errstate(all="ignore"):
        for A, B in ((PHt, Si), (K, PH)):
            got = _matmul_formula(A, B)
            part = slice(0, 300)  # the exact product, element by element in Python
            assert _bits_equal(got[part], _matmul_exact(A[part], B[part])).all()
            if not special:
                t0 = A[:, :, 0, None] * B[:, None, 0, :]
                t1 = A[:, :, 1, None] * B[:, None, 1, :]
                assert _within_dot_bound(A @ B, got, t0, t1).all()
