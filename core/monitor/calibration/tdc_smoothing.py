"""The pressure and its derivative smoothed for the TDC fit (core.monitor.calibration.tdc): a Savitzky-Golay cubic
over ``SMOOTH_DEG``, applied as the linear map it is (``savgol_operator``; scipy's savgol_filter its reference), the
operator made once where a caller smooths the same grid again (``smoothing``: the TDC watch's window close)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned
from scipy.signal import savgol_filter

# Savitzky-Golay span of the pressure before its derivative (the TDC fit's tuning cases: core.monitor.tuned.json)
SMOOTH_DEG = read_tuned(MONITOR_RECORD)["TDC_SMOOTH_DEG"].value


class Smoothing(NamedTuple):
    """The Savitzky-Golay operator of ``smoothed_pressure`` for one grid step [rad] (``smoothing``): value and
    derivative (width, width) each (``savgol_operator``)."""

    step: float
    value: np.ndarray
    derivative: np.ndarray


def smoothing(step_rad: float) -> Smoothing:
    """The operator ``smoothed_pressure`` applies on a grid of ``step_rad``: made once by a caller that smooths the
    same grid again (the TDC watch's window close: one a close, not one a fitted cylinder; its pinv was ~100 of the
    ~127 us of a k9k cylinder's smoothing, design note 51)."""
    value, derivative = savgol_operator(smooth_width(step_rad), 3, step_rad)
    return Smoothing(float(step_rad), value, derivative)


def smoothed_pressure(pressure_pa: np.ndarray, step_rad: float, operator: Smoothing | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(p, dp/dtheta) of each row by a local cubic over SMOOTH_DEG (Savitzky-Golay): the ROHR needs p', and a
    plain difference of 1-deg samples turns the sensor noise into a ROHR noise larger than a 1 deg TDC error.

    scipy's ``savgol_filter(..., mode="interp")`` (``smoothed_pressure_reference``, tested equal) as the linear map it
    is (``savgol_operator``): each sample a dot product with its window; 25 against 450 us for a TDC window's
    (5, 360) block sums (scipy refits the edge polynomials and its coefficients on every call). ``operator``: the
    operator made for this step (``smoothing``; another step's, or None: made here)."""
    p = np.asarray(pressure_pa, dtype=np.float64)
    width = smooth_width(step_rad)
    n = p.shape[1]
    if n < width:  # shorter than one window: scipy's own error
        return smoothed_pressure_reference(p, step_rad)
    if operator is None or operator.step != step_rad or operator.value.shape != (width, width):
        operator = smoothing(step_rad)
    h = width // 2
    windows = np.lib.stride_tricks.sliding_window_view(p, width, axis=1)  # (rows, n - 2h, width), no copy
    out = []
    for op in (operator.value, operator.derivative):
        y = np.empty_like(p)
        y[:, :h] = p[:, :width] @ op[:h].T
        y[:, h:n - h] = windows @ op[h]
        y[:, n - h:] = p[:, n - width:] @ op[width - h:].T
        out.append(y)
    return out[0], out[1]


def smoothed_pressure_reference(pressure_pa: np.ndarray, step_rad: float) -> tuple[np.ndarray, np.ndarray]:
    """``smoothed_pressure`` by scipy.signal.savgol_filter (its reference)."""
    width = smooth_width(step_rad)
    return (savgol_filter(pressure_pa, width, 3, axis=1, mode="interp"),
            savgol_filter(pressure_pa, width, 3, deriv=1, delta=step_rad, axis=1, mode="interp"))


def smooth_width(step_rad: float) -> int:
    """The odd sample count of the smoothing span on a grid of ``step_rad`` (at least 5)."""
    return max(5, 2 * int(round(0.5 * SMOOTH_DEG / math.degrees(step_rad))) + 1)


def savgol_operator(width: int, order: int, step: float) -> tuple[np.ndarray, np.ndarray]:
    """(value, derivative) (width, width) each: row i maps ``width`` samples (spacing ``step``) to the least-squares
    polynomial of ``order`` through them, and its derivative, at sample i. Row width // 2 is the Savitzky-Golay
    filter inside a trace; the rows before and after it are savgol_filter's mode="interp" edges (the polynomial of
    the first / last window evaluated at the edge samples)."""
    t = np.arange(width, dtype=np.float64) - width // 2  # centred: a well-conditioned Vandermonde
    powers = np.arange(order + 1)
    vander = t[:, None] ** powers  # (width, order + 1)
    fit = np.linalg.pinv(vander)  # (order + 1, width): the coefficients of the least-squares polynomial
    dvander = np.zeros_like(vander)
    dvander[:, 1:] = powers[1:] * t[:, None] ** (powers[1:] - 1)
    return vander @ fit, (dvander @ fit) / step


__all__ = ["SMOOTH_DEG", "Smoothing", "savgol_operator", "smooth_width", "smoothed_pressure",
           "smoothed_pressure_reference", "smoothing"]
