"""Seeded random numbers drawn inside the compiled kernels: xoshiro256++ and a 256-layer ziggurat.

A part that draws per-particle noise at every update owns one :class:`Stream`: four ``uint64`` words of
xoshiro256++ state (Blackman & Vigna, "Scrambled linear pseudorandom number generators", ACM TOMS
2021; period ``2**256 - 1``), seeded from the filter's numpy :class:`~numpy.random.Generator`, so the
whole filter stays reproducible from one seed and no two parts (or two trackers) share a stream. Its
kernel reads the state into registers, draws with the functions below and writes it back: no buffer of
normals, no call into numpy per update.

Normals come from the ziggurat of Marsaglia & Tsang ("The ziggurat method for generating random
variables", J. Stat. Softw. 2000) with 256 layers, laid out as numpy's ``Generator.standard_normal``
lays it out: one 64-bit draw gives the layer (8 bits), the sign (1 bit) and a 52-bit abscissa; 98.8 %
of the draws are accepted by one integer comparison, the rest go through the layer's wedge test or,
in the base layer, Marsaglia's exact tail sampler. The layer tables are computed here at import from
the ziggurat's defining recursion (:func:`ziggurat_tables`).

The compiled functions take and return the state as a 4-tuple (``(value, state) = f(state)``) so
that LLVM keeps it in registers inside a kernel's loop::

    @numba.njit
    def kernel(rng_state, out):
        s = load(rng_state)
        for i in range(out.shape[0]):
            out[i], s = standard_normal(s)
        store(rng_state, s)

numba's on-disk cache (``cache=True``) keys a kernel on its own source file only: after editing this
module, delete the ``__pycache__`` folders of the modules whose kernels use it.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: Right edge of the ziggurat's base layer for 256 layers (numpy's ``ziggurat_nor_r``).
ZIGGURAT_R = 3.6541528853610088
LAYERS = 256

_U = np.uint64
_MANTISSA = float(2**52)


def ziggurat_tables(r: float = ZIGGURAT_R, layers: int = LAYERS) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ziggurat of ``f(x) = exp(-x^2 / 2)``: ``(k, w, f)`` tables, one entry per layer.

    Every layer has the area ``v = r f(r) + (tail beyond r)``; layer ``i`` is the box ``[0, x_i]``
    under ``f`` between heights ``f(x_i)`` and ``f(x_{i+1})``, with ``x_0 = v / f(r)`` (the base layer,
    a box plus the tail), ``x_1 = r``, ``x_{i+1} = f^-1(v / x_i + f(x_i))`` and ``x_layers = 0``.

    Returns
    -------
    k
        ``uint64``: a 52-bit abscissa ``a`` below ``k[i]`` lies under the curve in layer ``i``
        (``a / 2**52 < x_{i+1} / x_i``).
    w
        ``x_i / 2**52``: the sample is ``a * w[i]``.
    f
        ``f(x_i)``, with ``f[layers] = 1``.
    """
    fr = math.exp(-0.5 * r * r)
    v = r * fr + math.sqrt(math.pi / 2) * math.erfc(r / math.sqrt(2))
    x = np.zeros(layers + 1)
    x[0], x[1] = v / fr, r
    for i in range(1, layers - 1):
        x[i + 1] = math.sqrt(-2.0 * math.log(v / x[i] + math.exp(-0.5 * x[i] ** 2)))
    k = np.array([int(_MANTISSA * x[i + 1] / x[i]) for i in range(layers)], dtype=np.uint64)
    w = x[:layers] / _MANTISSA
    f = np.exp(-0.5 * x**2)
    return k, w, f


_K, _W, _F = ziggurat_tables()


class Stream:
    """One part's xoshiro256++ state, seeded from a numpy generator.

    Parameters
    ----------
    rng
        The filter's seeded generator: four 64-bit words are drawn from it (so the stream depends on the
        filter's seed and on the order in which the parts were made).

    Attributes
    ----------
    state
        ``(4,)`` ``uint64``: what a kernel takes (:func:`load` / :func:`store`).
    """

    def __init__(self, rng: np.random.Generator) -> None:
        self.state = rng.integers(0, 2**64, size=4, dtype=np.uint64)
        while not self.state.any():  # the one state xoshiro cannot leave (probability 2**-256)
            self.state = rng.integers(0, 2**64, size=4, dtype=np.uint64)

    def copy(self) -> Stream:
        """An independent copy at the same position (it will draw the same numbers)."""
        other = object.__new__(Stream)
        other.state = self.state.copy()
        return other

    def standard_normal(self, size: int) -> np.ndarray:
        """``size`` standard normals (advances the stream)."""
        out = np.empty(size)
        fill_standard_normal(self.state, out)
        return out

    def random(self, size: int) -> np.ndarray:
        """``size`` uniforms in ``[0, 1)`` (advances the stream)."""
        out = np.empty(size)
        fill_random(self.state, out)
        return out


@numba.njit(inline="always", cache=True, nogil=True)
def load(state):  # pragma: no cover - compiled
    """The stream state array as a tuple (keep it in registers)."""
    return state[0], state[1], state[2], state[3]


@numba.njit(inline="always", cache=True, nogil=True)
def store(state, s):  # pragma: no cover - compiled
    """Write the tuple ``s`` back to the state array."""
    state[0], state[1], state[2], state[3] = s


@numba.njit(inline="always", cache=True, nogil=True)
def _rotl(x, k):  # pragma: no cover - compiled
    return (x << _U(k)) | (x >> _U(64 - k))


@numba.njit(inline="always", cache=True, nogil=True)
def next_uint64(s):  # pragma: no cover - compiled
    """xoshiro256++: ``(64 random bits, new state)``."""
    s0, s1, s2, s3 = s
    result = _rotl(s0 + s3, 23) + s0
    t = s1 << _U(17)
    s2 ^= s0
    s3 ^= s1
    s1 ^= s2
    s0 ^= s3
    s2 ^= t
    s3 = _rotl(s3, 45)
    return result, (s0, s1, s2, s3)


@numba.njit(inline="always", cache=True, nogil=True)
def next_double(s):  # pragma: no cover - compiled
    """``(uniform in [0, 1), new state)``: the top 53 bits, as numpy's ``Generator.random``."""
    r, s = next_uint64(s)
    return np.int64(r >> _U(11)) * (1.0 / 9007199254740992.0), s


@numba.njit(cache=True, nogil=True)
def _normal_slow(s, idx, x):  # pragma: no cover - compiled
    # The 1.2 % of draws outside the layer's inner box: wedge test, or the tail of the base layer.
    # Returns (accepted, x, state); on rejection the caller draws again.
    if idx == 0:
        while True:
            u1, s = next_double(s)
            u2, s = next_double(s)
            xx = -math.log1p(-u1) / ZIGGURAT_R  # 1 - u is in (0, 1]: no log(0)
            yy = -math.log1p(-u2)
            if yy + yy > xx * xx:
                tail = ZIGGURAT_R + xx
                return True, (-tail if x < 0 else tail), s
    u, s = next_double(s)
    return (_F[idx] + u * (_F[idx + 1] - _F[idx])) < math.exp(-0.5 * x * x), x, s


@numba.njit(inline="always", cache=True, nogil=True)
def standard_normal(s):  # pragma: no cover - compiled
    """``(standard normal, new state)`` by the ziggurat (see the module docstring)."""
    while True:
        r, s = next_uint64(s)
        idx = np.intp(r & _U(0xFF))
        r >>= _U(8)
        rabs = (r >> _U(1)) & _U(0x000FFFFFFFFFFFFF)
        x = np.int64(rabs) * _W[idx]
        if r & _U(1):
            x = -x
        if rabs < _K[idx]:
            return x, s
        ok, x, s = _normal_slow(s, idx, x)
        if ok:
            return x, s


@numba.njit(cache=True, nogil=True)
def draw_random(state):  # pragma: no cover - compiled
    """One uniform in ``[0, 1)`` from the state array (advances it; for replaying a kernel's draws)."""
    u, s = next_double(load(state))
    store(state, s)
    return u


@numba.njit(cache=True, nogil=True)
def draw_standard_normal(state):  # pragma: no cover - compiled
    """One standard normal from the state array (advances it; for replaying a kernel's draws)."""
    z, s = standard_normal(load(state))
    store(state, s)
    return z


@numba.njit(cache=True, nogil=True)
def fill_standard_normal(state, out):  # pragma: no cover - compiled
    """Fill the float64 array ``out`` (any shape) with standard normals drawn from ``state``."""
    s = load(state)
    flat = out.reshape(-1)
    for i in range(flat.shape[0]):
        flat[i], s = standard_normal(s)
    store(state, s)


@numba.njit(cache=True, nogil=True)
def fill_random(state, out):  # pragma: no cover - compiled
    """Fill the float64 array ``out`` (any shape) with uniforms in ``[0, 1)`` drawn from ``state``."""
    s = load(state)
    flat = out.reshape(-1)
    for i in range(flat.shape[0]):
        flat[i], s = next_double(s)
    store(state, s)
