"""Instantaneous speed and acceleration from tooth timestamps (physics.md §14.4, §14.7).

Chain for one assembled cycle (``cycle_speed``):

1. ``tooth_speed``: omega_{j+1/2} = (theta_{j+1} - theta_j) / dt_j at the mid-angle, with dt_j an integer tick
   difference (design.md §3: no tick is lost before the division) and theta corrected for tooth-spacing error.
2. ``pitch_samples``: the 2T intervals that span exactly one cycle from the first edge become 2N uniform samples
   at the tooth pitch; the (k+1)-pitch gap interval is split by a linear fill that keeps its measured mean.
3. ``lowpass_cycle``: zero-phase Fourier filter. The linear drift of omega over the cycle is removed first (so the
   data are periodic), the rFFT is truncated at orders <= n_max (optionally with a cosine taper), and the series is
   evaluated straight onto the uniform grid; d omega / d theta is its spectral derivative plus the drift.
   alpha = omega d omega / d theta.

Drift. With one cycle alone the drift b is estimated jointly with the band-limited periodic part: least squares of
the DFT over the bins above the kept band, where a ramp shows (its sawtooth spectrum) and a band-limited periodic
signal does not. Exact for band-limited data; biased by content above n_max (tooth error not yet learned, high
orders), so a caller that has the neighbouring cycles should pass ``drift`` from their mean speeds instead
(``drift_from_means``), or use the streaming filter (core/speed_stream.py) which needs no drift at all.

``tooth_average`` applies the tooth-interval averaging (a sinc(n/N) filter at order n, §14.4) to a model curve, so
the model can be taken through the same chain and compared like for like.

Tooth-spacing learning lives in core/speed_spacing.py, the streaming FIR filter in core/speed_stream.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.monitor.speed_spacing import (  # re-exported: one speed API
    SpacingState,
    ToothSpacingLearner,
    engine_orders,
)
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class CycleSpeed:
    """Speed of one cycle on the uniform grid.

    grid        (G,) crank angle [rad], 0..4 pi (cyl-1 convention)
    omega       (G,) filtered angular speed [rad/s] (tooth-interval averaged, physics.md §14.4)
    alpha       (G,) angular acceleration omega d omega / d theta [rad/s^2]
    omega_mean  time-mean speed over the cycle, 4 pi / T [rad/s]
    rpm_mean    the same in rpm
    drift       linear speed drift used [rad/s per rad]
    """

    grid: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    omega_mean: float
    rpm_mean: float
    drift: float


# ---- 1. tooth speed ---------------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _tooth_speed(ticks, angle, tick_hz, theta_mid, omega):
    for j in range(ticks.shape[0] - 1):
        dt = ticks[j + 1] - ticks[j]  # int64 difference: exact
        theta_mid[j] = 0.5 * (angle[j] + angle[j + 1])
        omega[j] = (angle[j + 1] - angle[j]) * tick_hz / dt


def tooth_speed(tooth_ticks: np.ndarray, tooth_angle: np.ndarray, tick_hz: float,
                angle_correction: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Interval speeds between consecutive tooth edges (physics.md §14.4).

    Parameters
    ----------
    tooth_ticks : (n,) int64 edge times, strictly increasing [timer ticks]
    tooth_angle : (n,) nominal crank angle of each edge, increasing [rad]
    tick_hz : timer clock [Hz]
    angle_correction : (n,) tooth-angle error eps of each edge [rad], added to the nominal angle (None: zero)

    Returns
    -------
    theta_mid : (n-1,) mid-angle of each interval [rad]
    omega : (n-1,) interval-mean angular speed [rad/s]
    """
    ticks = np.ascontiguousarray(tooth_ticks)
    if ticks.dtype != np.int64:
        raise ValueError(f"tooth_ticks must be int64 timer ticks, got {ticks.dtype}")
    ang = np.ascontiguousarray(tooth_angle, dtype=np.float64)
    if ticks.ndim != 1 or ang.shape != ticks.shape or ticks.shape[0] < 2:
        raise ValueError(f"tooth_ticks and tooth_angle must be 1-D of equal length >= 2, got {ticks.shape}, "
                         f"{ang.shape}")
    if angle_correction is not None:
        corr = np.asarray(angle_correction, dtype=np.float64)
        if corr.shape != ang.shape:
            raise ValueError(f"angle_correction has shape {corr.shape}; expected {ang.shape} (one per edge)")
        ang = ang + corr
    if np.any(np.diff(ticks) <= 0):
        raise ValueError("tooth_ticks must be strictly increasing")
    if not tick_hz > 0:
        raise ValueError(f"tick_hz must be > 0, got {tick_hz}")
    theta_mid = np.empty(ticks.shape[0] - 1)
    omega = np.empty_like(theta_mid)
    _tooth_speed(ticks, ang, float(tick_hz), theta_mid, omega)
    return theta_mid, omega


# ---- 2. uniform pitch samples -------------------------------------------------------------------------------------
@numba.njit(cache=True)
def _pitch_samples(nominal, omega, pitch, out):
    """Fill ``out`` (M samples at the pitch) from interval speeds; returns the number of intervals used."""
    m_total = out.shape[0]
    i = 0
    j = 0
    while i < m_total:
        m = int(round((nominal[j + 1] - nominal[j]) / pitch))  # noqa: RUF046 (numba: round may give float)
        if m <= 1:
            out[i] = omega[j]
            i += 1
        else:
            # linear between the neighbouring intervals' values, shifted to keep the measured mean
            left = omega[j - 1] if j > 0 else omega[j]
            right = omega[j + 1] if j + 1 < omega.shape[0] else omega[j]
            s = 0.0
            for q in range(m):
                s += left + (right - left) * (q + 1.0) / (m + 1.0)
            shift = omega[j] - s / m
            for q in range(m):
                if i < m_total:
                    out[i] = left + (right - left) * (q + 1.0) / (m + 1.0) + shift
                    i += 1
        j += 1
    return j


def pitch_samples(tooth_angle: np.ndarray, omega: np.ndarray, positions_per_rev: int) -> tuple[float, np.ndarray]:
    """Uniform samples at the tooth pitch over exactly one cycle (4 pi) from the first edge.

    tooth_angle : (n,) nominal edge angles [rad] (gap intervals are (k+1) pitches)
    omega : (n-1,) interval speeds [rad/s] (``tooth_speed``)
    positions_per_rev : N, tooth positions per revolution including missing ones

    Returns theta0 (angle of the first edge [rad]) and samples (2N,) [rad/s]; sample i sits at
    theta0 + (i + 1/2) 2 pi / N."""
    nom = np.ascontiguousarray(tooth_angle, dtype=np.float64)
    w = np.ascontiguousarray(omega, dtype=np.float64)
    n = int(positions_per_rev)
    if w.shape[0] != nom.shape[0] - 1:
        raise ValueError(f"omega has {w.shape[0]} intervals for {nom.shape[0]} edges")
    if nom[-1] - nom[0] < FOUR_PI - 1e-9:
        raise ValueError(f"the edges span {np.degrees(nom[-1] - nom[0]):.2f} deg; a whole cycle (720) is needed")
    out = np.empty(2 * n)
    _pitch_samples(nom, w, 2 * np.pi / n, out)
    return float(nom[0]), out


# ---- 3. zero-phase Fourier filter ------------------------------------------------------------------------------------
def _ramp(m: int) -> np.ndarray:
    """Centred ramp on m samples, in units of the sample spacing."""
    return np.arange(m) + 0.5 - 0.5 * m


def _order_weights(m_bins: int, n_max_order: float, taper_orders: float) -> np.ndarray:
    """Weights of rFFT bins 0..m_bins-1 (bin b = order b/2): 1 up to n_max - taper, cosine to 0 at n_max."""
    order = 0.5 * np.arange(m_bins)
    wts = (order <= n_max_order + 1e-9).astype(np.float64)
    if taper_orders > 0:
        lo = n_max_order - taper_orders
        band = (order > lo) & (order <= n_max_order)
        wts[band] = 0.5 * (1.0 + np.cos(np.pi * (order[band] - lo) / taper_orders))
    return wts


def drift_from_means(omega_prev: float, omega_next: float) -> float:
    """Drift [rad/s per rad] at a cycle from the mean speeds of its neighbours (central difference over 8 pi)."""
    return (omega_next - omega_prev) / (2.0 * FOUR_PI)


def lowpass_cycle(samples: np.ndarray, theta0: float, n_max_order: float, grid_points: int,
                  taper_orders: float = 0.0, drift: float | None = None) -> tuple[np.ndarray, np.ndarray, float]:
    """Zero-phase low-pass of one cycle's pitch samples, evaluated on the uniform grid.

    Parameters
    ----------
    samples : (M,) speed at theta0 + (i + 1/2) 4 pi / M [rad/s] (``pitch_samples``)
    theta0 : angle of the first edge [rad]
    n_max_order : highest engine order kept (order n = n events per revolution; bin 2n of the cycle)
    grid_points : G, output grid 4 pi g / G
    taper_orders : width of a cosine roll-off ending at n_max (0: sharp cut)
    drift : linear speed drift [rad/s per rad]; None estimates it from the bins above the kept band

    Returns omega (G,) [rad/s], d omega / d theta (G,) [rad/s per rad], drift used."""
    x = np.ascontiguousarray(samples, dtype=np.float64)
    m = x.shape[0]
    g = int(grid_points)
    kmax = int(np.floor(2 * n_max_order + 1e-9))
    if not 0.5 <= n_max_order:
        raise ValueError(f"n_max_order must be >= 0.5, got {n_max_order}")
    if kmax >= m // 2 or kmax >= g // 2:
        raise ValueError(f"n_max_order {n_max_order} needs more than {m} samples and {g} grid points per cycle "
                         f"(cycle harmonic {kmax} must stay below both Nyquist limits)")
    if not (0 <= taper_orders < n_max_order):
        raise ValueError("taper_orders must be in [0, n_max_order)")
    step = FOUR_PI / m
    ramp = _ramp(m) * step  # theta - theta_centre at the samples
    spec = np.fft.rfft(x)
    if drift is None:
        rr = np.fft.rfft(ramp)
        hi = slice(kmax + 1, None)
        w = np.full(rr.shape[0], 2.0)
        if m % 2 == 0:
            w[-1] = 1.0
        den = float(np.sum(w[hi] * np.abs(rr[hi]) ** 2))
        drift = float(np.sum(w[hi] * np.real(np.conj(rr[hi]) * spec[hi])) / den) if den > 0 else 0.0
        spec = spec - drift * rr
    else:
        spec = np.fft.rfft(x - drift * ramp)
    keep = np.zeros(g // 2 + 1, dtype=np.complex128)
    bins = np.arange(kmax + 1)
    phi0 = theta0 + 0.5 * step  # angle of sample 0
    keep[: kmax + 1] = spec[: kmax + 1] * _order_weights(kmax + 1, n_max_order, taper_orders) \
        * np.exp(-0.5j * bins * phi0) * (g / m)
    grid = np.arange(g) * (FOUR_PI / g)
    centre = theta0 + 2.0 * np.pi
    omega = np.fft.irfft(keep, n=g) + drift * (grid - centre)
    keep[: kmax + 1] *= 0.5j * bins
    domega = np.fft.irfft(keep, n=g) + drift
    return omega, domega, float(drift)


# ---- public per-cycle entry -------------------------------------------------------------------------------------------
def wheel_of(cycle: Cycle) -> tuple[int, int]:
    """(N, k) of the wheel a cycle was measured with, from its nominal tooth angles."""
    d = np.diff(cycle.tooth_angle)
    pitch = float(np.min(d))
    n = round(2 * np.pi / pitch)
    k = round(float(np.max(d)) / (2 * np.pi / n)) - 1
    return n, k


def cycle_speed(cycle: Cycle, correction: np.ndarray | None, n_max_order: float, grid_points: int = 720,
                taper_orders: float = 0.0, drift: float | None = None) -> CycleSpeed:
    """omega(theta), alpha(theta) of one cycle on the uniform grid (physics.md §14.4, §14.7).

    correction : (T,) tooth-angle errors eps_j [rad] by wheel index (``ToothSpacingLearner.correction``), or None
    n_max_order : highest engine order kept; drift: as in ``lowpass_cycle`` (None: estimated from this cycle)
    """
    n, _ = wheel_of(cycle)
    corr = None
    if correction is not None:
        eps = np.asarray(correction, dtype=np.float64)
        if eps.ndim != 1 or eps.shape[0] <= int(np.max(cycle.tooth_index)):
            raise ValueError(f"correction has {eps.shape} values; the wheel has teeth up to index "
                             f"{int(np.max(cycle.tooth_index))}")
        corr = eps[cycle.tooth_index]
    _, omega = tooth_speed(cycle.tooth_ticks, cycle.tooth_angle, cycle.tick_hz, corr)
    theta0, samples = pitch_samples(cycle.tooth_angle, omega, n)
    w, dw, b = lowpass_cycle(samples, theta0, n_max_order, grid_points, taper_orders, drift)
    # time-mean speed over exactly 4 pi from the first edge (same tooth one cycle later: tooth error cancels)
    j4 = int(np.searchsorted(cycle.tooth_angle, cycle.tooth_angle[0] + FOUR_PI - 1e-9))
    omega_mean = FOUR_PI * cycle.tick_hz / float(cycle.tooth_ticks[j4] - cycle.tooth_ticks[0])
    grid = np.arange(grid_points) * (FOUR_PI / grid_points)
    return CycleSpeed(grid, w, w * dw, omega_mean, omega_mean * 30.0 / np.pi, b)


# ---- model through the tooth averaging ------------------------------------------------------------------------------
@numba.njit(cache=True)
def _hermite_periodic(xg, yg, dyg, period_rise, xq, out):
    """Cubic Hermite on a uniform periodic grid; y rises by ``period_rise`` per period (an antiderivative)."""
    g = xg.shape[0]
    h = xg[1] - xg[0]
    span = h * g
    for i in range(xq.shape[0]):
        u = (xq[i] - xg[0]) / span
        wraps = np.floor(u)
        r = (u - wraps) * g
        j = int(r)
        if j >= g:
            j = g - 1
        s = r - j
        j1 = j + 1
        y1 = yg[j1 % g] + (period_rise if j1 == g else 0.0)
        h00 = (1.0 + 2.0 * s) * (1.0 - s) * (1.0 - s)
        h10 = s * (1.0 - s) * (1.0 - s)
        h01 = s * s * (3.0 - 2.0 * s)
        h11 = s * s * (s - 1.0)
        out[i] = h00 * yg[j] + h10 * h * dyg[j] + h01 * y1 + h11 * h * dyg[j1 % g] + wraps * period_rise


def tooth_average(theta_grid: np.ndarray, omega_model: np.ndarray,
                  tooth_angles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """What the teeth would measure of a model speed: Delta theta / integral of d theta / omega per interval.

    Parameters
    ----------
    theta_grid : (G,) uniform grid 4 pi g / G [rad] of one (periodic) cycle
    omega_model : (G,) model speed on it [rad/s], > 0
    tooth_angles : (n,) edge angles [rad], increasing (may lie outside [0, 4 pi): periodic)

    Returns theta_mid (n-1,) and omega (n-1,) like ``tooth_speed``. For omega = Omega (1 + a cos(n theta)), a << 1,
    the result is Omega (1 + a sinc(n/N) cos(n theta_mid)) (physics.md §14.4).
    """
    th = np.ascontiguousarray(theta_grid, dtype=np.float64)
    w = np.ascontiguousarray(omega_model, dtype=np.float64)
    q = np.ascontiguousarray(tooth_angles, dtype=np.float64)
    g = th.shape[0]
    if w.shape != th.shape or g < 8:
        raise ValueError("theta_grid and omega_model must be 1-D of equal length >= 8")
    if not np.allclose(th, np.arange(g) * (FOUR_PI / g) + th[0], atol=1e-9):
        raise ValueError("theta_grid must be uniform with G points over 4 pi")
    if np.any(w <= 0) or not np.all(np.isfinite(w)):
        raise ValueError("omega_model must be finite and > 0")
    if q.shape[0] < 2 or np.any(np.diff(q) <= 0):
        raise ValueError("tooth_angles must be increasing, at least two")
    slowness = 1.0 / w
    spec = np.fft.rfft(slowness)
    mean = spec[0].real / g
    m = np.arange(spec.shape[0])
    integ = np.zeros_like(spec)
    integ[1:] = spec[1:] / (0.5j * m[1:])  # antiderivative of the periodic part (harmonic m: e^{i m theta / 2})
    if g % 2 == 0:
        integ[-1] = 0.0
    t_grid = np.fft.irfft(integ, n=g) + mean * (th - th[0])
    t_at = np.empty(q.shape[0])
    _hermite_periodic(th, t_grid, slowness, mean * FOUR_PI, q, t_at)
    return 0.5 * (q[1:] + q[:-1]), np.diff(q) / np.diff(t_at)


__all__ = ["FOUR_PI", "CycleSpeed", "SpacingState", "ToothSpacingLearner", "cycle_speed", "drift_from_means",
           "engine_orders", "lowpass_cycle", "pitch_samples", "tooth_average", "tooth_speed", "wheel_of"]
