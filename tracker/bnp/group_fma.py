r"""The 2x2 products of the two-level tracker's partition kernel, in one fixed rounding on every CPU.

The collapsed Gibbs kernel of :mod:`tracker.bnp.group_scan` (``_partition_kernel``) computed its
2x2 matrix-vector and 2-vector products with numba's ``np.dot`` / ``@``, i.e. calls of
OpenBLAS's ``dgemv`` and ``ddot`` (through ``scipy.linalg.cython_blas``): some 100-200 ns per
call on two numbers, most of the kernel's time.  OpenBLAS (0.3.31, Haswell kernels, on session
9's Intel machine) rounds them with fused multiply-adds:

* ``y = A x`` (gemv, row ``i``): :math:`y_i = \mathrm{fma}(A_{i0}, x_0, A_{i1} x_1) + 0` (the
  ``+ 0`` turns an exact ``-0.0`` into ``+0.0``, as BLAS's accumulator does);
* ``a . b`` (dot): :math:`\mathrm{fma}(a_1, b_1, \mathrm{fma}(a_0, b_0, 0))`;
* numpy's stacked ``matmul`` with an inner dimension of 2 (``dgemm``; the sharing's gains in
  :func:`tracker.bnp.group_share.share_velocity`): each entry as the dot above (:func:`sum2`).

:func:`gemv2` and :func:`dot2` compute exactly these with ``llvm.fma.f64`` (:func:`fma`, a numba
intrinsic: one instruction on a CPU with FMA, a correctly rounded libm call otherwise): the
same doubles as that BLAS, bit for bit, including signed zeros, infinities and NaNs.  That ties
the kernel to this formula on every machine, whatever its BLAS rounds (another CPU's kernels,
e.g. an AMD EPYC's ``ddot``, differ in the last bits).  ``tests/tracker/test_group_fma.py`` checks the compiled products
against the formula in exact arithmetic, and BLAS's within a dot product's error bound.
Interpreted (``BNPTRACK_NO_JIT=1``), :func:`fma` is the correctly rounded ``a b + c`` in exact
rational arithmetic.

numba is imported only when a kernel first runs (:mod:`tracker.numerics`): the intrinsic is
built then (:class:`_LazyIntrinsic`), and every module name bound to it is rebound, as
:mod:`tracker.numerics` rebinds its lazy kernels.
"""

from __future__ import annotations

import math
import sys
from fractions import Fraction
from typing import Any

from bnptrack.tracker import numerics
from bnptrack.tracker.numerics import JIT, jit


def exact_fma(a: float, b: float, c: float) -> float:
    r""":math:`a b + c` rounded once (to nearest, ties to even), as IEEE 754's fusedMultiplyAdd;
    infinities and NaNs as ``a * b + c``.  A zero result takes the sign IEEE gives it: that of
    an exact ``a b + c`` of two zeros, else ``+0.0`` when the sum cancels."""
    if not (math.isfinite(a) and math.isfinite(b)):
        return a * b + c
    if not math.isfinite(c):  # the exact, finite product does not overflow first: inf stays inf
        return c
    exact = Fraction(a) * Fraction(b) + Fraction(c)
    if exact == 0:
        return (a * b) + c  # the signs of an exact zero sum: (+-0) + (+-0) or +0 on cancellation
    try:
        out = float(exact)  # correctly rounded
    except OverflowError:  # rounds beyond the largest double
        return math.inf if exact > 0 else -math.inf
    return out if out != 0.0 else (0.0 if exact > 0 else -0.0)  # underflow keeps the exact sign


def _build_intrinsic() -> Any:
    """numba intrinsic ``fma(a, b, c)`` on doubles emitting ``llvm.fma.f64``."""
    from llvmlite import ir
    from numba import types
    from numba.core import cgutils
    from numba.extending import intrinsic

    @intrinsic
    def fma(typingctx, a, b, c):  # noqa: ARG001 - numba's signature
        sig = types.float64(types.float64, types.float64, types.float64)

        def codegen(context, builder, signature, args):  # noqa: ARG001
            fnty = ir.FunctionType(ir.DoubleType(), [ir.DoubleType()] * 3)
            fn = cgutils.get_or_insert_function(builder.module, fnty, "llvm.fma.f64")
            return builder.call(fn, [context.cast(builder, v, t, types.float64)
                                     for v, t in zip(args, signature.args)])

        return sig, codegen

    return fma


class _LazyIntrinsic(numerics._LazyKernel):
    """:func:`exact_fma` in Python; in compiled code the intrinsic of :func:`_build_intrinsic`,
    built when :mod:`tracker.numerics` compiles its pending kernels (numba is imported by then):
    it sees a "dispatcher" already there, so it compiles nothing and rebinds the names."""

    def __init__(self) -> None:
        self._impl = None
        super().__init__(exact_fma, inline=False)

    @property
    def dispatcher(self) -> Any:  # type: ignore[override]
        if self._impl is None and "numba" in sys.modules:
            self._impl = _build_intrinsic()
        return self._impl

    @dispatcher.setter
    def dispatcher(self, value: Any) -> None:
        pass  # _LazyKernel.__init__ sets None; the intrinsic is built on demand

    def __call__(self, *args: Any) -> Any:
        return exact_fma(*args)


if JIT:
    fma = _LazyIntrinsic()
    with numerics._lock:
        numerics._pending.append(fma)
else:
    fma = exact_fma


def gemv2(A, x, out) -> None:
    """``out = A @ x`` for a 2x2 ``A`` and 2-vector ``x``: each row fma(A_i0, x_0, A_i1 x_1) + 0."""
    out[0] = fma(A[0, 0], x[0], A[0, 1] * x[1]) + 0.0
    out[1] = fma(A[1, 0], x[0], A[1, 1] * x[1]) + 0.0


def dot2(a, b) -> float:
    """``a @ b`` for two 2-vectors: fma(a_1, b_1, fma(a_0, b_0, 0))."""
    return fma(a[1], b[1], fma(a[0], b[0], 0.0))


def sum2(a0, b0, a1, b1) -> float:
    """``a0 b0 + a1 b1`` rounded as :func:`dot2`: also each entry of numpy's stacked ``matmul``
    with an inner dimension of 2 (``(Q, n, 2) @ (Q, 2, m)``, OpenBLAS ``dgemm``, either operand
    transposed)."""
    return fma(a1, b1, fma(a0, b0, 0.0))


gemv2 = jit(gemv2, inline=True)
dot2 = jit(dot2, inline=True)
sum2 = jit(sum2, inline=True)
