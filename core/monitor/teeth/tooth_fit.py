"""The monitor's flywheel fit of one cycle's tooth edges, with on-line tooth-spacing learning (design.md §4 step 1).

The fit is in time, over the cycle's 4 pi window of raw edge times (core.monitor.teeth.flywheel: harmonics of the cycle period,
no sinc to undo). The tooth-spacing error above the band is learned from the fit residuals (core.monitor.teeth.flywheel.
ToothLearner); inside the band it is fixed in angle and repeats every revolution, so at one operating point it cannot
be told from a steady engine response at integer orders: it is carried as nuisance parameters whose columns are the
angle patterns passed through the same fit (core.monitor.identify.parameters.tooth_patterns).

Speed: the whole step (prepare, fit, learn, refit) is one kernel call (tooth_fit_cycle_kernel below), the
same arithmetic as core.monitor.teeth.flywheel.prepare_fit / fit_prepared / ToothLearner.update (tests/core/test_tooth_fit.py).

The numba kernels of the tooth step come first in this file: the cycle window and pattern-cache
test, the learned correction applied to the nominal angles, and the whole step (prepare, fit, learn, refit) fused in one call so a
cycle costs one kernel dispatch instead of a dozen numpy calls (the arithmetic is core.monitor.teeth.flywheel_kernels').

The second (free-end) wheel, step 1b of a cycle that has one: its own motion from its own tooth times (issue 29 item 1).

The second wheel's edges (``Cycle.wheel2``, cut by the assembler on the crank angle of that wheel) go through the very
fit the flywheel's do (fit_cycle_teeth above: harmonics of the cycle period in time, the
in-band tooth pattern as nuisance columns, the out-of-band tooth-spacing error learnt from the residuals) with a
``ToothLearner`` and pattern cache of its own: a wheel with another tooth count, another gap and other tooth errors.

``FreeEndSpeed`` keeps what the balance needs of it: the mean speed, the angle harmonics of the free-end node and
the time of its window's first edge relative to the flywheel's (each fit's harmonics are referred to its own first
edge; ``harmonics_at(t)`` refers them to another origin). The joint fit of both wheels (its half-order speed
equations with the flywheel's): core.monitor.identify.noise_model.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.balance.harmonic_balance import OperatingPoint
from frictionwatch.core.monitor.identify.noise_model import ResidualStats
from frictionwatch.core.monitor.identify.parameters import tooth_patterns
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion, LearnerSettings, ToothLearner
from frictionwatch.core.monitor.teeth.flywheel_kernels import (
    BAD_SPAN,
    FOUR_PI,
    NOT_INCREASING,
    OK,
    fit_angles_kernel,
    prepare_fit_kernel,
    tooth_update_kernel,
)
from frictionwatch.core.types import Cycle


@numba.njit(cache=True)
def _corrected_angles(nominal, correction, tooth_index, out):
    """out (n,) = nominal + correction[tooth_index % wheel positions] [rad] (the learned tooth-spacing correction
    applied to the nominal edge angles)."""
    n = correction.shape[0]
    for e in range(out.shape[0]):
        out[e] = nominal[e] + correction[tooth_index[e] % n]


@numba.njit(cache=True)
def _revolution_period(rel_angle):
    """Edges per revolution T when every edge e + T sits exactly one revolution (2 pi, to 1e-9 rad) after edge e,
    else 0. rel_angle (n,) [rad] nominal edge angles relative to the first, increasing."""
    n = rel_angle.shape[0]
    two_pi = 0.5 * FOUR_PI
    period = 0
    for e in range(n):
        if rel_angle[e] > two_pi - 1e-9:
            period = e
            break
    if period == 0:
        return 0
    for e in range(n - period):
        if abs(rel_angle[e + period] - rel_angle[e] - two_pi) > 1e-9:
            return 0
    return period


@numba.njit(cache=True)
def _cycle_window(nominal, cached_rel):
    """The cycle's 4 pi window and its pattern-cache test in one pass (core.monitor.teeth.tooth_fit.fit_cycle_teeth).

    Returns (end, hit, period): ``end`` the index of the edge 4 pi after the first (np.searchsorted of
    nominal[0] + 4 pi - 1e-6), -1 when there is none within 1e-6 rad; ``hit`` whether cached_rel equals
    nominal[:end+1] - nominal[0] exactly (np.array_equal); ``period`` as ``_revolution_period`` of those angles."""
    m = nominal.shape[0]
    a0 = nominal[0]
    target = a0 + FOUR_PI - 1e-6
    lo = 0
    hi = m
    while lo < hi:  # first index with nominal[i] >= target (np.searchsorted, side="left")
        mid = (lo + hi) // 2
        if nominal[mid] < target:
            lo = mid + 1
        else:
            hi = mid
    end = lo
    if end >= m or not abs(nominal[end] - a0 - FOUR_PI) <= 1e-6:
        return -1, False, 0
    n = end + 1
    hit = cached_rel.shape[0] == n
    if hit:
        for e in range(n):
            if not cached_rel[e] == nominal[e] - a0:
                hit = False
                break
    rel = np.empty(n)
    for e in range(n):
        rel[e] = nominal[e] - a0
    return end, hit, _revolution_period(rel)


# statuses of tooth_fit_cycle_kernel beyond core.monitor.teeth.flywheel_kernels' (OK, NOT_INCREASING, BAD_SPAN)
NO_WINDOW = 4  # no edge 4 pi after the first
TOO_FEW = 5  # too few edges for the harmonics
CACHE_MISS = 6  # the pattern cache does not match this cycle's edges: build the patterns and call again
BAD_SHAPES = 7  # tooth_ticks / tooth_index shorter than the window

# layout of the step's settings, one small float64 array (a single cheap argument per cycle; counts and flags are
# stored as exact small floats): tick rate [Hz], drift columns (1 or 2), fitted harmonics, whether the in-band pattern
# columns are fitted, whether the drift pattern is, whether the learner steps, its gain, whether to refit after it,
# the previous fitted cycle's period [s] (0: none) and the relative speed change beyond which the learner skips a cycle
(TF_TICK_HZ, TF_N_DRIFT, TF_M_FIT, TF_USE_PATTERNS, TF_DRIFT_PATTERN, TF_LEARN, TF_GAIN, TF_REFIT, TF_PREV_PERIOD,
 TF_SPEED_STEP, TF_N_SETTINGS) = range(11)


@numba.njit(cache=True)
def tooth_fit_cycle_kernel(nominal_all, ticks_all, index_all, settings, cached_rel, cached_patterns, correction, harm,
                           pat):
    """The monitor's whole tooth step in one call (core.monitor.teeth.tooth_fit.fit_cycle_teeth): the cycle window and the
    pattern-cache test (``_cycle_window``), ``prepare_fit_kernel`` (patterns folded per revolution when their rows
    repeat), the fit of the corrected angles (``_corrected_angles``, ``fit_angles_kernel``), with TF_LEARN the
    learner step (``tooth_update_kernel`` with TF_GAIN) and, with TF_REFIT, the fit again with the fresh correction.
    The learner skips a cycle whose mean speed differs from the previous fitted cycle's (TF_PREV_PERIOD) by more
    than TF_SPEED_STEP (relative): a speed step's settling is not a ramp, so what the band and the drift column
    cannot follow stays in the residual, at the same wheel positions at every step (design note 60).

    settings (TF_N_SETTINGS,) in the TF_* layout. Fills harm (n_harm,) and pat (n_harm, q); returns (status,
    n edges, period [s], offset, drift, rms, edge residual (n,), correction after the cycle, whether it learnt)."""
    tick_hz = settings[TF_TICK_HZ]
    n_drift = int(settings[TF_N_DRIFT])
    m_fit = int(settings[TF_M_FIT])
    n_harm = harm.shape[0]
    use_patterns = settings[TF_USE_PATTERNS] != 0.0
    drift_pattern = settings[TF_DRIFT_PATTERN] != 0.0
    learn = settings[TF_LEARN] != 0.0
    gain = settings[TF_GAIN]
    refit = settings[TF_REFIT] != 0.0
    prev_period = settings[TF_PREV_PERIOD]
    speed_step = settings[TF_SPEED_STEP]
    no_resid = np.empty(0)
    end, hit, period_rows = _cycle_window(nominal_all, cached_rel)
    if end < 0:
        return NO_WINDOW, 0, 0.0, 0.0, 0.0, 0.0, no_resid, correction, False
    n = end + 1
    if ticks_all.shape[0] < n or index_all.shape[0] < n:
        return BAD_SHAPES, n, 0.0, 0.0, 0.0, 0.0, no_resid, correction, False
    p = n_drift + 2 * m_fit
    if n < p + 4:
        return TOO_FEW, n, 0.0, 0.0, 0.0, 0.0, no_resid, correction, False
    if use_patterns and not hit:
        return CACHE_MISS, n, 0.0, 0.0, 0.0, 0.0, no_resid, correction, False
    if not use_patterns:
        period_rows = 0
    patterns = cached_patterns[:period_rows] if period_rows > 0 else cached_patterns
    ticks = ticks_all[:n]
    nominal = nominal_all[:n]
    index = index_all[:n]
    tau = np.empty(n)
    design_t = np.empty((p, n))
    scale = np.empty(p)
    normal_inv = np.empty((p, p))
    status = prepare_fit_kernel(ticks, tick_hz, n_drift, m_fit, n_harm, patterns, period_rows, drift_pattern,
                                (tau, design_t, scale, normal_inv), pat)
    if status != OK:
        return status, n, 0.0, 0.0, 0.0, 0.0, no_resid, correction, False
    period = tau[n - 1]
    omega = FOUR_PI / period
    angle = np.empty(n)
    resid = np.empty(n)
    _corrected_angles(nominal, correction, index, angle)
    status, offset, drift, rms = fit_angles_kernel(design_t, scale, normal_inv, tau, omega, angle, n_drift, m_fit, harm, resid)
    if learn and prev_period > 0.0 and abs(prev_period / period - 1.0) > speed_step:
        learn = False
    if status != OK or not learn:
        return status, n, period, offset, drift, rms, resid, correction, False
    corr = tooth_update_kernel(correction, index, resid, gain)
    if refit:  # while the learner is young, use what this cycle taught at once
        _corrected_angles(nominal, corr, index, angle)
        status, offset, drift, rms = fit_angles_kernel(design_t, scale, normal_inv, tau, omega, angle, n_drift, m_fit, harm,
                                                 resid)
    return status, n, period, offset, drift, rms, resid, corr, True



@dataclass(frozen=True)
class ToothPatterns:
    """The in-band tooth-error patterns at a cycle's edges (core.monitor.identify.parameters.tooth_patterns), kept from cycle to
    cycle: they depend on the edge angles relative to the first one only, the same every cycle of a run.
    edge_angles (n,) [rad] relative to the first edge; patterns (n, 2 orders)."""

    edge_angles: np.ndarray
    patterns: np.ndarray

_NO_PATTERNS = np.zeros((1, 0))
_NO_ANGLES = np.zeros(0)
_STATUS_TEXT = {
    NO_WINDOW: "no tooth edge 720 deg after the first one",
    BAD_SHAPES: "tooth_ticks and tooth_index must have one entry per tooth angle",
    TOO_FEW: "{n} tooth edges cannot carry {m} harmonics; lower the order limit",
    NOT_INCREASING: "tooth times and angles must be strictly increasing",
    BAD_SPAN: "the corrected edge angles do not span one 720 deg cycle",
}


def fit_cycle_teeth(cycle: Cycle, wheel_teeth: int, n_harmonics: int, n_nuisance: int, teeth: ToothLearner,
                    cache: ToothPatterns | None, drift_nuisance: bool, fit_harmonics: int, fit_drift: bool,
                    learning: LearnerSettings) -> tuple[FlywheelMotion, ToothLearner, float, ToothPatterns | None]:
    """Flywheel fit of the cycle's 4 pi window (the assembler brackets [0, 4 pi] with an edge either side; the
    window starts at the first edge), tooth learning, and the angle of the first edge [rad].

    Pattern columns: ``n_nuisance`` in-band tooth-error patterns (orders 1..n_nuisance/2 per revolution), then, with
    ``drift_nuisance``, the angle of a linear speed drift over the cycle, q(u) = u (u - 1), u = t / T. The learner
    folds the cycle in (``learning``) only when its mean speed is within ``learning.speed_step`` (relative) of the
    previous fitted cycle's (``teeth.period``; MonitorConfig.tooth_speed_step, design note 60). Raises
    ValueError when the edges cannot be fitted (the monitor rejects the cycle as 'bad_teeth')."""
    nominal = np.asarray(cycle.tooth_angle, dtype=np.float64)
    if nominal.ndim != 1 or nominal.shape[0] < 2:
        raise ValueError("a cycle needs at least two tooth edges")
    ticks = np.asarray(cycle.tooth_ticks)
    index = np.asarray(cycle.tooth_index)  # wheel position = index % wheel_teeth (in the kernels)
    correction = teeth.correction
    if correction.shape[0] != wheel_teeth:
        raise ValueError(f"the tooth learner has {correction.shape[0]} positions, the wheel {wheel_teeth}")
    m_fit = max(n_harmonics, fit_harmonics or n_harmonics)
    n_drift = 2 if fit_drift else 1
    use_patterns = bool(n_nuisance)
    if use_patterns and cache is not None:
        cached_rel = np.ascontiguousarray(cache.edge_angles, dtype=np.float64)
        cached_patterns = np.ascontiguousarray(cache.patterns, dtype=np.float64)
    else:
        cached_rel, cached_patterns = _NO_ANGLES, _NO_PATTERNS
    n_cols = 2 * (n_nuisance // 2) if use_patterns else 0
    harm = np.empty(n_harmonics, dtype=np.complex128)
    pat = np.empty((n_harmonics, n_cols + (1 if drift_nuisance else 0)), dtype=np.complex128)
    settings = np.empty(TF_N_SETTINGS)
    settings[TF_TICK_HZ] = cycle.tick_hz
    settings[TF_N_DRIFT] = n_drift
    settings[TF_M_FIT] = m_fit
    settings[TF_USE_PATTERNS] = use_patterns
    settings[TF_DRIFT_PATTERN] = bool(drift_nuisance)
    settings[TF_LEARN] = bool(learning.learn)
    settings[TF_GAIN] = max(1.0 - learning.memory, 1.0 / (teeth.count + 1))
    settings[TF_REFIT] = teeth.count + 1 <= learning.refit_cycles
    settings[TF_PREV_PERIOD] = teeth.period
    settings[TF_SPEED_STEP] = learning.speed_step
    for _ in range(2):
        try:
            status, n, period, offset, drift, rms, resid, new_corr, learnt = tooth_fit_cycle_kernel(
                nominal, ticks, index, settings, cached_rel, cached_patterns, correction, harm, pat)
        except np.linalg.LinAlgError as exc:
            raise ValueError(f"the tooth edges give a singular flywheel fit ({exc})") from exc
        if status != CACHE_MISS:
            break
        # the patterns depend on the edge angles relative to the first one only, the same every cycle of a run
        window = nominal[:n]
        cached_patterns = tooth_patterns(window, n_nuisance // 2)
        cached_rel = window - window[0]
        cache = ToothPatterns(edge_angles=cached_rel, patterns=cached_patterns)
    if status != OK:
        raise ValueError(_STATUS_TEXT.get(status, "flywheel fit failed").format(n=n, m=n_harmonics))
    teeth = ToothLearner(correction=new_corr, count=teeth.count + learnt, period=period)
    fly = FlywheelMotion(period=period, omega_mean=FOUR_PI / period, harmonics=harm, offset=offset, drift=drift,
                       residual_rms=rms, n_edges=n, edge_residual=resid, pattern_harmonics=pat)
    return fly, teeth, float(nominal[0] + teeth.correction[int(index[0]) % wheel_teeth]), cache


@dataclass(frozen=True)
class SecondWheelState:
    """The second wheel's tooth learner (its positions) and in-band pattern cache, carried cycle to cycle, and the
    residual statistics of its speed equations in the joint fit (core.monitor.identify.noise_model)."""

    teeth: ToothLearner
    patterns: ToothPatterns | None = None
    stats: ResidualStats | None = None


@dataclass(frozen=True)
class FreeEndSpeed:
    """The free-end node's motion over one cycle, from the second wheel.

    omega_mean [rad/s]; harmonics (M,) complex Phi_m [rad] of the angle deviation, order m/2, referred to the time of
    its own first edge; t_first_s [s] that time minus the flywheel window's first edge; residual_rms [rad] of its
    fit (timing noise, tooth errors not yet learnt, orders above the band); n_edges used."""

    omega_mean: float
    harmonics: np.ndarray
    t_first_s: float
    residual_rms: float
    n_edges: int
    drift_harmonics: np.ndarray | None = None  # (M,) complex [rad]: its fit's drift pattern q(u), same reference
    # (M, n_nuisance) complex [rad per rad]: its in-band tooth-error patterns through its fit, same reference. Fixed
    # in angle, they are integer orders; seen in time on a shaft whose speed ripples at half orders they leak into
    # the half orders too (bench/drive_train_model_error.py: up to ~50 % of the free end's small harmonics at orders
    # 7.5-8.5 on genset-v20). The drive train's identification counts that leak as noise of its free-end rows.
    pattern_harmonics: np.ndarray | None = None

    def harmonics_at(self, t_s: float, values: np.ndarray | None = None) -> np.ndarray:
        """The harmonics referred to an origin ``t_s`` [s] after the flywheel window's first edge (0: that edge):
        phi(tau) = sum Re(Phi_m exp(i w_m tau)) with tau from its own first edge (core.monitor.teeth.flywheel) is
        sum Re(Phi_m exp(-i w_m (t_first_s - t_s)) exp(i w_m tau')) with tau' from ``t_s``. ``values``: other
        harmonics of the same reference (the drift pattern's) instead of the angle's."""
        h = self.harmonics if values is None else values
        w = 0.5 * self.omega_mean * np.arange(1, h.shape[0] + 1)
        return h * np.exp(-1j * w * (self.t_first_s - t_s))

    @property
    def speed_harmonics(self) -> np.ndarray:
        """(M,) complex [rad/s] speed harmonics i w_m Phi_m (same reference as ``harmonics``)."""
        return 1j * 0.5 * self.omega_mean * np.arange(1, self.harmonics.shape[0] + 1) * self.harmonics


def fit_second_wheel(cycle: Cycle, state: SecondWheelState | None, n_harmonics: int, n_nuisance: int,
                     settings: tuple) -> tuple[FreeEndSpeed | None, SecondWheelState | None, str | None]:
    """The second wheel's fit of ``cycle`` (None and the state unchanged when the cycle has no second wheel), its
    learner updated, and a flag when its edges could not be fitted ('second_wheel_bad_teeth': the flywheel's cycle
    goes on without it).

    settings : (drift_nuisance, fit_harmonics, fit_drift, learning: LearnerSettings), the
    flywheel fit's own (core.monitor.teeth.tooth_fit.fit_cycle_teeth)."""
    w = cycle.wheel2
    if w is None:
        return None, state, None
    if state is None or state.teeth.correction.shape[0] != w.teeth:  # first sight, or another wheel stated
        state = SecondWheelState(ToothLearner.empty(w.teeth), None, None if state is None else state.stats)
    view = replace(cycle, tooth_ticks=w.ticks, tooth_angle=w.angle, tooth_index=w.index, wheel2=None)
    try:
        fly, teeth, _, patterns = fit_cycle_teeth(view, w.teeth, n_harmonics, n_nuisance, state.teeth,
                                                  state.patterns, *settings)
    except ValueError:
        return None, state, "second_wheel_bad_teeth"
    speed = FreeEndSpeed(omega_mean=fly.omega_mean, harmonics=fly.harmonics.copy(),
                         t_first_s=float(w.ticks[0] - cycle.tooth_ticks[0]) / cycle.tick_hz,
                         residual_rms=fly.residual_rms, n_edges=fly.n_edges,
                         drift_harmonics=fly.pattern_harmonics[:, -1].copy() if settings[0] else None,
                         pattern_harmonics=fly.pattern_harmonics[:, :n_nuisance].copy())
    return speed, SecondWheelState(teeth, patterns, state.stats), None


def free_end_input(spec: EngineSpec, op: OperatingPoint, free: FreeEndSpeed | None
                   ) -> tuple[np.ndarray, np.ndarray] | None:
    """What the harmonic balance needs for the second wheel's equations (core.monitor.balance.harmonic_balance):
    the chain's speed transfer to its node (the engine file's [sensors.second_wheel] node; a one-node chain: that
    node) and its harmonics referred to the flywheel window's first edge; None without a fit or a stated node."""
    if free is None or spec.sensors.second_wheel is None:
        return None
    n_nodes = op.receptance.inverse.shape[1]
    node = spec.sensors.second_wheel.node if n_nodes == len(spec.node_names) else 0
    return op.receptance.speed_transfer(node), free.harmonics_at(0.0)
