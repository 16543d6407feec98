"""Foot-contact labels, exactly as the paper's Sec. 4.1.

A foot is in contact when its toe is both low and slow:

* **height**: below ``min(p10(left toe y), p10(right toe y)) + 5 cm``, the 10th
  percentile taken per sequence;
* **speed**: below 1 cm per frame at 60 fps (0.6 m/s), after smoothing the velocity
  with a Savitzky-Golay filter (window 11, polynomial order 3). The filter's first
  derivative is the smoothed velocity.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

HEIGHT_PERCENTILE = 10.0
HEIGHT_MARGIN_M = 0.05
SPEED_LIMIT_M_PER_FRAME_AT_60 = 0.01
SAVGOL_WINDOW = 11
SAVGOL_ORDER = 3


def smoothed_velocity(pos: ArrayLike, fps: float) -> NDArray[np.float64]:
    """Savitzky-Golay smoothed velocity ``(F, ..., 3)`` in m/s along axis 0."""
    from scipy.signal import savgol_filter  # data extra; the server never imports this

    p = np.asarray(pos, dtype=np.float64)
    n = p.shape[0]
    window = min(SAVGOL_WINDOW, n if n % 2 == 1 else n - 1)
    if window <= SAVGOL_ORDER:
        return np.gradient(p, axis=0) * fps if n > 1 else np.zeros_like(p)
    v = savgol_filter(p, window, SAVGOL_ORDER, deriv=1, axis=0, mode="interp")
    return np.asarray(v) * fps


def foot_contacts(toe_pos: ArrayLike, fps: float) -> NDArray[np.bool_]:
    """Contact labels ``(F, 2)`` from toe positions ``(F, 2, 3)`` (left, right), metres."""
    toes = np.asarray(toe_pos, dtype=np.float64)
    height = toes[..., 1]  # (F, 2)
    threshold = float(np.min(np.percentile(height, HEIGHT_PERCENTILE, axis=0))) + HEIGHT_MARGIN_M
    speed = np.linalg.norm(smoothed_velocity(toes, fps), axis=-1)  # (F, 2) m/s
    speed_limit = SPEED_LIMIT_M_PER_FRAME_AT_60 * 60.0
    contact: NDArray[np.bool_] = (height < threshold) & (speed < speed_limit)
    return contact
