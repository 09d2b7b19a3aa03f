"""Measured flywheel motion of one cycle as a Fourier series in *time*, fitted to the raw tooth times.

Why time and not angle: the harmonic-balance model (core.dynamics) is linear in time, not in encoder angle
(physics.md §12.3 item 3). Fitting the tooth edges (t_j, theta_j) directly gives the angle deviation
phi(tau) = theta(tau) - theta_0 - Omega tau as harmonics of the cycle period, with no differentiation of noisy
intervals and no tooth-interval (sinc) averaging to undo (physics.md §14.4): the model is compared with what the
teeth measured, exactly.

    phi(tau) = c_0 + c_1 q(u) + sum_{m=1..M} Re(Phi_m exp(i w_m tau)),  u = tau/T,  q(u) = u (u - 1),

q is a nuisance that carries a linear speed drift over the cycle (cycle-to-cycle variability and load changes make a
single cycle non-periodic; physics.md §14.7). The speed drift over the cycle is Delta omega = 2 c_1 / T.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from core.flywheel_kernels import _fit_design

FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class FlywheelMotion:
    """Fitted flywheel angle over one cycle.

    period        T [s]; omega_mean = 4 pi / T [rad/s]
    harmonics     (M,) complex Phi_m [rad], angle-deviation harmonics (speed harmonics are i w_m Phi_m)
    offset        c_0 [rad]; drift c_1 [rad] (coefficient of q(u) = u(u-1))
    residual_rms  rms of the fit residual over the teeth [rad] (timing noise + tooth-spacing error + high orders)
    n_edges       number of tooth edges used
    edge_residual (n_edges,) fit residual at each edge [rad] (for learning the tooth-spacing pattern)
    pattern_harmonics (M, q) complex: fitted harmonics of the optional angle patterns (see ``fit_flywheel``)
    """

    period: float
    omega_mean: float
    harmonics: np.ndarray
    offset: float
    drift: float
    residual_rms: float
    n_edges: int
    edge_residual: np.ndarray
    pattern_harmonics: np.ndarray

    @property
    def n_harmonics(self) -> int:
        return int(self.harmonics.shape[0])

    @property
    def freq(self) -> np.ndarray:
        return 0.5 * self.omega_mean * np.arange(1, self.n_harmonics + 1)

    @property
    def speed_harmonics(self) -> np.ndarray:
        """(M,) complex speed harmonics [rad/s]."""
        return 1j * self.freq * self.harmonics

    @property
    def speed_drift(self) -> float:
        """End-minus-start speed change over the cycle from the drift term [rad/s]."""
        return 2.0 * self.drift / self.period

    def on_grid(self, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Uniform time grid tau_i = i T / n and the angle deviation phi, speed omega, acceleration alpha there.

        Returns tau (n,) [s], phi (n,) [rad], omega (n,) [rad/s], alpha (n,) [rad/s^2]."""
        tau = np.arange(n) * (self.period / n)
        u = tau / self.period
        phi = self.offset + self.drift * u * (u - 1.0) + harmonic_series(self.harmonics, n)
        w = self.freq
        omega = (self.omega_mean + self.drift * (2.0 * u - 1.0) / self.period
                 + harmonic_series(1j * w * self.harmonics, n))
        alpha = 2.0 * self.drift / self.period**2 + harmonic_series(-(w**2) * self.harmonics, n)
        return tau, phi, omega, alpha


def harmonic_series(coeffs: np.ndarray, n: int, mean: float = 0.0) -> np.ndarray:
    """Evaluate mean + sum_m Re(X_m exp(i m 2 pi k / n)) on n uniform samples (harmonic convention of core.dynamics).

    coeffs (..., M) complex with M < n/2; returns (..., n)."""
    c = np.asarray(coeffs)
    m = c.shape[-1]
    if 2 * m >= n:
        raise ValueError(f"{m} harmonics need more than {2 * m} samples per cycle, got {n}")
    spec = np.zeros(c.shape[:-1] + (n // 2 + 1,), dtype=np.complex128)
    spec[..., 1 : m + 1] = c * (0.5 * n)
    out = np.fft.irfft(spec, n=n, axis=-1)
    return out + mean


def harmonics_of(x: np.ndarray, n_harmonics: int) -> np.ndarray:
    """Harmonics X_1..X_M (..., M) of uniformly sampled periodic signals x (..., n): X_m = 2 rfft(x)[m] / n."""
    a = np.asarray(x, dtype=np.float64)
    n = a.shape[-1]
    if 2 * n_harmonics >= n:
        raise ValueError(f"{n_harmonics} harmonics need more than {2 * n_harmonics} samples, got {n}")
    return np.fft.rfft(a, axis=-1)[..., 1 : n_harmonics + 1] * (2.0 / n)


def fit_flywheel(
    tooth_ticks: np.ndarray,
    tick_hz: float,
    tooth_angle: np.ndarray,
    n_harmonics: int,
    patterns: np.ndarray | None = None,
    fit_harmonics: int | None = None,
    drift: bool = True,
) -> FlywheelMotion:
    """Least-squares Fourier fit of the tooth edges of one cycle.

    Parameters
    ----------
    tooth_ticks : (m+1,) int64 edge times, first edge at the cycle start, last the closing edge 4 pi later
    tick_hz : timer clock [Hz]
    tooth_angle : (m+1,) edge angles [rad], increasing, spanning exactly 4 pi (apply any learned tooth-spacing
        correction before calling)
    n_harmonics : M, harmonics of the cycle (engine orders 0.5 .. M/2)
    patterns : (m+1, q) optional angle patterns at the edges [rad per unit]; the same fit is applied to each, so
        ``pattern_harmonics`` (M, q) is exactly how an angle error of that shape moves the fitted harmonics (used
        for the tooth-spacing nuisance: fixed in angle, it is not a pure time harmonic when the speed ripples)
    fit_harmonics : harmonics fitted (>= n_harmonics; default n_harmonics). Fitting strong content just above the
        band keeps it from leaking into the band through the uneven edge spacing; only n_harmonics are returned
    drift : fit the q(u) drift term (it is nearly collinear with order 0.5 over one cycle)

    The work splits in ``prepare_fit`` (everything that depends on the edge times only) and ``fit_prepared`` (the
    angles); refitting the same edges with corrected angles reuses the first.
    """
    ang = np.asarray(tooth_angle, dtype=np.float64)
    ticks = np.asarray(tooth_ticks)
    if ticks.ndim != 1 or ticks.shape != ang.shape:
        raise ValueError(f"tooth_ticks and tooth_angle must be 1-D of equal length, got {ticks.shape}, {ang.shape}")
    return fit_prepared(prepare_fit(ticks, tick_hz, n_harmonics, patterns, fit_harmonics, drift), ang)


@dataclass(frozen=True)
class FitSetup:
    """The angle-independent part of one cycle's flywheel fit (``prepare_fit``): time grid, design matrix, the
    factored normal equations on unit-scaled columns and the fitted pattern harmonics."""

    tau: np.ndarray
    period: float
    omega: float
    design: np.ndarray
    scale: np.ndarray
    scaled: np.ndarray
    factor: tuple[np.ndarray, np.ndarray]
    n_harmonics: int
    m_fit: int
    n_drift: int
    pattern_harmonics: np.ndarray


def prepare_fit(tooth_ticks: np.ndarray, tick_hz: float, n_harmonics: int, patterns: np.ndarray | None = None,
                fit_harmonics: int | None = None, drift: bool = True) -> FitSetup:
    """Design, normal equations and pattern fit of the edges ``tooth_ticks`` (see ``fit_flywheel``)."""
    ticks = np.asarray(tooth_ticks)
    if ticks.ndim != 1:
        raise ValueError(f"tooth_ticks must be 1-D, got shape {ticks.shape}")
    n_edges = ticks.shape[0]
    m_fit = max(n_harmonics, fit_harmonics or n_harmonics)
    n_drift = 2 if drift else 1
    n_par = 2 * m_fit + n_drift
    if n_edges < n_par + 4:
        raise ValueError(f"{n_edges} tooth edges cannot carry {n_harmonics} harmonics; lower the order limit")
    if np.any(np.diff(ticks) <= 0):
        raise ValueError("tooth times and angles must be strictly increasing")
    tau = (ticks - ticks[0]).astype(np.float64) / tick_hz  # exact integer differences, then seconds
    period = float(tau[-1])
    omega = FOUR_PI / period
    design = np.empty((n_edges, n_par))
    _fit_design(tau, period, 0.5 * omega, n_drift, m_fit, design)
    # normal equations on unit-scaled columns: the Fourier columns are nearly orthogonal over the edges, so this is
    # well conditioned and ~10x cheaper than an SVD least squares
    scale = np.sqrt(np.einsum("ij,ij->j", design, design))
    d = design / scale
    factor = scipy.linalg.lu_factor(d.T @ d, check_finite=False)
    c0, s0 = n_drift, n_drift + m_fit
    if patterns is None or np.shape(patterns)[-1] == 0:
        pat = np.zeros((n_harmonics, 0), dtype=np.complex128)
    else:
        p = np.asarray(patterns, dtype=np.float64)
        if p.ndim != 2 or p.shape[0] != n_edges:
            raise ValueError(f"patterns must have one row per edge ({n_edges}), got {p.shape[0]}")
        sol = scipy.linalg.lu_solve(factor, d.T @ p, check_finite=False) / scale[:, None]
        pat = sol[c0 : c0 + n_harmonics] - 1j * sol[s0 : s0 + n_harmonics]
    return FitSetup(tau, period, omega, design, scale, d, factor, n_harmonics, m_fit, n_drift, pat)


def fit_prepared(setup: FitSetup, tooth_angle: np.ndarray) -> FlywheelMotion:
    """Fit the edge angles ``tooth_angle`` (n_edges,) [rad] on a prepared design (``prepare_fit``)."""
    ang = np.asarray(tooth_angle, dtype=np.float64)
    tau = setup.tau
    if ang.shape != tau.shape:
        raise ValueError(f"tooth_ticks and tooth_angle must be 1-D of equal length, got {tau.shape}, {ang.shape}")
    if np.any(np.diff(ang) <= 0):
        raise ValueError("tooth times and angles must be strictly increasing")
    span = ang[-1] - ang[0]
    if abs(span - FOUR_PI) > 1e-6:
        raise ValueError(f"the edges must span one 720 deg cycle, got {np.degrees(span):.3f} deg")
    phi = ang - ang[0] - setup.omega * tau
    coef = scipy.linalg.lu_solve(setup.factor, setup.scaled.T @ phi, check_finite=False) / setup.scale
    resid = phi - setup.design @ coef
    m = setup.n_harmonics
    c0, s0 = setup.n_drift, setup.n_drift + setup.m_fit
    return FlywheelMotion(
        period=setup.period,
        omega_mean=float(setup.omega),
        harmonics=coef[c0 : c0 + m] - 1j * coef[s0 : s0 + m],
        offset=float(coef[0]),
        drift=float(coef[1]) if setup.n_drift == 2 else 0.0,
        residual_rms=float(np.sqrt(np.mean(resid**2))),
        n_edges=int(tau.shape[0]),
        edge_residual=resid,
        pattern_harmonics=setup.pattern_harmonics,
    )


@dataclass(frozen=True)
class ToothLearner:
    """On-line estimate of the tooth-spacing error above the fitted band (physics.md §14.3).

    The fit residual at an edge is its tooth's angle error minus what the in-band harmonics absorbed, plus timing
    noise. Averaged per wheel position over many revolutions (both revolutions of a cycle, so half orders of the
    engine cancel) it converges to the out-of-band part of the pattern, which is then added to the nominal angles.
    The in-band part cannot be told from the engine's own steady response at one operating point; the identification
    carries it as nuisance parameters. ``correction`` (wheel positions,) [rad], ``count`` cycles seen.
    """

    correction: np.ndarray
    count: int

    @staticmethod
    def empty(wheel_positions: int) -> ToothLearner:
        return ToothLearner(np.zeros(wheel_positions), 0)

    def update(self, tooth_index: np.ndarray, residual: np.ndarray, memory: float) -> ToothLearner:
        """Fold in one cycle's edge residuals (the closing edge, a repeat of the first position, is ignored)."""
        n = self.correction.shape[0]
        pos = np.asarray(tooth_index[:-1]) % n
        r = np.asarray(residual[:-1])
        total = np.bincount(pos, weights=r, minlength=n)
        hits = np.bincount(pos, minlength=n)
        seen = hits > 0
        g = max(1.0 - memory, 1.0 / (self.count + 1))
        c = self.correction.copy()
        # an edge whose tooth sits eps further than assumed is reached later: its residual is -(eps - correction)
        c[seen] -= g * total[seen] / hits[seen]
        c[seen] -= c[seen].mean()  # tooth errors sum to zero over a revolution
        return ToothLearner(c, self.count + 1)
