"""The monitor's flywheel fit of one cycle's tooth edges, with on-line tooth-spacing learning (design.md §4 step 1).

The fit is in time, over the cycle's 4 pi window of raw edge times (core.flywheel: harmonics of the cycle period,
no sinc to undo). The tooth-spacing error above the band is learned from the fit residuals (core.flywheel.
ToothLearner); inside the band it is fixed in angle and repeats every revolution, so at one operating point it cannot
be told from a steady engine response at integer orders: it is carried as nuisance parameters whose columns are the
angle patterns passed through the same fit (core.identify.tooth_patterns).
"""

from __future__ import annotations

import numpy as np

from core.flywheel import FlywheelMotion, ToothLearner, fit_prepared, prepare_fit
from core.identify import tooth_patterns
from core.types import Cycle

FOUR_PI = 4.0 * np.pi

PatternCache = tuple[np.ndarray, np.ndarray]  # (edge angles relative to the first, patterns)


def fit_cycle_teeth(cycle: Cycle, wheel_teeth: int, n_harmonics: int, n_nuisance: int, teeth: ToothLearner,
                    cache: PatternCache | None, drift_nuisance: bool, fit_harmonics: int, fit_drift: bool,
                    learn_teeth: bool, tooth_memory: float, tooth_refit_cycles: int
                    ) -> tuple[FlywheelMotion, ToothLearner, float, PatternCache | None]:
    """Flywheel fit of the cycle's 4 pi window (the assembler brackets [0, 4 pi] with an edge either side; the
    window starts at the first edge), tooth learning, and the angle of the first edge [rad].

    Pattern columns: ``n_nuisance`` in-band tooth-error patterns (orders 1..n_nuisance/2 per revolution), then, with
    ``drift_nuisance``, the angle of a linear speed drift over the cycle. Raises ValueError when the edges cannot be
    fitted (the monitor rejects the cycle as 'bad_teeth')."""
    nominal = np.asarray(cycle.tooth_angle, dtype=np.float64)
    end = int(np.searchsorted(nominal, nominal[0] + FOUR_PI - 1e-6))
    if end >= nominal.shape[0] or abs(nominal[end] - nominal[0] - FOUR_PI) > 1e-6:
        raise ValueError("no tooth edge 720 deg after the first one")
    ticks = cycle.tooth_ticks[: end + 1]
    pos = np.asarray(cycle.tooth_index[: end + 1]) % wheel_teeth
    nominal = nominal[: end + 1]
    if n_nuisance:
        # the patterns depend on the edge angles relative to the first one only, the same every cycle of a run
        rel_angle = nominal - nominal[0]
        if cache is not None and np.array_equal(cache[0], rel_angle):
            patterns = cache[1]
        else:
            patterns = tooth_patterns(nominal, n_nuisance // 2)
            cache = (rel_angle, patterns)
    else:
        patterns = np.zeros((nominal.size, 0))
    if drift_nuisance:  # angle of a linear speed drift over the cycle, q(u) = u (u - 1), u = t / T
        u = (ticks - ticks[0]) / float(ticks[-1] - ticks[0])
        patterns = np.column_stack([patterns, u * (u - 1.0)])
    setup = prepare_fit(ticks, cycle.tick_hz, n_harmonics, patterns, fit_harmonics, fit_drift)  # shared by the refit
    fly = fit_prepared(setup, nominal + teeth.correction[pos])
    if learn_teeth:
        teeth = teeth.update(pos, fly.edge_residual, tooth_memory)
        if teeth.count <= tooth_refit_cycles:  # while young, use what this cycle taught at once
            fly = fit_prepared(setup, nominal + teeth.correction[pos])
    return fly, teeth, float(nominal[0] + teeth.correction[pos[0]]), cache
