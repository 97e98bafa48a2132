r"""Compiled unscented-filter kernels for the models the trackers use (numba, ``cache=True``).

The reference is the numpy code of :mod:`tracker.filtering` (``ukf_predict``,
``ukf_innovation``, ``log_likelihood_matrix``, ``gated_log_likelihood``); these kernels do the
same arithmetic, track by track, without the ~40 small numpy calls per batch that dominate on
vo2017-sized frames (10-100 tracks).  They agree with the reference to rounding (the sums run in
another order than BLAS's, LAPACK's Cholesky and ``inv``): tests/tracker/test_filtering_kernels.py.

Three general kernels (not one per model and kind, to keep numba's first compile short):

* :func:`ct_ukf_predict`: sigma points of each :math:`(m, P)` through the coordinated-turn
  transition (:class:`~tracker.models.motion.CoordinatedTurn`), weighted mean and covariance plus
  :math:`Q`;
* :func:`ukf_innovation_kernel`: sigma points through :math:`h` of one of the measurement kinds
  below (code ``kind``), wrapped residuals, :math:`\hat z, S, C`, the Cholesky factor of :math:`S`,
  :math:`S^{-1}`, :math:`\log\det S`, :math:`K = C S^{-1}` and :math:`P - K S K^T`;
* :func:`loglik_dense` / :func:`loglik_gated`: Mahalanobis distances, Gaussian log-likelihoods and
  the chi-square gate of every track/measurement pair; :func:`loglik_balls` the same gate of
  large frames, evaluated only where each track's ball reaches (a grid over the measurements).

A kernel returns ``ok = False`` when a covariance it factors is not positive definite (Cholesky
pivot :math:`\le 0` or NaN); the caller then runs the numpy reference, which has the eigen-factor
fallbacks.
"""

from __future__ import annotations

import math

import numpy as np

from bnptrack.tracker.numerics import argsort_stable, jit

#: Measurement kinds of :func:`ukf_innovation_kernel` (``h`` and which residual is wrapped).
KIND_BEARING_RANGE, KIND_RANGE, KIND_XY = 0, 1, 2

_TWO_PI = 2.0 * math.pi


def _wrap(a: float) -> float:
    """:func:`~tracker.models.measurement.wrap_angle` of a scalar, to :math:`[-\\pi, \\pi)`:
    :math:`((a + \\pi) \\bmod 2\\pi) - \\pi`, bit for bit; the (slow) floating modulo only
    when :math:`a + \\pi` is outside :math:`[0, 2\\pi)`, where it is the identity."""
    t = a + math.pi
    if not (0.0 <= t < _TWO_PI):
        t = t % _TWO_PI
    return t - math.pi


_wrap = jit(_wrap, inline=True)


def _cholesky(A: np.ndarray, L: np.ndarray, n: int) -> bool:
    """Lower Cholesky factor of the SPD ``(n, n)`` ``A`` into ``L``; ``False`` when a pivot is not > 0
    (``n`` passed as a constant from the caller, so that the inlined loops unroll)."""
    for j in range(n):
        s = A[j, j]
        for k in range(j):
            s -= L[j, k] * L[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        L[j, j] = d
        for i in range(j + 1, n):
            t = A[i, j]
            for k in range(j):
                t -= L[i, k] * L[j, k]
            L[i, j] = t / d
        for i in range(j):
            L[i, j] = 0.0
    return True


_cholesky = jit(_cholesky, inline=True)


def _ct_f(X: np.ndarray, k: int, T: float, out: np.ndarray) -> None:
    """Coordinated-turn transition of state ``X[k]`` into ``out[k]`` (as :meth:`CoordinatedTurn.f`)."""
    px, vx, py, vy, w = X[k, 0], X[k, 1], X[k, 2], X[k, 3], X[k, 4]
    wT = w * T
    s, c = math.sin(wT), math.cos(wT)
    if abs(w) < 1e-10:
        a, b = T, 0.0
    else:
        a = s / w
        h = math.sin(wT / 2.0)
        b = 2.0 * h * h / w
    out[k, 0] = px + a * vx - b * vy
    out[k, 1] = c * vx - s * vy
    out[k, 2] = b * vx + py + a * vy
    out[k, 3] = s * vx + c * vy
    out[k, 4] = w


_ct_f = jit(_ct_f, inline=True)


def _sigma(m: np.ndarray, L: np.ndarray, sqrt_c: float, X: np.ndarray, n: int) -> None:
    r"""Sigma points into ``X (2n+1, n)``: :math:`m`, :math:`m \pm \sqrt c\, L_{:,i}`."""
    for j in range(n):
        X[0, j] = m[j]
    for col in range(n):
        for j in range(n):
            d = sqrt_c * L[j, col]
            X[1 + col, j] = m[j] + d
            X[1 + n + col, j] = m[j] - d


_sigma = jit(_sigma, inline=True)


def _wcov(A: np.ndarray, WA: np.ndarray, B: np.ndarray, WB: np.ndarray, a: int, b: int, K: int) -> float:
    r""":math:`\tfrac12(\sum_k (W_k A_{ka}) B_{kb} + \sum_k (W_k B_{kb}) A_{ka})` with
    ``WA = W A``, ``WB = W B`` precomputed: entry ``(a, b)`` of numpy's
    ``sym((A * W)^T @ B)`` (for ``A is B``)."""
    sab, sba = 0.0, 0.0
    for k in range(K):
        sab += WA[k, a] * B[k, b]
        sba += WB[k, b] * A[k, a]
    return 0.5 * (sab + sba)


_wcov = jit(_wcov, inline=True)


def ct_ukf_predict(m: np.ndarray, P: np.ndarray, T: float, Wm: np.ndarray, Wc: np.ndarray,
                   sqrt_c: float, Q: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Unscented prediction of ``(N, 5)`` means, ``(N, 5, 5)`` covariances through the CT model
    of period ``T`` (the reference: :func:`tracker.filtering.ukf_predict`)."""
    N = m.shape[0]
    n = 5
    K = 2 * n + 1
    m_out = np.empty((N, n))
    P_out = np.empty((N, n, n))
    L = np.zeros((n, n))
    X, Y = np.empty((K, n)), np.empty((K, n))
    dY, WdY = np.empty((K, n)), np.empty((K, n))
    for i in range(N):
        if not _cholesky(P[i], L, n):
            return m_out, P_out, False
        _sigma(m[i], L, sqrt_c, X, n)
        for k in range(K):
            _ct_f(X, k, T, Y)
        for j in range(n):
            acc = 0.0
            for k in range(K):
                acc += Wm[k] * Y[k, j]
            m_out[i, j] = acc
        for k in range(K):
            for j in range(n):
                dY[k, j] = Y[k, j] - m_out[i, j]
                WdY[k, j] = dY[k, j] * Wc[k]
        for a in range(n):
            for b in range(a, n):
                v = _wcov(dY, WdY, dY, WdY, a, b, K)
                P_out[i, a, b] = v + Q[a, b]
                P_out[i, b, a] = v + Q[b, a]
    return m_out, P_out, True


ct_ukf_predict = jit(ct_ukf_predict)


def _h(X: np.ndarray, k: int, kind: int, sx: float, sy: float, heading: float, out: np.ndarray) -> None:
    """Noise-free measurement of state ``X[k]`` into ``out[k]`` for ``kind`` (as the models' ``h``)."""
    if kind == KIND_XY:
        out[k, 0] = X[k, 0]
        out[k, 1] = X[k, 2]
        return
    dx = X[k, 0] - sx
    dy = X[k, 2] - sy
    r = math.hypot(dx, dy)
    if kind == KIND_RANGE:
        out[k, 0] = r
        out[k, 1] = 0.0  # the padding component (see ukf_innovation_kernel)
        return
    phi = math.atan2(dx, dy)
    if heading != 0.0:
        phi = _wrap(phi - heading)
    out[k, 0] = phi
    out[k, 1] = r


_h = jit(_h, inline=True)


def _inv_logdet(S: np.ndarray, L: np.ndarray, Linv: np.ndarray, S_inv: np.ndarray, d: int) -> float:
    r""":math:`S^{-1} = L^{-T} L^{-1}` (symmetrised) into ``S_inv`` and :math:`\log\det S`, from
    the Cholesky factor ``L`` of ``S`` (already computed)."""
    for j in range(d):  # forward substitution: L Linv = I
        for i in range(d):
            if i < j:
                Linv[i, j] = 0.0
                continue
            t = 1.0 if i == j else 0.0
            for k in range(j, i):
                t -= L[i, k] * Linv[k, j]
            Linv[i, j] = t / L[i, i]
    log_det = 0.0
    for j in range(d):
        log_det += math.log(L[j, j])
    for a in range(d):
        for b in range(a, d):
            sab = 0.0
            for k in range(d):
                sab += Linv[k, a] * Linv[k, b]
            S_inv[a, b] = sab
            S_inv[b, a] = sab
    return 2.0 * log_det


_inv_logdet = jit(_inv_logdet, inline=True)


def _zpred(Zs: np.ndarray, z0: np.ndarray, Wm: np.ndarray, wrap0: bool, out: np.ndarray, K: int, d: int) -> None:
    r""":math:`\hat z = \operatorname{wrap}(z_0 + \sum_k W_k r(\mathcal Z_k, z_0))` into ``out``."""
    for j in range(d):
        acc = 0.0
        for k in range(K):
            r = Zs[k, j] - z0[j]
            if wrap0 and j == 0:
                r = _wrap(r)
            acc += Wm[k] * r
        v = z0[j] + acc
        out[j] = _wrap(v) if wrap0 and j == 0 else v


_zpred = jit(_zpred, inline=True)


def _moments(Zs, X, z_pred, m, Wc, wrap0, R, dZ, dX, S, C, K, n, d) -> None:
    r""":math:`S = \operatorname{sym}(\sum_k W_k\, r_k r_k^T + R)`,
    :math:`C = \sum_k W_k (\mathcal X_k - m) r_k^T`, :math:`r_k = r(\mathcal Z_k, \hat z)`."""
    for k in range(K):
        for j in range(d):
            r = Zs[k, j] - z_pred[j]
            dZ[k, j] = _wrap(r) if wrap0 and j == 0 else r
        for j in range(n):
            dX[k, j] = X[k, j] - m[j]
    for a in range(d):
        for b in range(a, d):
            sab, sba = 0.0, 0.0
            for k in range(K):
                sab += dZ[k, a] * Wc[k] * dZ[k, b]
                sba += dZ[k, b] * Wc[k] * dZ[k, a]
            v = 0.5 * ((sab + R[a, b]) + (sba + R[b, a]))
            S[a, b] = v
            S[b, a] = v
    for a in range(n):
        for b in range(d):
            acc = 0.0
            for k in range(K):
                acc += dX[k, a] * Wc[k] * dZ[k, b]
            C[a, b] = acc


_moments = jit(_moments, inline=True)


def _matmul_nd(A: np.ndarray, B: np.ndarray, out: np.ndarray, n: int, d: int) -> None:
    """``out[:n, :d] = A[:n, :d] @ B[:d, :d]`` (summed in ``k`` order)."""
    for a in range(n):
        for b in range(d):
            acc = 0.0
            for k in range(d):
                acc += A[a, k] * B[k, b]
            out[a, b] = acc


_matmul_nd = jit(_matmul_nd, inline=True)


def _gain_update(P: np.ndarray, S: np.ndarray, S_inv: np.ndarray, C: np.ndarray, K: np.ndarray,
                 KS: np.ndarray, P_upd: np.ndarray, n: int, d: int) -> None:
    r""":math:`K = C S^{-1}` and :math:`P^+ = \operatorname{sym}(P - (K S) K^T)`."""
    _matmul_nd(C, S_inv, K, n, d)
    _matmul_nd(K, S, KS, n, d)
    for a in range(n):
        for b in range(a, n):
            kab, kba = 0.0, 0.0
            for k in range(d):
                kab += KS[a, k] * K[b, k]
                kba += KS[b, k] * K[a, k]
            v = 0.5 * ((P[a, b] - kab) + (P[b, a] - kba))
            P_upd[a, b] = v
            P_upd[b, a] = v


_gain_update = jit(_gain_update, inline=True)


def ukf_innovation_kernel(m: np.ndarray, P: np.ndarray, Wm: np.ndarray, Wc: np.ndarray, sqrt_c: float,
                          kind: int, sx: float, sy: float, heading: float, R: np.ndarray):
    """Unscented innovation of ``N`` predicted Gaussians ``(N, 5)`` for measurement ``kind``
    (sensor at ``(sx, sy)``, ``heading``; noise ``R (2, 2)``).  Returns ``z_pred (N, 2)``,
    ``S``, ``S_inv (N, 2, 2)``, ``log_det_S (N,)``, ``gain (N, 5, 2)``, ``P_upd (N, 5, 5)``,
    ``cross_cov (N, 5, 2)`` and ``ok`` (the reference: :func:`tracker.filtering.ukf_innovation`).

    The dimensions are constants (the loops unroll: 1.5x faster than with run-time sizes).  A
    range (``d = 1``) runs padded: a second component with :math:`h = 0` and ``R[1, 1] = 1``
    (``R[0, 1] = 0``), which leaves :math:`S` block-diagonal, :math:`C_{:,1} = 0`, and every
    quantity of the first component the same, value for value (the padding only adds zeros);
    the caller keeps the first component."""
    N = m.shape[0]
    n, d = 5, 2
    Kp = 2 * n + 1
    wrap0 = kind == KIND_BEARING_RANGE
    z_pred, S, S_inv = np.empty((N, d)), np.empty((N, d, d)), np.empty((N, d, d))
    log_det, gain, P_upd = np.empty(N), np.empty((N, n, d)), np.empty((N, n, n))
    C = np.empty((N, n, d))
    L, Ls, Linv = np.zeros((n, n)), np.zeros((d, d)), np.zeros((d, d))
    X, Zs, z0 = np.empty((Kp, n)), np.empty((Kp, d)), np.empty((N, d))
    dZ, dX, KS = np.empty((Kp, d)), np.empty((Kp, n)), np.empty((n, d))
    for i in range(N):
        if not _cholesky(P[i], L, n):
            return z_pred, S, S_inv, log_det, gain, P_upd, C, False
        _sigma(m[i], L, sqrt_c, X, n)
        for k in range(Kp):
            _h(X, k, kind, sx, sy, heading, Zs)
        _h(m, i, kind, sx, sy, heading, z0)
        _zpred(Zs, z0[i], Wm, wrap0, z_pred[i], Kp, d)
        _moments(Zs, X, z_pred[i], m[i], Wc, wrap0, R, dZ, dX, S[i], C[i], Kp, n, d)
        if not _cholesky(S[i], Ls, d):
            return z_pred, S, S_inv, log_det, gain, P_upd, C, False
        log_det[i] = _inv_logdet(S[i], Ls, Linv, S_inv[i], d)
        _gain_update(P[i], S[i], S_inv[i], C[i], gain[i], KS, P_upd[i], n, d)
    return z_pred, S, S_inv, log_det, gain, P_upd, C, True


ukf_innovation_kernel = jit(ukf_innovation_kernel)


def _d2(Z: np.ndarray, j: int, zp: np.ndarray, S_inv: np.ndarray, n: int, wrap0: bool) -> float:
    r"""Squared Mahalanobis distance :math:`r^T S_n^{-1} r`, :math:`r = z_j \ominus \hat z_n`
    (bearing wrapped when ``wrap0``) for ``d`` = 1 or 2, summed as numpy's
    ``sum((r @ S_inv) * r)``: :math:`(r_0 s_{00} + r_1 s_{10}) r_0 + (r_0 s_{01} + r_1 s_{11}) r_1`."""
    r0 = Z[j, 0] - zp[n, 0]
    if wrap0:
        r0 = _wrap(r0)
    if Z.shape[1] == 1:
        return (r0 * S_inv[n, 0, 0]) * r0
    r1 = Z[j, 1] - zp[n, 1]
    return (r0 * S_inv[n, 0, 0] + r1 * S_inv[n, 1, 0]) * r0 + (r0 * S_inv[n, 0, 1] + r1 * S_inv[n, 1, 1]) * r1


_d2 = jit(_d2, inline=True)


def loglik_dense(z_pred: np.ndarray, S_inv: np.ndarray, log_det: np.ndarray, Z: np.ndarray, wrap0: bool,
                 g: float, log_2pi: float) -> np.ndarray:
    r"""``(N, M)`` Gaussian log-likelihoods :math:`-\frac12(d\log 2\pi + \log\det S_n + D^2_{nm})`,
    ``-inf`` where not :math:`D^2_{nm} \le g` (``g = inf``: no gate; a NaN distance is ``-inf``).
    Measurement dimension ``d`` = 1 or 2."""
    N, d = z_pred.shape
    M = Z.shape[0]
    out = np.empty((N, M))
    for n in range(N):
        c = d * log_2pi + log_det[n]
        for j in range(M):
            D2 = _d2(Z, j, z_pred, S_inv, n, wrap0)
            out[n, j] = -0.5 * (D2 + c) if D2 <= g else -np.inf
    return out


loglik_dense = jit(loglik_dense)


def loglik_gated(z_pred: np.ndarray, S_inv: np.ndarray, log_det: np.ndarray, Z: np.ndarray, wrap0: bool,
                 g: float, log_2pi: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The finite entries of :func:`loglik_dense`'s matrix as ``(track, measurement,
    log-likelihood)``, sorted by measurement then track (``np.nonzero`` of the transpose)."""
    N, d = z_pred.shape
    M = Z.shape[0]
    ti, mi, ll = np.empty(N * M, np.int64), np.empty(N * M, np.int64), np.empty(N * M)
    L = 0
    for j in range(M):
        for n in range(N):
            D2 = _d2(Z, j, z_pred, S_inv, n, wrap0)
            v = -0.5 * (D2 + (d * log_2pi + log_det[n]))
            if D2 <= g and math.isfinite(v):
                ti[L], mi[L] = n, j
                ll[L] = v
                L += 1
    return ti[:L].copy(), mi[:L].copy(), ll[:L].copy()


loglik_gated = jit(loglik_gated)


def _ball_cells(c, r, lo, h, n):
    """The cells ``[first, last]`` of a grid (cells of side ``h`` from ``lo``, ``n`` of them)
    that hold the points within ``r`` of ``c`` along one axis; ``first > last``: none."""
    a = (c - r - lo) / h
    b = (c + r - lo) / h
    if not (b >= 0.0 and a < n):  # every point is below n (the grid's last cell ends past them)
        return 1, 0
    return int(max(a, 0.0)), int(min(b, n - 1.0))


def loglik_balls(z_pred: np.ndarray, S_inv: np.ndarray, log_det: np.ndarray, Z: np.ndarray, wrap0: bool, g: float,
                 log_2pi: float, Zs: np.ndarray, ok_z: np.ndarray, centres: np.ndarray, owner: np.ndarray,
                 radii: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    r"""The gated pairs of :func:`loglik_gated` found through balls instead of every pair:
    ``Zs`` are the finite measurements ``Z[ok_z]`` in scaled coordinates, and ball ``k``
    (``centres[k]``, ``radii[k]``, same coordinates) holds every measurement in track
    ``owner[k]``'s gate that it can reach (:func:`tracker.gating.gated_log_likelihood` builds
    them: a superset of the gate, with images across the wrapped cut).  The measurements are
    bucketed in a grid of about one ball per cell; each ball's distances
    (:func:`_d2`, the same arithmetic) are computed for the measurements of the cells its box
    covers.  ``(track, measurement, log-likelihood)`` of :math:`D^2 \le g`, sorted by
    measurement then track, each pair once."""
    N, d = z_pred.shape
    M, K = Zs.shape[0], centres.shape[0]
    lo, hi = np.zeros(2), np.zeros(2)
    for a in range(d):
        lo[a], hi[a] = Zs[:, a].min(), Zs[:, a].max()
    h = max(np.median(radii), 1e-9 * max(hi[0] - lo[0], hi[1] - lo[1], 1.0))
    while (np.floor((hi[0] - lo[0]) / h) + 1.0) * (np.floor((hi[1] - lo[1]) / h) + 1.0) > 4.0 * M + 64.0:
        h *= 1.5  # at most 4 M + 64 cells (counted in floats: no integer overflow)
    n0, n1 = int((hi[0] - lo[0]) / h) + 1, int((hi[1] - lo[1]) / h) + 1
    start = np.zeros(n0 * n1 + 1, np.int64)
    cell = np.empty(M, np.int64)
    for p in range(M):
        i0 = min(int((Zs[p, 0] - lo[0]) / h), n0 - 1)
        i1 = min(int((Zs[p, 1] - lo[1]) / h), n1 - 1) if d == 2 else 0
        cell[p] = i0 * n1 + i1
        start[cell[p] + 1] += 1
    for q in range(n0 * n1):
        start[q + 1] += start[q]
    pts, fill = np.empty(M, np.int64), start[:-1].copy()
    for p in range(M):
        pts[fill[cell[p]]] = ok_z[p]
        fill[cell[p]] += 1
    keys, dist = np.empty(4 * (M + K), np.int64), np.empty(4 * (M + K))
    L = 0
    for k in range(K):
        a0, b0 = _ball_cells(centres[k, 0], radii[k], lo[0], h, n0)
        a1, b1 = 0, 0
        if d == 2:
            a1, b1 = _ball_cells(centres[k, 1], radii[k], lo[1], h, n1)
        n = owner[k]
        for i0 in range(a0, b0 + 1):
            for i1 in range(a1, b1 + 1):
                for q in range(start[i0 * n1 + i1], start[i0 * n1 + i1 + 1]):
                    D2 = _d2(Z, pts[q], z_pred, S_inv, n, wrap0)
                    if D2 <= g:
                        if L == keys.shape[0]:
                            keys, dist = _grown(keys, L), _grown(dist, L)
                        keys[L], dist[L] = pts[q] * N + n, D2
                        L += 1
    order = argsort_stable(keys[:L])
    ti, mi, ll = np.empty(L, np.int64), np.empty(L, np.int64), np.empty(L)
    out = 0
    for i in range(L):
        key = keys[order[i]]
        if out > 0 and key == mi[out - 1] * N + ti[out - 1]:
            continue  # the same pair through another image of the ball
        ti[out], mi[out] = key % N, key // N
        ll[out] = -0.5 * (dist[order[i]] + (d * log_2pi + log_det[ti[out]]))
        out += 1
    return ti[:out].copy(), mi[:out].copy(), ll[:out].copy()


def _grown(v, n):
    """``v`` in an array twice its size (its first ``n`` entries kept)."""
    out = np.empty(2 * v.shape[0], v.dtype)
    out[:n] = v[:n]
    return out


_ball_cells = jit(_ball_cells, inline=True)
_grown = jit(_grown)
loglik_balls = jit(loglik_balls)


def update_pairs_kernel(m: np.ndarray, gain: np.ndarray, z_pred: np.ndarray, Z: np.ndarray, ti: np.ndarray,
                        mi: np.ndarray, wrap0: bool) -> np.ndarray:
    r"""``(L, n)`` updated means :math:`m_{t_l} + K_{t_l} (z_{j_l} \ominus \hat z_{t_l})` (the
    reference: :func:`tracker.filtering.update_pairs`; the same sums, in numpy's matmul order)."""
    L = ti.shape[0]
    n, d = gain.shape[1], gain.shape[2]
    out = np.empty((L, n))
    r = np.empty(d)
    for l in range(L):
        t, j = ti[l], mi[l]
        for b in range(d):
            v = Z[j, b] - z_pred[t, b]
            r[b] = _wrap(v) if wrap0 and b == 0 else v
        for a in range(n):
            acc = 0.0
            for b in range(d):
                acc += gain[t, a, b] * r[b]
            out[l, a] = m[t, a] + acc
    return out


update_pairs_kernel = jit(update_pairs_kernel)
