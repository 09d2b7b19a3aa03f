"""What a window mean (GET .../losses?window_cycles=N) is made of, and the plain way to compute it from every cycle.

Each cycle's own estimate (``CycleResult.to_json(smoothed=False)``) becomes one row of numbers (``cycle_row``): the
engine's measured FMEP, and per cylinder the friction torque, the FMEP, the data weight, each loss coefficient and
the figure's status. A window's figures (``WindowFigures``) are each number's mean, the 1-sigma of that mean from
the cycle-to-cycle scatter and how many cycles had it, the status counts per cylinder and the flag counts.

A cycle without a cycle before it (flag ``no_previous_cycle``: a log's first cycle, the first after each loop
seam of a replay or after a stream restart) has no estimate of its own (nothing to balance its indicated work
against: every figure null or unresolved). It is left out of the means and the status counts and counted
(``left_out``), so that one such cycle does not make a whole window 'unresolved'; its flags still count.

``figures_from_cycles`` computes them from the window's cycles one by one: the reference. The service reads them
from running sums kept once per cycle (service/window_sums.py, O(1) per request); a test holds the two together.
The sums take each cycle's row from ``result_row`` (the same numbers from the result's arrays, without the
document; tests/service/test_window_row.py holds it to ``cycle_row``).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from frictionwatch.core.monitor.report.figure_status import STATUSES, friction_status
from frictionwatch.core.monitor.report.results import PA_PER_BAR, VALUED_STATUSES, CycleResult
from frictionwatch.core.monitor.report.run_summary import ACTIVE_SHARE, mean_and_sem

NO_PREVIOUS_CYCLE = "no_previous_cycle"  # core.monitor.monitor: the cycle has no cycle before it
SHARE = STATUSES.index("share")  # statuses as FrictionStatus.codes hold them
VALUED_BY_CODE = np.array([s in VALUED_STATUSES for s in STATUSES])  # by code: does the figure show a value


def left_out(flags) -> bool:
    """Whether a cycle with these flags stays out of a window's means (module doc)."""
    return NO_PREVIOUS_CYCLE in flags


def active_from_counts(newest: Iterable[str], counts: Mapping[str, int], cycles: int) -> frozenset[str]:
    """``run_summary.active_flags`` over a window of ``cycles`` results from its flag counts (cycles of the window
    that raised each flag, as ``WindowSums`` keeps them) instead of every result's flags: the newest result's flags
    and those raised in at least ACTIVE_SHARE of the window (tests/service/test_api_rendered.py holds the two
    equal)."""
    return frozenset(newest) | {f for f, c in counts.items() if c >= ACTIVE_SHARE * cycles}


@dataclass(frozen=True)
class RowLayout:
    """Where each number of a cycle's row sits: column 0 the engine FMEP, then per cylinder torque, FMEP, data
    weight and the ``n_coefs`` coefficients."""

    n_cyl: int
    n_coefs: int

    @property
    def per_cyl(self) -> int:
        return 3 + self.n_coefs

    @property
    def width(self) -> int:
        return 1 + self.n_cyl * self.per_cyl

    def torque(self, k: int) -> int:
        return 1 + k * self.per_cyl

    def fmep(self, k: int) -> int:
        return self.torque(k) + 1

    def weight(self, k: int) -> int:
        return self.torque(k) + 2

    def coef(self, k: int, j: int) -> int:
        return self.torque(k) + 3 + j


def _f(x: float | None) -> float:
    return math.nan if x is None else float(x)


def layout_of(doc: dict) -> RowLayout:
    cyls = doc["cylinders"]
    return RowLayout(len(cyls), len(cyls[0]["coefficients"]) if cyls else 0)


def cycle_row(doc: dict, layout: RowLayout) -> tuple[np.ndarray, np.ndarray]:
    """One cycle's numbers (NaN where a figure is null) and each cylinder's status as an index into STATUSES."""
    row = np.full(layout.width, np.nan)
    row[0] = _f(doc["fmep_bar"])  # the flat key: a value only where the engine's friction is measured
    status = np.empty(layout.n_cyl, np.int64)
    for k, cyl in enumerate(doc["cylinders"]):
        fig = cyl["friction"]
        row[layout.torque(k)] = _f(fig["friction_torque_mean_nm"])
        row[layout.fmep(k)] = _f(fig["fmep_bar"])
        row[layout.weight(k)] = _f(fig["data_weight"])
        start = layout.coef(k, 0)
        row[start:start + layout.n_coefs] = [_f(c) for c in cyl["coefficients"]]
        status[k] = STATUSES.index(fig["status"])
    return row, status


def _finite(x: np.ndarray) -> np.ndarray:
    """``_num`` of each element: the value where finite, NaN (null) elsewhere."""
    return np.where(np.isfinite(x), x, np.nan)


def result_row(result: CycleResult) -> tuple[RowLayout, np.ndarray, np.ndarray]:
    """``layout_of`` and ``cycle_row`` of ``result.to_json(smoothed=False)``, by the document's own arithmetic from
    the result's arrays, without making the document, of whose numbers the row takes ~1 % (the API state makes one
    row a cycle: 0.24 ms a genset-v20 cycle through the document, 0.08 this way; design notes 34). ``cycle_row`` of
    the document stays the reference: equal, NaN as NaN (tests/service/test_window_row.py)."""
    est = result.cycle
    st = friction_status(est, result.flags)
    coefs = np.asarray(est.coefficients, dtype=np.float64)
    n_cyl = len(st.codes)
    layout = RowLayout(n_cyl, coefs.shape[1] if n_cyl else 0)
    row = np.full(layout.width, np.nan)
    if st.engine.status == "measured":  # the flat key: the total's fmep_bar where measured (_measured_only)
        torque = float(est.total_friction_torque)
        if math.isfinite(torque):
            row[0] = _finite(np.float64(torque * result.mep_per_nm(engine=True) / PA_PER_BAR))
    status = st.codes.copy()  # each cylinder's status as its index in STATUSES (the words never read here)
    if n_cyl:
        share = status == SHARE
        valued = VALUED_BY_CODE[status]  # (a table, not np.isin: ~20 us a call)
        shown = np.where(share, est.prior_friction_torque_mean, est.friction_torque_mean).astype(np.float64)
        torque = np.where(valued, _finite(shown), np.nan)
        table = row[1:].reshape(n_cyl, layout.per_cyl)  # a view: torque, FMEP, weight, coefficients per cylinder
        table[:, 0] = torque
        table[:, 1] = _finite(torque * result.mep_per_nm() / PA_PER_BAR)
        table[:, 2] = st.data_weight  # NaN where the figure has none (None in the document)
        table[:, 3:] = _finite(coefs)
    return layout, row, status


@dataclass(frozen=True)
class WindowFigures:
    """The figures of a window of ``cycles`` consecutive cycles (``first_cycle`` .. ``last_cycle``): per column of
    ``layout``, the mean of the finite values, the 1-sigma of that mean (NaN for fewer than two) and how many;
    ``status_counts`` (n_cyl, len(STATUSES)) of the counted cycles; ``flag_counts``: cycles of the window that raised
    each flag (all of them); ``left_out``: cycles of the window without a previous cycle, in neither the means nor
    the status counts (module doc)."""

    layout: RowLayout
    cycles: int
    first_cycle: int
    last_cycle: int
    mean: np.ndarray
    sem: np.ndarray
    count: np.ndarray
    status_counts: np.ndarray
    flag_counts: dict[str, int]
    left_out: int = 0

    @property
    def counted(self) -> int:
        """The cycles the means and status counts stand for."""
        return self.cycles - self.left_out

    def stat(self, col: int) -> tuple[float, float, int]:
        return float(self.mean[col]), float(self.sem[col]), int(self.count[col])


def figures_from_cycles(results: Sequence[CycleResult]) -> WindowFigures:
    """The reference: every cycle of the window read again (cost grows with the window)."""
    docs = [r.to_json(smoothed=False) for r in results]
    layout = layout_of(docs[-1])
    made = [cycle_row(d, layout) for d, r in zip(docs, results) if not left_out(r.flags)]
    values = np.array([row for row, _ in made]).reshape(len(made), layout.width)
    stats = [mean_and_sem(values[:, c]) for c in range(layout.width)]
    counts = np.zeros((layout.n_cyl, len(STATUSES)), np.int64)
    for _, st in made:
        counts[np.arange(layout.n_cyl), st] += 1
    flags = Counter(f for r in results for f in set(r.flags))
    return WindowFigures(layout, len(results), int(results[0].index), int(results[-1].index),
                         np.array([s[0] for s in stats]), np.array([s[1] for s in stats]),
                         np.array([s[2] for s in stats]), counts, dict(flags), len(results) - len(made))
