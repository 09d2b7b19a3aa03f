"""The monitor's flywheel fit of one cycle's tooth edges, with on-line tooth-spacing learning (design.md §4 step 1).

The fit is in time, over the cycle's 4 pi window of raw edge times (core.monitor.teeth.flywheel: harmonics of the cycle period,
no sinc to undo). The tooth-spacing error above the band is learned from the fit residuals (core.monitor.teeth.flywheel.
ToothLearner); inside the band it is fixed in angle and repeats every revolution, so at one operating point it cannot
be told from a steady engine response at integer orders: it is carried as nuisance parameters whose columns are the
angle patterns passed through the same fit (core.monitor.identify.layout.tooth_patterns).

Speed: the whole step (prepare, fit, learn, refit) is one kernel call (core.monitor.teeth.tooth_fit_kernels.tooth_fit_cycle_kernel), the
same arithmetic as core.monitor.teeth.flywheel.prepare_fit / fit_prepared / ToothLearner.update (tests/core/test_tooth_fit.py).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.monitor.identify.layout import tooth_patterns
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion, ToothLearner
from frictionwatch.core.monitor.teeth.flywheel_kernels import BAD_SPAN, NOT_INCREASING, OK
from frictionwatch.core.monitor.teeth.tooth_fit_kernels import (
    BAD_SHAPES,
    CACHE_MISS,
    NO_WINDOW,
    TF_DRIFT_PATTERN,
    TF_GAIN,
    TF_LEARN,
    TF_M_FIT,
    TF_N_DRIFT,
    TF_N_SETTINGS,
    TF_REFIT,
    TF_TICK_HZ,
    TF_USE_PATTERNS,
    TOO_FEW,
    tooth_fit_cycle_kernel,
)
from frictionwatch.core.types import Cycle

FOUR_PI = 4.0 * np.pi



@dataclass(frozen=True)
class ToothPatterns:
    """The in-band tooth-error patterns at a cycle's edges (core.monitor.identify.layout.tooth_patterns), kept from cycle to
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
                    learn_teeth: bool, tooth_memory: float, tooth_refit_cycles: int
                    ) -> tuple[FlywheelMotion, ToothLearner, float, ToothPatterns | None]:
    """Flywheel fit of the cycle's 4 pi window (the assembler brackets [0, 4 pi] with an edge either side; the
    window starts at the first edge), tooth learning, and the angle of the first edge [rad].

    Pattern columns: ``n_nuisance`` in-band tooth-error patterns (orders 1..n_nuisance/2 per revolution), then, with
    ``drift_nuisance``, the angle of a linear speed drift over the cycle, q(u) = u (u - 1), u = t / T. Raises
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
    settings[TF_LEARN] = bool(learn_teeth)
    settings[TF_GAIN] = max(1.0 - tooth_memory, 1.0 / (teeth.count + 1))
    settings[TF_REFIT] = teeth.count + 1 <= tooth_refit_cycles
    for _ in range(2):
        try:
            status, n, period, offset, drift, rms, resid, new_corr = tooth_fit_cycle_kernel(
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
    if learn_teeth:
        teeth = ToothLearner(correction=new_corr, count=teeth.count + 1)
    fly = FlywheelMotion(period=period, omega_mean=FOUR_PI / period, harmonics=harm, offset=offset, drift=drift,
                       residual_rms=rms, n_edges=n, edge_residual=resid, pattern_harmonics=pat)
    return fly, teeth, float(nominal[0] + teeth.correction[int(index[0]) % wheel_teeth]), cache
