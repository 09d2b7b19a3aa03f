"""The drive train identified from both wheels' speed spectra (issue 29 item 2): a stiffness and a damping scale of
the shaft line with their sigmas, and what they say of its first torsional mode.

Data: cycles of running with a second wheel (``CycleResult.chain``, ``CycleResult.free_end``). The excitation is
what the monitor's balance already put through its chain every cycle (gas, mass and friction torques at each node,
``ChainSample.torque``). A chain whose sections' stiffnesses are x kappa and dampings x delta (core.model.chain; the
ground terms of the load stay) answers with the speeds W_q = i w_m [Z_m(kappa, delta)^-1 T]_q at the flywheel and at
the free end; kappa and delta are fitted (Gauss-Newton in their logarithms) to the cycles' mean of measured minus
modelled speed at the **half orders** of both wheels. Integer orders are left out: there each wheel's in-band
tooth-spacing errors are as large as the engine's response and this fit carries no parameters for them.

The noise of a row (a harmonic at one wheel), each part for a reason:
- the standard error of the cycles' mean (their scatter over sqrt(n)): combustion variability, timing noise;
- the leak of that wheel's in-band tooth errors into the half order (its patterns through its own fit,
  ``pattern_harmonics``, times the rms Fourier coefficient of white tooth errors of ``tooth_error_deg``, as the
  monitor's prior has it): fixed in angle, seen in time on a rippling shaft; repeatable, so it does not average down
  (bench/drive_train_model_error.py: up to half of the free end's small harmonics at orders 7.5-8.5 on genset-v20);
- the model floor ``model_rel_error`` of the harmonic, the monitor's own budget for what its chain leaves out.

chi^2 over the rows' degrees of freedom says whether two scales explain both wheels. A fit beyond the 0.1 % tail of
chi^2 is ``poor``: the chain is wrong in a way two scales cannot represent (one section's stiffness, an inertia), and
its scales are not to be applied. The sigmas come from the curvature, times sqrt(chi^2/dof) where that exceeds 1,
with a floor for what the model leaves out (STIFFNESS_FLOOR, DAMPING_FLOOR).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np
import scipy.linalg
import scipy.stats
from frictionwatch.core.model.dynamics import dynamic_stiffness, shaft_model
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.identify.parameters import tooth_coefficient_sigma
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned

_TUNED = read_tuned(MONITOR_RECORD)  # the floors and SETTLED, hand-set, with their provenance (core.tuned)

POOR_FIT_TAIL = 1e-3  # a chi^2 beyond this upper tail of its distribution is a poor fit (a 1-in-1000 false alarm)
# What the curvature's sigma leaves out, relative, added in quadrature: the largest error of a good fit seen on
# genset-v20 seeds 7 and 11 (bench/drive_train_identification.py, rounds settled: damping 1.986 against 2, stiffness
# 1.1489 against 1.15); validated on seed 13 (largest there: damping 1.993 against 2, stiffness 1.1498 against 1.15).
STIFFNESS_FLOOR = _TUNED["DRIVE_TRAIN_STIFFNESS_FLOOR"].value
DAMPING_FLOOR = _TUNED["DRIVE_TRAIN_DAMPING_FLOOR"].value
# rounds stop when a round's correction is within this part of its sigma (1 left the damping 0.5 %
# short and chi2 81-85 on 46 dof on seeds 11 and 13, stiffness 0.85; 0.2: chi2 10-22, damping within 0.3 %)
SETTLED = _TUNED["DRIVE_TRAIN_SETTLED"].value
MIN_FLEXIBLE_HZ = 5.0  # the first flexible mode: above the rigid and the grid's electromechanical mode


@dataclass(frozen=True)
class DriveTrainData:
    """Cycles for the identification (SI): omega (n,) mean speed [rad/s]; torque (n, N, M) complex node torques
    [N m]; speed (2, n, M) complex measured speed harmonics [rad/s] at the flywheel [0] and the free end [1], both
    referred to the flywheel window's first edge; leak_var (2, n, M) the tooth-pattern leak variance of each
    [rad^2/s^2]; load_torque the cycles' mean load [N m]."""

    omega: np.ndarray
    torque: np.ndarray
    speed: np.ndarray
    leak_var: np.ndarray
    load_torque: float

    @property
    def n_cycles(self) -> int:
        return int(self.omega.shape[0])


@dataclass(frozen=True)
class ModeFigures:
    """The flexible modes of a chain within the band the spectra see (above MIN_FLEXIBLE_HZ, up to the highest
    harmonic used), each (K,): natural frequency [Hz], mode shape free end / flywheel (the ratio of their
    amplitudes in the undamped mode, signed), modal damping ratio."""

    frequency_hz: np.ndarray
    shape_ratio: np.ndarray
    damping_ratio: np.ndarray


@dataclass(frozen=True)
class DriveTrainFit:
    """The identified scales (relative to the chain the monitor ran with) and their 1-sigma; the mode of the
    identified chain with 1-sigma (``mode``, ``mode_sigma``) and of the one the monitor ran with (``mode_before``);
    chi2 over dof and its upper-tail probability, ``poor`` when beyond POOR_FIT_TAIL; per row (wheel 0 flywheel /
    1 free end, harmonic index j: order (j + 1) / 2) the mean residual in % of the measured harmonic and in its
    noise (sigma) before (the monitor's chain) and after; n cycles; rounds of the iteration
    (``identify_iteratively``)."""

    stiffness_scale: float
    stiffness_sigma: float
    damping_scale: float
    damping_sigma: float
    mode: ModeFigures
    mode_sigma: ModeFigures
    mode_before: ModeFigures
    chi2: float
    dof: int
    tail: float
    poor: bool
    orders: np.ndarray
    residual_pct_before: np.ndarray
    residual_pct_after: np.ndarray
    residual_sigmas_before: np.ndarray
    residual_sigmas_after: np.ndarray
    cycles: int
    rounds: int = 1

    @property
    def words(self) -> str:
        text = (f"drive train from {self.cycles} cycles of both wheels ({self.rounds} round(s)): stiffness x "
                f"{self.stiffness_scale:.3f} +- {self.stiffness_sigma:.3f}, damping x {self.damping_scale:.2f} +- "
                f"{self.damping_sigma:.2f}; modes " + ", ".join(
                    f"{f:.1f} +- {sf:.1f} Hz (model {f0:.1f}, free end / flywheel {r:+.2f}, damping ratio {z:.3f})"
                    for f, sf, f0, r, z in zip(self.mode.frequency_hz, self.mode_sigma.frequency_hz,
                                               self.mode_before.frequency_hz, self.mode.shape_ratio,
                                               self.mode.damping_ratio, strict=False))
                + f"; chi2 {self.chi2:.1f} on {self.dof} dof")
        if self.poor:
            text += (f": a poor fit (tail {self.tail:.1e}): two scales of the whole shaft line do not explain both "
                     "wheels (one section or an inertia off?); the scales are not to be applied")
        return text

    def to_dict(self) -> dict:
        return {"stiffness_scale": self.stiffness_scale, "stiffness_scale_sigma": self.stiffness_sigma,
                "damping_scale": self.damping_scale, "damping_scale_sigma": self.damping_sigma,
                "modes_hz": self.mode.frequency_hz.tolist(), "modes_hz_sigma": self.mode_sigma.frequency_hz.tolist(),
                "modes_hz_before": self.mode_before.frequency_hz.tolist(),
                "mode_shape_free_end_over_flywheel": self.mode.shape_ratio.tolist(),
                "mode_shape_sigma": self.mode_sigma.shape_ratio.tolist(),
                "modal_damping_ratio": self.mode.damping_ratio.tolist(),
                "modal_damping_sigma": self.mode_sigma.damping_ratio.tolist(),
                "chi2": self.chi2, "dof": self.dof, "chi2_tail": self.tail, "poor_fit": self.poor,
                "cycles": self.cycles, "rounds": self.rounds, "words": self.words,
                "orders": self.orders.tolist(),
                "residual_pct_before": {"flywheel": self.residual_pct_before[0].tolist(),
                                        "free_end": self.residual_pct_before[1].tolist()},
                "residual_pct_after": {"flywheel": self.residual_pct_after[0].tolist(),
                                       "free_end": self.residual_pct_after[1].tolist()},
                "residual_sigmas_before": {"flywheel": self.residual_sigmas_before[0].tolist(),
                                           "free_end": self.residual_sigmas_before[1].tolist()},
                "residual_sigmas_after": {"flywheel": self.residual_sigmas_after[0].tolist(),
                                          "free_end": self.residual_sigmas_after[1].tolist()}}


def drive_train_data(spec: EngineSpec, results: Sequence, tooth_error_deg: float) -> DriveTrainData:
    """The cycles of ``results`` (CycleResults of a monitor with a second wheel) that carry both wheels; the leak
    variances from each wheel's patterns and white tooth errors of rms ``tooth_error_deg`` (module doc)."""
    used = [r for r in results if getattr(r, "chain", None) is not None and r.free_end is not None
            and r.free_end.pattern_harmonics is not None]
    if len(used) < 3:
        raise ValueError(f"the drive train needs cycles with both wheels; {len(used)} of {len(results)} have them")
    wheel2 = spec.sensors.second_wheel
    edges = (spec.sensors.wheel_teeth - spec.sensors.wheel_missing,
             wheel2.teeth - wheel2.missing if wheel2 is not None else 1)
    omega = np.array([r.omega_mean for r in used])
    m = used[0].chain.flywheel.shape[0]
    w = 0.5 * omega[:, None] * np.arange(1, m + 1)[None, :]
    fly = np.array([r.chain.flywheel for r in used])
    free = np.array([r.free_end.harmonics_at(0.0) for r in used]) * 1j * w
    leak = np.empty((2, len(used), m))
    for i, patterns in enumerate(([r.chain.flywheel_patterns for r in used],
                                  [r.free_end.pattern_harmonics for r in used])):
        coef_var = tooth_coefficient_sigma(tooth_error_deg, edges[i]) ** 2
        leak[i] = w**2 * coef_var * np.array([np.sum(np.abs(p) ** 2, axis=1) for p in patterns])
    load = np.array([r.load_torque for r in used])
    return DriveTrainData(omega, np.array([r.chain.torque for r in used]), np.stack([fly, free]), leak,
                          float(np.nanmean(load)) if np.isfinite(load).any() else 0.0)


def scaled_spec(spec: EngineSpec, stiffness_scale: float, damping_scale: float) -> EngineSpec:
    """``spec`` with every section's stiffness and damping scaled (the chain_mismatch effect's view)."""
    return replace(spec, stiffness=spec.stiffness * stiffness_scale, damping=spec.damping * damping_scale)


class _Chain:
    """The chain's parts, sections apart from the ground terms: Z = kappa K_s + K_g - w^2 M + i w (delta C_s + C_g)."""

    def __init__(self, spec: EngineSpec, data: DriveTrainData):
        if spec.n_nodes < 2 or spec.sensors.second_wheel is None:
            raise ValueError(f"{spec.name}: the drive train needs a flexible shaft line and a second wheel on it")
        omega = float(np.mean(data.omega))
        shaft = shaft_model(spec, data.load_torque, omega)
        if data.torque.shape[1] != shaft.n_nodes:
            raise ValueError(f"the monitor ran a chain of {data.torque.shape[1]} node(s), {spec.name}'s has "
                             f"{shaft.n_nodes}: the drive train needs torsional flexibility on")
        _, self.k_sec, self.c_sec = shaft.train.matrices()
        self.k_gnd = shaft.stiffness - self.k_sec
        self.c_gnd = shaft.damping - self.c_sec
        self.shaft = shaft
        self.nodes = (shaft.flywheel, spec.sensors.second_wheel.node)
        m = data.torque.shape[2]
        self.w = 0.5 * data.omega[:, None] * np.arange(1, m + 1)[None, :]  # (n, M)
        self.torque = np.transpose(data.torque, (0, 2, 1))  # (n, M, N)

    def speeds(self, kappa: float, delta: float) -> np.ndarray:
        """(2, n, M) modelled speed harmonics at the flywheel and the free end."""
        base = replace(self.shaft, stiffness=kappa * self.k_sec + self.k_gnd, damping=delta * self.c_sec + self.c_gnd)
        n, m = self.w.shape
        z = dynamic_stiffness(base, self.w.ravel()).reshape(n, m, *self.k_sec.shape)
        phi = np.linalg.solve(z, self.torque[..., None])[..., 0]  # (n, M, N)
        return np.stack([1j * self.w * phi[:, :, q] for q in self.nodes])

    def mode(self, kappa: float, delta: float, top_hz: float) -> ModeFigures:
        """The modes between MIN_FLEXIBLE_HZ and ``top_hz`` (the same count for nearby scales: the caller's
        ``top_hz`` is set with margin)."""
        k = kappa * self.k_sec + self.k_gnd
        mass = np.diag(self.shaft.mass)
        lam, vec = scipy.linalg.eigh(k, mass)
        f = np.sqrt(np.clip(lam, 0.0, None)) / (2.0 * np.pi)
        idx = np.flatnonzero((f > MIN_FLEXIBLE_HZ) & (f <= top_hz))
        v = vec[:, idx]
        c = delta * self.c_sec + self.c_gnd
        zeta = np.einsum("ik,ij,jk->k", v, c, v) / (4.0 * np.pi * f[idx] * np.einsum("ik,ij,jk->k", v, mass, v))
        fly, free = self.nodes
        return ModeFigures(f[idx], v[free] / v[fly], zeta)


def identify_drive_train(spec: EngineSpec, data: DriveTrainData, model_rel_error: float,
                         max_order: float = np.inf, iterations: int = 20) -> DriveTrainFit:
    """Stiffness and damping scales of ``spec``'s chain from ``data`` (module doc); model_rel_error the floor of
    each row relative to its harmonic (MonitorConfig.model_rel_error); max_order the highest half order used."""
    chain = _Chain(spec, data)
    m = data.speed.shape[2]
    half = np.arange(0, m, 2)
    half = half[(half + 1) / 2.0 <= max_order]
    if half.size < 2:
        raise ValueError("the drive train needs at least two half orders")
    meas = data.speed[:, :, half]  # (2, n, H)
    n = data.n_cycles
    mean_meas = meas.mean(axis=1)

    def resid(x: np.ndarray) -> np.ndarray:
        return meas - chain.speeds(math.exp(x[0]), math.exp(x[1]))[:, :, half]

    r0 = resid(np.zeros(2))
    # the row noise at the monitor's chain: scatter (the same for any chain near it), leak and floor
    scatter = (np.var(r0.real, axis=1) + np.var(r0.imag, axis=1)) / n
    var = scatter + data.leak_var[:, :, half].mean(axis=1) + (model_rel_error * np.abs(mean_meas)) ** 2
    inv = 1.0 / np.sqrt(np.maximum(var, 1e-30))

    def whitened(x: np.ndarray) -> np.ndarray:
        r = resid(x).mean(axis=1) * inv  # (2, H) complex, each part of variance 1/2
        return math.sqrt(2.0) * np.concatenate([r.real.ravel(), r.imag.ravel()])

    x = np.zeros(2)
    y = whitened(x)
    step = 1e-4
    for _ in range(iterations):
        jac = np.column_stack([(whitened(x + step * e) - y) / step for e in np.eye(2)])
        dx = -np.linalg.lstsq(jac, y, rcond=None)[0]
        dx = np.clip(dx, -0.5, 0.5)  # at most a factor 1.65 a step: the chain's response is far from linear
        for _ in range(10):  # halve a step that does not lower chi^2
            y_new = whitened(x + dx)
            if y_new @ y_new <= y @ y:
                break
            dx = 0.5 * dx
        else:
            break
        x, y = x + dx, y_new
        if np.max(np.abs(dx)) < 1e-6:
            break
    jac = np.column_stack([(whitened(x + step * e) - y) / step for e in np.eye(2)])
    chi2 = float(y @ y)
    dof = y.size - 2
    tail = float(scipy.stats.chi2.sf(chi2, dof))
    cov = np.linalg.inv(jac.T @ jac) * max(1.0, chi2 / dof) + np.diag([STIFFNESS_FLOOR**2, DAMPING_FLOOR**2])
    kappa, delta = math.exp(x[0]), math.exp(x[1])
    sig_log = np.sqrt(np.diag(cov))
    # the modes the spectra see: up to the highest harmonic used, with margin (mode counts must not change with
    # the small steps of the sigma's gradient)
    top_hz = 1.1 * float(np.max(data.omega)) * (half[-1] + 1) / (4.0 * np.pi)
    before = chain.mode(1.0, 1.0, top_hz)
    mode = chain.mode(kappa, delta, top_hz)
    k = min(mode.frequency_hz.size, before.frequency_hz.size)  # a mode that crossed the band's edge: left out
    mode, before = (ModeFigures(*(a[:k] for a in (f.frequency_hz, f.shape_ratio, f.damping_ratio)))
                    for f in (mode, before))
    mode_sigma = _mode_sigma(chain, x, cov, mode, top_hz)
    r1 = resid(x).mean(axis=1)
    pct0, pct1 = 100 * np.abs(r0.mean(axis=1)) / np.abs(mean_meas), 100 * np.abs(r1) / np.abs(mean_meas)
    sd = np.sqrt(var)
    return DriveTrainFit(kappa, kappa * sig_log[0], delta, delta * sig_log[1], mode, mode_sigma, before, chi2, dof,
                         tail, tail < POOR_FIT_TAIL, (half + 1) / 2.0, pct0, pct1, np.abs(r0.mean(axis=1)) / sd,
                         np.abs(r1) / sd, n)


def identify_iteratively(spec: EngineSpec, results_for: Callable[[EngineSpec], Sequence], tooth_error_deg: float,
                         model_rel_error: float, rounds: int = 6, skip: int = 30, max_order: float = np.inf
                         ) -> DriveTrainFit:
    """The drive train of ``spec`` from the cycles ``results_for(chain)`` gives (the same records through the
    monitor running with ``chain``), in rounds: the excitation a chain's balance computes depends on that chain (the
    twist moves the throws' gas and mass torques), so each round's monitor runs with the chain the round before
    identified, until a round's correction is within SETTLED of its sigma (or ``rounds``). The fit is the last round's,
    its scales and sigmas relative to ``spec``, its "before" residuals and mode those of ``spec``'s chain; ``skip``
    the first cycles of each run (the monitor's cold start)."""
    kappa = delta = 1.0
    first = fit = None
    done = 0
    for _ in range(rounds):
        done += 1
        chain = scaled_spec(spec, kappa, delta)
        results = list(results_for(chain))[skip:]
        fit = identify_drive_train(chain, drive_train_data(chain, results, tooth_error_deg), model_rel_error,
                                   max_order)
        first = first or fit
        kappa, delta = kappa * fit.stiffness_scale, delta * fit.damping_scale
        # settled when a round moves the scales by a small part of their sigmas (the floors are most of those)
        settled = (abs(fit.stiffness_scale - 1.0) <= SETTLED * fit.stiffness_sigma
                   and abs(fit.damping_scale - 1.0) <= SETTLED * fit.damping_sigma)
        if settled:
            break
    scale_k, scale_d = kappa / fit.stiffness_scale, delta / fit.damping_scale  # the last round's chain
    return replace(fit, stiffness_scale=kappa, stiffness_sigma=scale_k * fit.stiffness_sigma, damping_scale=delta,
                   damping_sigma=scale_d * fit.damping_sigma, mode_before=first.mode_before,
                   residual_pct_before=first.residual_pct_before, residual_sigmas_before=first.residual_sigmas_before,
                   rounds=done)


def _mode_sigma(chain: _Chain, x: np.ndarray, cov: np.ndarray, mode: ModeFigures, top_hz: float) -> ModeFigures:
    """1-sigma of the mode figures through their numerical gradient in (log kappa, log delta)."""
    base = np.concatenate([mode.frequency_hz, mode.shape_ratio, mode.damping_ratio])
    grad = np.empty((base.size, 2))
    for i, e in enumerate(np.eye(2)):
        xi = x + 1e-5 * e
        mi = chain.mode(math.exp(xi[0]), math.exp(xi[1]), top_hz * 1.01)
        k = mode.frequency_hz.size
        grad[:, i] = (np.concatenate([mi.frequency_hz[:k], mi.shape_ratio[:k], mi.damping_ratio[:k]]) - base) / 1e-5
    s = np.sqrt(np.einsum("ij,jk,ik->i", grad, cov, grad)).reshape(3, -1)
    return ModeFigures(s[0], s[1], s[2])


__all__ = ["POOR_FIT_TAIL", "DriveTrainData", "DriveTrainFit", "ModeFigures", "drive_train_data",
           "identify_drive_train", "identify_iteratively", "scaled_spec"]
