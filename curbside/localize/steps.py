"""Footstep detection from the accelerometer (the filter updates once per footstep, as in the paper).

Each footstep shows as a peak of the acceleration magnitude ``|a|`` at heel strike, 1.5-2.5 times a
second. The detector

1. resamples ``|a|`` onto a uniform grid at the accelerometer's median rate (phone timestamps jitter),
2. low-passes it (zero-phase Butterworth, ``settings.step_lowpass_hz``) to keep the gait fundamental,
3. takes the local mean and standard deviation over ``settings.step_window_s`` (centred),
4. keeps peaks at least ``settings.step_min_interval_s`` apart whose height above the local mean
   exceeds ``settings.step_threshold_sigma`` local standard deviations (the adaptive threshold:
   it follows a soft or a heavy gait) and whose local standard deviation exceeds
   ``settings.step_still_std_ms2`` (standing still, or holding the phone quietly, makes no steps).

The magnitude does not depend on how the phone is held, so no orientation is needed.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from scipy.ndimage import uniform_filter1d
from scipy.signal import butter, find_peaks, sosfiltfilt

from curbside import settings


def uniform_magnitude(imu: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """The accelerometer magnitude resampled on a uniform grid at the median sample rate.

    Parameters
    ----------
    imu
        Table with ``t`` (s, increasing) and ``ax,ay,az`` (m/s^2).

    Returns
    -------
    t : numpy.ndarray
        Uniform times (s).
    magnitude : numpy.ndarray
        ``|a|`` (m/s^2) at ``t``.
    """
    t_raw = imu["t"].to_numpy(float)
    mag_raw = np.linalg.norm(imu[["ax", "ay", "az"]].to_numpy(float), axis=1)
    dt = float(np.median(np.diff(t_raw)))
    t = np.arange(t_raw[0], t_raw[-1] + 0.5 * dt, dt)
    return t, np.interp(t, t_raw, mag_raw)


def lowpass(x: np.ndarray, rate_hz: float, cutoff_hz: float) -> np.ndarray:
    """Zero-phase 4th-order Butterworth low-pass of a uniformly sampled signal.

    A signal shorter than the filter's edge padding (under half a second) is returned unfiltered.
    """
    sos = butter(4, min(cutoff_hz, 0.45 * rate_hz), btype="low", fs=rate_hz, output="sos")
    padding = 3 * (2 * len(sos) + 1)
    return sosfiltfilt(sos, x) if len(x) > padding else np.array(x, float)


def detect_steps(
    imu: pd.DataFrame,
    *,
    lowpass_hz: float | None = None,
    min_interval_s: float | None = None,
    threshold_sigma: float | None = None,
    still_std_ms2: float | None = None,
    window_s: float | None = None,
) -> np.ndarray:
    """Footstep times from the accelerometer magnitude.

    Parameters
    ----------
    imu
        ``imu.csv`` table: ``t`` (s) and ``ax,ay,az`` (m/s^2, gravity included).
    lowpass_hz, min_interval_s, threshold_sigma, still_std_ms2, window_s
        Override the ``settings.step_*`` values of the same names.

    Returns
    -------
    numpy.ndarray
        Increasing footstep times (s), on the ``imu`` clock; empty when nobody walks.
    """
    lowpass_hz = settings.step_lowpass_hz if lowpass_hz is None else lowpass_hz
    min_interval_s = settings.step_min_interval_s if min_interval_s is None else min_interval_s
    threshold_sigma = settings.step_threshold_sigma if threshold_sigma is None else threshold_sigma
    still_std_ms2 = settings.step_still_std_ms2 if still_std_ms2 is None else still_std_ms2
    window_s = settings.step_window_s if window_s is None else window_s
    if len(imu) < 3:
        return np.empty(0)
    t, mag = uniform_magnitude(imu)
    rate_hz = 1.0 / (t[1] - t[0])
    smooth = lowpass(mag, rate_hz, lowpass_hz)
    width = max(3, int(round(window_s * rate_hz)))
    mean = uniform_filter1d(smooth, width, mode="nearest")
    std = np.sqrt(np.maximum(uniform_filter1d(smooth**2, width, mode="nearest") - mean**2, 0.0))
    peaks, _ = find_peaks(smooth, distance=max(1, int(round(min_interval_s * rate_hz))))
    keep = (std[peaks] > still_std_ms2) & (smooth[peaks] - mean[peaks] > threshold_sigma * std[peaks])
    return t[peaks[keep]]
