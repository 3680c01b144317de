"""Causal device orientation from the gyroscope, for IMU logs without an orientation quaternion.

:class:`GyroscopeIntegrator` builds a game rotation vector (tilt held to gravity, yaw free) sample by
sample, in chunks of any size, with results that do not depend on the chunking: every reduction has
a fixed order and the prefix product runs in blocks anchored at the segment's first sample.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

#: Length of the blocks of the gyroscope's parallel prefix product. Blocks are anchored at a
#: segment's first sample, so a sample's orientation never depends on where a chunk ended.
SCAN_BLOCK = 64


def norm_rows(v: np.ndarray) -> np.ndarray:
    """Euclidean norm of each row, summed in a fixed order (no reduction whose order could vary)."""
    total = v[..., 0] * v[..., 0]
    for k in range(1, v.shape[-1]):
        total = total + v[..., k] * v[..., k]
    return np.sqrt(total)


def quat_mul(p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-last quaternion arrays ``(..., 4)``, ``p * q`` row by row.

    Kept instead of ``Rotation.__mul__``: in the prefix product below it is 3-7x faster (scipy 1.17
    normalises both operands and the result; ``benchmarks/bench_ronin.py`` measures both).
    """
    px, py, pz, pw = (p[..., k] for k in range(4))
    qx, qy, qz, qw = (q[..., k] for k in range(4))
    return np.stack(
        [
            pw * qx + px * qw + py * qz - pz * qy,
            pw * qy - px * qz + py * qw + pz * qx,
            pw * qz + px * qy - py * qx + pz * qw,
            pw * qw - px * qx - py * qy - pz * qz,
        ],
        axis=-1,
    )


def rotate_vectors(quat: np.ndarray, vectors: np.ndarray) -> np.ndarray:
    """Rotate each row of ``vectors`` ``(N, 3)`` by the unit scalar-last quaternion ``(N, 4)`` of its row.

    Used instead of ``Rotation.apply``, whose result for a single rotation differs in the last bits
    from the same rotation applied in a batch (scipy 1.17): a sample's world-frame value must not
    depend on the size of the chunk it came in. ``v' = v + w t + q x t`` with ``t = 2 q x v``.
    """
    x, y, z, w = (quat[:, k] for k in range(4))
    vx, vy, vz = (vectors[:, k] for k in range(3))
    tx = 2.0 * (y * vz - z * vy)
    ty = 2.0 * (z * vx - x * vz)
    tz = 2.0 * (x * vy - y * vx)
    return np.stack([vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz),
                     vz + w * tz + (x * ty - y * tx)], axis=1)


def block_prefix_products(increments: np.ndarray) -> np.ndarray:
    """Inclusive prefix products of quaternions within each block: Hillis-Steele, log2(B) steps.

    Parameters
    ----------
    increments
        ``(nb, B, 4)`` scalar-last unit quaternions.

    Returns
    -------
    numpy.ndarray
        ``(nb, B, 4)``: row ``i`` of a block is ``q_0 * q_1 * ... * q_i``. It depends on rows
        ``0..i`` only (only the rows a step updates are renormalised), so a partly filled block
        padded with identities gives the same rows as the full block.
    """
    prefix = increments.copy()
    d = 1
    while d < prefix.shape[1]:
        updated = quat_mul(prefix[:, :-d], prefix[:, d:])
        prefix[:, d:] = updated / norm_rows(updated)[..., None]
        d *= 2
    return prefix


class GyroscopeIntegrator:
    """Causal device-to-world orientation of one segment from the gyroscope: a game rotation vector.

    The body-frame increments ``exp(omega dt)`` (trapezoidal rate) are chained by a prefix product
    in blocks of :data:`SCAN_BLOCK` samples anchored at the segment's first sample, starting from the
    tilt of the first accelerometer sample and zero yaw. Gyroscope bias makes the tilt drift, which
    would leak gravity into the horizontal channels, so each sample's tilt is then corrected by the
    smallest rotation taking the mean world-frame specific force over the trailing
    ``tilt_window_s`` to +z. That correction has no yaw component: yaw drifts as it does in
    Android's game rotation vector. Samples may be given in chunks of any size; the orientations
    are bit-identical whatever the chunking.

    Parameters
    ----------
    tilt_window_s
        Trailing window of the gravity estimate (s).
    """

    def __init__(self, tilt_window_s: float = 2.0) -> None:
        self.tilt_window_s = tilt_window_s
        self._block_start: Rotation | None = None  # orientation before the current block
        self._block_increments = np.zeros((0, 4))
        self._last_t = 0.0
        self._last_gyro = np.zeros(3)
        self._sum_t = np.array([-np.inf])  # times and running sums of the world specific force,
        self._sum = np.zeros((1, 3))  # over the trailing window plus the sample before it

    def update(self, t: np.ndarray, gyro: np.ndarray, acc: np.ndarray) -> Rotation:
        """Orientations at the next samples ``t`` (s), ``gyro`` (rad/s) and ``acc`` (m/s^2), device frame."""
        t, gyro, acc = (np.array(a, dtype=float) for a in (t, gyro, acc))  # writable copies for scipy
        if self._block_start is None:
            self._block_start, _ = Rotation.align_vectors([[0.0, 0.0, 1.0]], [acc[0]])
            self._last_t, self._last_gyro = t[0], gyro[0]
        dt = np.diff(t, prepend=self._last_t)
        omega = 0.5 * (gyro + np.vstack([self._last_gyro, gyro[:-1]]))
        self._last_t, self._last_gyro = t[-1], gyro[-1]
        rot = self._chain(Rotation.from_rotvec(omega * dt[:, None]).as_quat())
        return self._hold_tilt(t, rot, rotate_vectors(rot.as_quat(), acc))

    def _chain(self, increments: np.ndarray) -> Rotation:
        n_new = len(increments)
        pending = np.vstack([self._block_increments, increments])
        n_blocks = -(-len(pending) // SCAN_BLOCK)
        padded = np.tile([0.0, 0.0, 0.0, 1.0], (n_blocks * SCAN_BLOCK, 1))
        padded[: len(pending)] = pending
        prefix = block_prefix_products(padded.reshape(n_blocks, SCAN_BLOCK, 4))
        starts = [self._block_start]
        for b in range(n_blocks - 1):
            starts.append(starts[-1] * Rotation.from_quat(prefix[b, -1]))
        block_of_row = np.repeat(np.arange(n_blocks), SCAN_BLOCK)[: len(pending)]
        within = Rotation.from_quat(prefix.reshape(-1, 4)[: len(pending)])
        rot = Rotation.concatenate(starts)[block_of_row] * within
        full = len(pending) % SCAN_BLOCK == 0
        self._block_start = starts[-1] * Rotation.from_quat(prefix[-1, -1]) if full else starts[-1]
        self._block_increments = pending[len(pending) - len(pending) % SCAN_BLOCK :]
        return rot[len(pending) - n_new :]

    def _hold_tilt(self, t: np.ndarray, rot: Rotation, world_acc: np.ndarray) -> Rotation:
        sums = np.cumsum(np.vstack([self._sum[-1:], world_acc]), axis=0)[1:]  # sequential: chunk-proof
        all_t = np.concatenate([self._sum_t, t])
        all_sums = np.vstack([self._sum, sums])
        first = np.searchsorted(all_t, t - self.tilt_window_s, side="right")  # first sample inside
        here = np.arange(len(self._sum_t), len(all_t))
        up = (all_sums[here] - all_sums[first - 1]) / (here - first + 1)[:, None]
        up = up / norm_rows(up)[:, None]
        axis = np.stack([up[:, 1], -up[:, 0], np.zeros(len(up))], axis=1)  # up x (0, 0, 1)
        sin = norm_rows(axis)
        angle = np.arctan2(sin, up[:, 2])
        axis = np.divide(axis, sin[:, None], out=np.zeros_like(axis), where=sin[:, None] > 1e-12)
        keep = np.searchsorted(all_t, t[-1] - self.tilt_window_s, side="right") - 1
        self._sum_t, self._sum = all_t[keep:], all_sums[keep:]
        return Rotation.from_rotvec(axis * angle[:, None]) * rot


def integrate_gyroscope(t: np.ndarray, gyro: np.ndarray, acc: np.ndarray,
                        tilt_window_s: float = 2.0) -> Rotation:
    """Device-to-world orientation of one gap-free stretch (see :class:`GyroscopeIntegrator`).

    Parameters
    ----------
    t
        ``(N,)`` sample times (s), increasing.
    gyro
        ``(N, 3)`` rad/s, device frame.
    acc
        ``(N, 3)`` m/s^2 with gravity, device frame.
    tilt_window_s
        Trailing window of the gravity estimate.

    Returns
    -------
    scipy.spatial.transform.Rotation
        ``N`` device-to-world rotations.
    """
    return GyroscopeIntegrator(tilt_window_s).update(t, gyro, acc)
