"""Scalar math for the compiled kernels, written so that LLVM can vectorise the loops that call it.

numba compiles ``math.exp``, ``math.log1p``, ``math.sin`` and ``math.cos`` to calls into the C library,
and a call keeps a loop scalar (4-15 ns per call here). The functions below are the polynomial kernels
of fdlibm (Sun Microsystems 1993: the coefficients of ``k_sin.c``, ``k_cos.c``, ``e_exp.c`` and
``e_log.c``) with the argument reduction done by arithmetic and bit operations and every case picked by
a select, not a branch, so that a loop of them runs on SIMD lanes (1-2 ns per element). Each is within
one unit in the last place of the C library's result over the range it is used on (tested). A kernel
that calls them must be compiled with ``error_model="numpy"``: under numba's default, every division
checks for zero and raises, and that branch keeps the loop scalar.

:func:`sincos`
    ``(sin x, cos x)`` after a two-part Cody-Waite reduction by ``pi / 2``, for ``|x| < LIMIT``
    (callers check :func:`in_range` and fall back to ``math.sin`` / ``math.cos`` beyond);
:func:`exp`
    ``e**x`` for ``x <= 709`` (``-inf`` and anything below -745.2 give 0, as they should);
:func:`logaddexp`
    ``log(e**u + e**v)`` as numpy computes it, with ``log1p`` on ``[0, 1]`` by fdlibm's ``log`` kernel;
:func:`cell_index`, :func:`cell_indices`
    a point's index in a padded map raster (:attr:`~curbside.localize.raster.RasterLookup.index_grid`),
    and every particle's, in a loop of its own (branch-free, so SIMD; a kernel that then reads the
    raster in a branchy loop is faster than with the index computed inside it).

numba's on-disk cache (``cache=True``) keys a kernel on its own source file only: after editing this
module, delete the ``__pycache__`` folders of the modules whose kernels use it.
"""

from __future__ import annotations

import math

import numba
import numpy as np
from llvmlite import ir
from numba import types
from numba.extending import intrinsic

#: Largest ``|x|`` that :func:`sincos` is accurate for (the two-part reduction by pi / 2).
LIMIT = 1024.0

_S1 = -1.66666666666666324348e-01
_S2 = 8.33333333332248946124e-03
_S3 = -1.98412698298579493134e-04
_S4 = 2.75573137070700676789e-06
_S5 = -2.50507602534068634195e-08
_S6 = 1.58969099521155010221e-10
_C1 = 4.16666666666666019037e-02
_C2 = -1.38888888888741095749e-03
_C3 = 2.48015872894767294178e-05
_C4 = -2.75573143513906633035e-07
_C5 = 2.08757232129817482790e-09
_C6 = -1.13596475577881948265e-11
_PIO2_1 = 1.57079632673412561417e00  # the first 33 bits of pi / 2: k * _PIO2_1 is exact
_PIO2_1T = 6.07710050650619224932e-11  # pi / 2 - _PIO2_1
_INV_PIO2 = 6.36619772367581382433e-01
_ROUND = 6755399441055744.0  # 1.5 * 2**52: (v + _ROUND) - _ROUND rounds v to an integer


@numba.njit(inline="always", cache=True, nogil=True)
def in_range(x):  # pragma: no cover - compiled
    """Whether :func:`sincos` is accurate at ``x`` (``False`` for NaN too)."""
    return abs(x) < LIMIT


@numba.njit(inline="always", cache=True, nogil=True)
def sincos(x):  # pragma: no cover - compiled
    """``(sin x, cos x)`` for ``|x| < LIMIT``, within one ulp of the C library's."""
    fk = (x * _INV_PIO2 + _ROUND) - _ROUND  # x = fk * pi / 2 + (y + tail), |y| <= pi / 4
    r = x - fk * _PIO2_1
    w = fk * _PIO2_1T
    y = r - w
    tail = (r - y) - w
    quadrant = int(fk) & 3
    z = y * y
    zz = z * z
    ps = _S2 + z * (_S3 + z * _S4) + z * zz * (_S5 + z * _S6)
    yz = z * y
    s = y - ((z * (0.5 * tail - yz * ps) - tail) - yz * _S1)
    pc = z * (_C1 + z * (_C2 + z * _C3)) + zz * zz * (_C4 + z * (_C5 + z * _C6))
    half_z = 0.5 * z
    one_minus = 1.0 - half_z
    c = one_minus + (((1.0 - one_minus) - half_z) + (z * pc - y * tail))
    odd = (quadrant & 1) != 0
    s_q = c if odd else s
    c_q = -s if odd else c
    flip = (quadrant & 2) != 0
    return (-s_q if flip else s_q), (-c_q if flip else c_q)


_LN2_HI = 6.93147180369123816490e-01  # its low 32 bits are zero: k * _LN2_HI is exact
_LN2_LO = 1.90821492927058770002e-10
_INV_LN2 = 1.44269504088896338700e00
_P1 = 1.66666666666666019037e-01
_P2 = -2.77777777770155933842e-03
_P3 = 6.61375632143793436117e-05
_P4 = -1.65339022054652515390e-06
_P5 = 4.13813679705723846039e-08
_LG1 = 6.666666666666735130e-01
_LG2 = 3.999999999940941908e-01
_LG3 = 2.857142874366239149e-01
_LG4 = 2.222219843214978396e-01
_LG5 = 1.818357216161805012e-01
_LG6 = 1.531383769920937332e-01
_LG7 = 1.479819860511658591e-01
_SQRT2_MINUS_1 = 0.41421356237309503


@intrinsic
def _float_from_bits(typingctx, bits):
    """The float64 whose IEEE 754 bits are the int64 ``bits`` (a bit cast, no conversion)."""
    if not isinstance(bits, types.Integer):
        return None

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


@numba.njit(inline="always", cache=True, nogil=True)
def _pow2(k):  # pragma: no cover - compiled
    """``2.0 ** k`` for integer ``k`` in [-1022, 1023]."""
    return _float_from_bits((k + 1023) << 52)


@numba.njit(inline="always", cache=True, nogil=True)
def exp(x):  # pragma: no cover - compiled
    """``e**x`` for ``x <= 709`` (0 for ``-inf``; NaN for NaN), within one ulp of the C library's."""
    x = -746.0 if x < -746.0 else x  # below -745.2 the result rounds to 0; the scaling then gives 0
    fk = (x * _INV_LN2 + _ROUND) - _ROUND
    hi = x - fk * _LN2_HI  # x = k ln 2 + r, |r| <= ln 2 / 2
    lo = fk * _LN2_LO
    r = hi - lo
    t = r * r
    c = r - t * (_P1 + t * (_P2 + t * (_P3 + t * (_P4 + t * _P5))))
    y = 1.0 - ((lo - (r * c) / (2.0 - c)) - hi)
    k = int(fk)
    half = k >> 1  # two factors, each a normal number, so that subnormal results come out right
    return y * _pow2(half) * _pow2(k - half)


@numba.njit(inline="always", cache=True, nogil=True)
def _log1p_unit(t):  # pragma: no cover - compiled
    """``log(1 + t)`` for ``t`` in ``[0, 1]``: fdlibm's ``log`` kernel on ``1 + f`` or ``2 (1 + f)``."""
    above = t > _SQRT2_MINUS_1
    f = (t - 1.0) * 0.5 if above else t  # 1 + t = 2 (1 + f) above sqrt(2) - 1, |f| < 0.293
    dk = 1.0 if above else 0.0
    s = f / (2.0 + f)
    z = s * s
    w = z * z
    r = z * (_LG1 + w * (_LG3 + w * (_LG5 + w * _LG7))) + w * (_LG2 + w * (_LG4 + w * _LG6))
    hfsq = 0.5 * f * f
    return dk * _LN2_HI - ((hfsq - (s * (hfsq + r) + dk * _LN2_LO)) - f)


@numba.njit(inline="always", cache=True, nogil=True)
def logaddexp(u, v):  # pragma: no cover - compiled
    """``log(e**u + e**v)`` without overflow, as ``numpy.logaddexp`` (``-inf`` when both are)."""
    hi = u if u > v else v
    lo = v if u > v else u  # NaN in either: lo is NaN and so is the result
    total = hi + _log1p_unit(exp(lo - hi))
    return hi if lo == -math.inf else total


@numba.njit(inline="always", cache=True, nogil=True)
def cell_index(x, y, grid):  # pragma: no cover - compiled
    """Index of point ``(x, y)`` in a padded, flattened raster; ``grid`` is ``RasterLookup.index_grid``.

    The index is clipped into the padding ring, so points off the map read the ring's value.
    """
    inv_res, x_offset, y_offset, col_max, row_max, stride = grid
    fx = min(max(x * inv_res - x_offset, 0.0), col_max)
    fy = min(max(y * inv_res - y_offset, 0.0), row_max)
    return int(fy) * stride + int(fx)


@numba.njit(inline="always", cache=True, nogil=True)
def cell_indices(state, grid):  # pragma: no cover - compiled
    """:func:`cell_index` of every particle (columns of ``state``, rows 0 and 1 east and north)."""
    n = state.shape[1]
    cells = np.empty(n, np.int64)
    for i in range(n):
        cells[i] = cell_index(state[0, i], state[1, i], grid)
    return cells
