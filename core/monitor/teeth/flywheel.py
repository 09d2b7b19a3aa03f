"""Measured flywheel motion of one cycle as a Fourier series in *time*, fitted to the raw tooth times.

Why time and not angle: the harmonic-balance model (core.model.dynamics) is linear in time, not in encoder angle
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
from frictionwatch.core.monitor.teeth.flywheel_kernels import (
    BAD_SPAN,
    NOT_INCREASING,
    OK,
    fit_angles_kernel,
    prepare_fit_kernel,
    series_rows_kernel,
    tooth_update_kernel,
)

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
    """Evaluate mean + sum_m Re(X_m exp(i m 2 pi k / n)) on n uniform samples (harmonic convention of core.model.dynamics).

    coeffs (..., M) complex with M < n/2; returns (..., n)."""
    c = np.asarray(coeffs)
    m = c.shape[-1]
    if 2 * m >= n:
        raise ValueError(f"{m} harmonics need more than {2 * m} samples per cycle, got {n}")
    if c.ndim == 2 and c.dtype == np.complex128 and c.flags.c_contiguous:
        # the monitor's report: one small kernel, the same transform as below (rocket-fft runs numpy's pocketfft)
        return series_rows_kernel(c, n, float(mean))
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
    inverse of the normal matrix on unit-scaled columns and the fitted pattern harmonics.

    design_rows (p, n_edges) = design^T, C-contiguous (``design`` is its (n_edges, p) transpose view);
    scale (p,) column norms of the design; normal_inv (p, p) the inverse of the unit-scaled normal matrix."""

    tau: np.ndarray
    period: float
    omega: float
    design_rows: np.ndarray
    scale: np.ndarray
    normal_inv: np.ndarray
    n_harmonics: int
    m_fit: int
    n_drift: int
    pattern_harmonics: np.ndarray

    @property
    def design(self) -> np.ndarray:
        """(n_edges, p) design matrix [1, (u (u - 1)), cos(w_m tau)..., sin(w_m tau)...]."""
        return self.design_rows.T

    @property
    def scaled(self) -> np.ndarray:
        """(n_edges, p) design with unit-norm columns."""
        return self.design / self.scale


def prepare_fit(tooth_ticks: np.ndarray, tick_hz: float, n_harmonics: int, patterns: np.ndarray | None = None,
                fit_harmonics: int | None = None, drift: bool = True, drift_pattern: bool = False,
                pattern_period: int = 0) -> FitSetup:
    """Design, normal equations and pattern fit of the edges ``tooth_ticks`` (see ``fit_flywheel``).

    ``drift_pattern`` appends one more pattern column, the angle of a linear speed drift over the cycle,
    u (u - 1) with u = (ticks - ticks[0]) / (ticks[-1] - ticks[0]) (built in the kernel, no (n, q) copy).
    ``pattern_period`` T > 0 states that pattern row e + T equals row e (tooth patterns repeat every revolution;
    the caller checks it, e.g. with ``core.monitor.teeth.tooth_fit._revolution_period``): the fit then uses rows 0..T-1
    only and sums the design over the repeats first (half the pattern product for a two-revolution cycle; the
    results move by the rounding of the patterns' own repeat, ~1e-14)."""
    ticks = np.asarray(tooth_ticks)
    if ticks.ndim != 1:
        raise ValueError(f"tooth_ticks must be 1-D, got shape {ticks.shape}")
    n_edges = ticks.shape[0]
    m_fit = max(n_harmonics, fit_harmonics or n_harmonics)
    n_drift = 2 if drift else 1
    n_par = 2 * m_fit + n_drift
    if n_edges < n_par + 4:
        raise ValueError(f"{n_edges} tooth edges cannot carry {n_harmonics} harmonics; lower the order limit")
    if patterns is None:
        pat_in = _NO_PATTERNS[:n_edges] if n_edges <= _NO_PATTERNS.shape[0] else np.zeros((n_edges, 0))
    else:
        pat_in = np.asarray(patterns, dtype=np.float64)
        if pat_in.ndim != 2 or pat_in.shape[0] != n_edges:
            raise ValueError(f"patterns must have one row per edge ({n_edges}), got {pat_in.shape[0]}")
        if pattern_period:
            if not 0 < pattern_period <= n_edges:
                raise ValueError(f"pattern_period must be in 1..{n_edges}, got {pattern_period}")
            pat_in = pat_in[:pattern_period]
        if not pat_in.flags.c_contiguous:
            pat_in = np.ascontiguousarray(pat_in)
    if not ticks.flags.c_contiguous:
        ticks = np.ascontiguousarray(ticks)
    tau = np.empty(n_edges)
    design_rows = np.empty((n_par, n_edges))
    scale = np.empty(n_par)
    normal_inv = np.empty((n_par, n_par))
    pat = np.empty((n_harmonics, pat_in.shape[1] + (1 if drift_pattern else 0)), dtype=np.complex128)
    try:
        status = prepare_fit_kernel(ticks, float(tick_hz), n_drift, m_fit, n_harmonics, pat_in,
                                    int(pattern_period) if patterns is not None else 0, bool(drift_pattern),
                                    (tau, design_rows, scale, normal_inv), pat)
    except np.linalg.LinAlgError as exc:
        raise ValueError(f"the tooth edges give a singular flywheel fit ({exc})") from exc
    if status == NOT_INCREASING:
        raise ValueError("tooth times and angles must be strictly increasing")
    if status != OK:
        raise ValueError("the tooth edges give a singular flywheel fit")
    period = float(tau[-1])
    return FitSetup(tau, period, FOUR_PI / period, design_rows, scale, normal_inv, n_harmonics, m_fit, n_drift, pat)


_NO_PATTERNS = np.zeros((4096, 0))  # a C-contiguous (n, 0) for fits without patterns


def fit_prepared(setup: FitSetup, tooth_angle: np.ndarray) -> FlywheelMotion:
    """Fit the edge angles ``tooth_angle`` (n_edges,) [rad] on a prepared design (``prepare_fit``)."""
    ang = np.asarray(tooth_angle, dtype=np.float64)
    tau = setup.tau
    if ang.shape != tau.shape:
        raise ValueError(f"tooth_ticks and tooth_angle must be 1-D of equal length, got {tau.shape}, {ang.shape}")
    if not ang.flags.c_contiguous:
        ang = np.ascontiguousarray(ang)
    harm = np.empty(setup.n_harmonics, dtype=np.complex128)
    resid = np.empty(tau.shape[0])
    status, offset, drift, rms = fit_angles_kernel(setup.design_rows, setup.scale, setup.normal_inv, tau, setup.omega, ang,
                                             setup.n_drift, setup.m_fit, harm, resid)
    if status == NOT_INCREASING:
        raise ValueError("tooth times and angles must be strictly increasing")
    if status == BAD_SPAN:
        raise ValueError(f"the edges must span one 720 deg cycle, got {np.degrees(ang[-1] - ang[0]):.3f} deg")
    return FlywheelMotion(
        period=setup.period,
        omega_mean=setup.omega,
        harmonics=harm,
        offset=offset,
        drift=drift,
        residual_rms=rms,
        n_edges=tau.shape[0],
        edge_residual=resid,
        pattern_harmonics=setup.pattern_harmonics,
    )


@dataclass(frozen=True)
class LearnerSettings:
    """How the tooth learner steps (MonitorConfig.tooth_learning): ``learn`` at all; EWMA factor ``memory``; refit
    with the fresh correction for the first ``refit_cycles``; skip a cycle whose mean speed moved more than
    ``speed_step`` (relative) from the last fitted cycle's (design note 60; inf: never)."""

    learn: bool
    memory: float
    refit_cycles: int
    speed_step: float = float("inf")


@dataclass(frozen=True)
class ToothLearner:
    """On-line estimate of the tooth-spacing error above the fitted band (physics.md §14.3).

    The fit residual at an edge is its tooth's angle error minus what the in-band harmonics absorbed, plus timing
    noise. Averaged per wheel position over many revolutions (both revolutions of a cycle, so half orders of the
    engine cancel) it converges to the out-of-band part of the pattern, which is then added to the nominal angles.
    The in-band part cannot be told from the engine's own steady response at one operating point; the identification
    carries it as nuisance parameters. ``correction`` (wheel positions,) [rad], ``count`` cycles folded in,
    ``period`` [s] the last fitted cycle's period, learnt from or not (0: none yet): a cycle whose mean speed moved
    beyond ``MonitorConfig.tooth_speed_step`` from it is not folded in (core.monitor.teeth.tooth_fit).
    """

    correction: np.ndarray
    count: int
    period: float = 0.0

    @staticmethod
    def empty(wheel_positions: int) -> ToothLearner:
        return ToothLearner(np.zeros(wheel_positions), 0)

    def update(self, tooth_index: np.ndarray, residual: np.ndarray, memory: float) -> ToothLearner:
        """Fold in one cycle's edge residuals (the closing edge, a repeat of the first position, is ignored)."""
        idx = np.asarray(tooth_index)
        r = np.asarray(residual, dtype=np.float64)
        if idx.shape != r.shape or idx.ndim != 1:
            raise ValueError(f"tooth_index and residual must be 1-D of equal length, got {idx.shape}, {r.shape}")
        gain = max(1.0 - memory, 1.0 / (self.count + 1))
        return ToothLearner(tooth_update_kernel(self.correction, idx, r, gain), self.count + 1, self.period)
