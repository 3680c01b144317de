"""Ground truth as the paper defines it: tapped waypoints joined by straight lines at constant speed.

The walker taps each waypoint on arrival. Between two taps they walked a straight line at a constant
pace, so the true position at time ``t`` is the linear interpolation of the bracketing waypoints.
Before the first tap and after the last one the position is held at that waypoint (the paper's
walkers start at the first waypoint and stop at the last).
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from curbside.errors import CurbsideInputError
from curbside.projection import LocalFrame


def waypoints_xy(waypoints: pd.DataFrame, frame: LocalFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Waypoint times and local metric coordinates.

    Parameters
    ----------
    waypoints
        ``t,lat,lon`` (SPEC ``waypoints.csv``), ``t`` strictly increasing.
    frame
        The local metric frame.

    Returns
    -------
    t, x, y : numpy.ndarray
        Seconds and metres east/north in ``frame``.
    """
    if waypoints is None or len(waypoints) < 2:
        raise CurbsideInputError("waypoints.csv", "ground truth needs at least two waypoints")
    x, y = frame.to_xy(waypoints["lon"].to_numpy(), waypoints["lat"].to_numpy())
    return waypoints["t"].to_numpy(float), x, y


def groundtruth_at(
    waypoints: pd.DataFrame, t: np.ndarray, frame: LocalFrame
) -> tuple[np.ndarray, np.ndarray]:
    """True position at times ``t`` (e.g. each footstep of a track).

    Parameters
    ----------
    waypoints
        ``t,lat,lon`` ground-truth taps.
    t
        Query times in seconds, on the session clock.
    frame
        The local metric frame the positions are returned in.

    Returns
    -------
    x, y : numpy.ndarray
        Metres east/north in ``frame``; clamped to the first/last waypoint outside their span.

    Examples
    --------
    A walker tapping at (0, 0) at t=0 and 10 m east at t=10 is 5 m east at t=5.
    """
    wt, wx, wy = waypoints_xy(waypoints, frame)
    t = np.asarray(t, float)
    return np.interp(t, wt, wx), np.interp(t, wt, wy)


def groundtruth_xy_at(wt: np.ndarray, wx: np.ndarray, wy: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Same as :func:`groundtruth_at` for waypoints already in metres; returns an ``(n, 2)`` array."""
    t = np.asarray(t, float)
    return np.column_stack([np.interp(t, wt, wx), np.interp(t, wt, wy)])
