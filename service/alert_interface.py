"""What the alert engine (service.alerts) and its rules (service.alert_rules) exchange: a rule's ``Decision`` or
``Hold`` per statistic, the ``Context`` of a cycle, the ``Pressure`` statistics, the ``Rule`` interface itself; and
the two pieces of decision logic they share, the hysteresis latch and the leak statistics. No physics."""

from __future__ import annotations

from collections.abc import Callable, Container
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from frictionwatch.core.monitor.report.figure_status import STATUSES, FrictionStatus, friction_status
from frictionwatch.core.monitor.report.results import CycleResult
from frictionwatch.service.alert_baseline import Band, Baseline

MEASURED = STATUSES.index("measured")  # a measured figure in FrictionStatus.codes (the rules read the codes, not words)


class Latch:
    """Hysteresis of one statistic: ``step`` returns "raise" after ``k_on`` consecutive cycles with ``on``, "clear"
    after ``k_off`` consecutive cycles with ``off`` while raised, else None; ``since`` is the first cycle of the
    current run of ``on`` cycles (the evidence's start)."""

    __slots__ = ("active", "on_count", "off_count", "since")

    def __init__(self) -> None:
        self.active, self.on_count, self.off_count, self.since = False, 0, 0, -1

    def step(self, on: bool, off: bool, k_on: int, k_off: int, cycle: int) -> str | None:
        if not self.active:
            if on:
                self.since = cycle if self.on_count == 0 else self.since
                self.on_count += 1
                if self.on_count >= k_on:
                    self.active, self.off_count = True, 0
                    return "raise"
            else:
                self.on_count = 0
            return None
        self.off_count = self.off_count + 1 if off else 0
        if self.off_count >= k_off:
            self.active, self.on_count = False, 0
            return "clear"
        return None


@dataclass(frozen=True)
class LeakStatistics:
    """Per cylinder (z,): z_leak the leak signature's EWMA in standard errors (> 0: compression exponent down and
    expansion exponent up from commissioning), effect its size in exponent units (-dn_c + dn_e) / 2, z_ratio the
    compression ratio's EWMA change in standard errors (signed)."""

    z_leak: np.ndarray
    effect: np.ndarray
    z_ratio: np.ndarray


def change_against_siblings(change: np.ndarray) -> np.ndarray:
    """(..., 4, z) each cylinder's change from its baseline (rows as alert_baseline.INDICATORS) less the median change of
    all cylinders, where there are three or more.

    The indicators are already against the siblings' median *level* each cycle; a change of one cylinder's level
    moves which cylinders that median is made of (a median of four is the mean of the middle two, of three the middle
    one), so its siblings' changes from their baselines moved too: a k9k (seed 11) commissioned with a leaking
    cylinder 3 whose leak then went (a bench run whose fault ramped in after commissioning) raised a leak warning on
    cylinder 2 after 26 cycles, a maruti (seed 3, cylinder 2 likewise) on cylinder 1 after 42. The median of the
    *changes* is the common part (load, temperature) and stays put when one cylinder changes: subtracted, a change of
    one cylinder is seen on that cylinder only. Nothing tuned. Two cylinders: the rows are each against the other,
    kept as they are; three: the median cylinder reads no change (two changed cylinders name nobody, as before)."""
    if change.shape[-1] < 3:
        return change
    return change - sibling_median(change)


def sibling_median(a: np.ndarray) -> np.ndarray:
    """``np.median(a, axis=-1, keepdims=True)`` by a sort (the same values: the middle one, or half the sum of the two
    middle ones): np.median costs ~10x on the z values of a (4, z) array, and the alerts take two a cycle. A row
    with a NaN goes to np.median (which gives NaN there; a sort would put the NaN last)."""
    z = a.shape[-1]
    s = np.sort(a, axis=-1)
    if not np.isfinite(s[..., -1]).all():  # a NaN sorts last: only the last column can tell
        return np.median(a, axis=-1, keepdims=True)
    m = s[..., z // 2:z // 2 + 1] if z % 2 else 0.5 * (s[..., z // 2 - 1:z // 2] + s[..., z // 2:z // 2 + 1])
    return m


def ewma_variance(previous: float, g: float) -> float:
    """The variance of an EWMA of independent unit-variance cycles after one more cycle with factor ``g``:
    (1 - g)^2 previous + g^2. With g = 1 / n it is a running mean's 1 / n; at a fixed g it tends to g / (2 - g).
    The alerts' EWMA starts as a running mean (g = max(1 / window, 1 / n)), where g / (2 - g) = 1 / (2n - 1) said
    half the variance: every z in its first ~2 windows read ~sqrt(2) high (design note 54)."""
    return (1.0 - g) ** 2 * previous + g * g


def sibling_reference_variance(n_cyl: int) -> float:
    """The factor on a cylinder's EWMA variance for its figure against ``change_against_siblings``'s reference.
    Three cylinders: the median change is one of the three; where one cylinder has moved (a fault coming or going)
    it is one of the other two, so each of those reads its change less the other's -- a difference of two
    cylinders, twice one's variance -- and on the side the moved one set: maruti seed 3, commissioned with a
    leaking cylinder 2 whose leak then ramped in afresh, read cylinder 1 against cylinder 3 and warned "leak"
    there (design note 54). Four or more: the median is a mean of two or more changes (1.0; note 49's iid
    0.78-0.97). Two: the rows are already each against the other (their band spread is a difference's)."""
    return 2.0 if n_cyl == 3 else 1.0


class LongRunVariance:
    """How much more an EWMA of a healthy engine's per-cycle figures varies than independent cycles would make it
    vary, estimated on line from the figures themselves (design note 71).

    A cycle's figures need not be independent of the last cycle's (the residual gas one cycle leaves to the next is
    combustion's known cycle-to-cycle coupling): for a first-order autoregression with lag-1 correlation phi the
    variance of an EWMA of factor g is the independent-cycle g / (2 - g) times
    f = (1 + phi (1 - g)) / (1 - phi (1 - g)). phi is each figure's lag-1 correlation: the running means (a running
    mean until ``horizon`` cycles, then an EWMA over it) of d_t d_(t-1) and d_t^2, d each figure less its own EWMA
    over ``centre`` cycles, in the order the alerts' EWMA folds the cycles.

    Why only lag 1 and a short centre (design note 71): a fault is a lasting shift of the figure, and a sum of lag
    products over a window's length counts a shift of delta (in per-cycle sd) as ~2 delta^2 sum_k (1 - g)^k of
    factor: an estimate over 150 lags read a factor of 30 on independent synthetic cycles after one cylinder leaked
    and then a second (the sibling median moves every cylinder's figure a little with a moved one, and the products
    remember it for their horizon) -- the standard error grew with the fault it was to reveal. The lag-1 product
    about a short centre sees a shift only while the centre catches up: a 5 sd shift adds ~0.3 to one cylinder's
    phi for a horizon, a sibling's 0.25 sd none to speak of. What this leaves out: a slow wander without lag-1
    correlation (the healthy figures' longer-lag sums on the simulator, 0.7-1.3 of the independent figure, are within
    their own scatter of 1).

    ``add`` takes one cycle's figures (s, z): s series (figures) per cylinder. ``factor(g)`` gives per series the
    median over the cylinders of each cylinder's f (a faulty cylinder is outvoted; with fewer than three cylinders
    there is no majority and the factor is 1), bounded below by 1 (phi < 0 gives no smaller standard error: no rule
    raises where it did not) and above by (2 - g) / g (an EWMA never varies more than its figure), and 1 until
    ``warmup`` cycles have been added (phi's scatter is ~1 / sqrt(n) per cylinder)."""

    __slots__ = ("centre_cycles", "horizon", "warmup", "n", "state", "_centre", "_last", "_c0", "_c1")

    def __init__(self, n_series: int, n_cyl: int, centre: float, horizon: float, warmup: int):
        self.centre_cycles, self.horizon, self.warmup = float(centre), float(horizon), int(warmup)
        self.n = 0  # cycles added
        # the four running figures in one array (core/monitor/checks/pressure_statistics.py updates it in place), each a view of it
        self.state = np.zeros((4, n_series, n_cyl))
        self._centre = self.state[0]  # each figure's short EWMA
        self._last = self.state[1]  # the last cycle's deviation from it
        self._c0 = self.state[2]  # running mean of d_t^2
        self._c1 = self.state[3]  # running mean of d_t d_(t-1)

    def add(self, x: np.ndarray) -> None:
        """One cycle's figures (s, z), the next in the alerts' EWMA (a non-finite one is not added)."""
        x = np.asarray(x, dtype=np.float64)
        if not np.isfinite(x).all():
            return
        self.n += 1
        self._centre += max(1.0 / self.centre_cycles, 1.0 / self.n) * (x - self._centre)
        d = x - self._centre
        a = max(1.0 / self.horizon, 1.0 / self.n)
        self._c0 += a * (d * d - self._c0)
        if self.n > 1:
            self._c1 += max(1.0 / self.horizon, 1.0 / (self.n - 1)) * (d * self._last - self._c1)
        self._last[...] = d

    def lag_one(self) -> np.ndarray:
        """(s, z) each figure's lag-1 correlation phi (0 where it has no spread yet)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(self._c0 > 0.0, self._c1 / np.where(self._c0 > 0.0, self._c0, 1.0), 0.0)

    def per_cylinder(self, g: float) -> np.ndarray:
        """(s, z) each cylinder's factor f for an EWMA of factor ``g`` (phi clipped to [0, 0.999]: class doc)."""
        r = np.minimum(np.maximum(self.lag_one(), 0.0), 0.999) * (1.0 - g)  # np.clip: 2x the cost on (2, z)
        return (1.0 + r) / (1.0 - r)

    def factor(self, g: float) -> np.ndarray:
        """(s,) the factor on each series' independent-cycle EWMA variance (class doc: median over the cylinders,
        bounded to [1, (2 - g) / g], 1 during the warm-up or with fewer than three cylinders)."""
        s, z = self._c0.shape
        if self.n < self.warmup or z < 3:
            return np.ones(s)
        f = np.sort(self.per_cylinder(g), axis=1)  # the median by a sort: np.median's overhead is ~10x on z values
        median = f[:, z // 2] if z % 2 else 0.5 * (f[:, z // 2 - 1] + f[:, z // 2])
        return np.minimum(np.maximum(median, 1.0), (2.0 - g) / g)


@dataclass(frozen=True)
class LeakWeights:
    """What ``leak_statistics`` takes from a load band, worked out once per band (the alert engine keeps the newest
    band's: a cycle's statistics then cost no einsum and no square roots of the covariance). w1, w2 (z,) the leak
    signature's weights on the compression and expansion exponents' changes (-1 / sd_c and 1 / sd_e, over sqrt(2)),
    s_sd (z,) the signature's per-cycle spread from the band's covariance, sd_ratio (z,) the compression ratio's
    (at least 1e-12)."""

    band: Band
    w1: np.ndarray
    w2: np.ndarray
    s_sd: np.ndarray
    sd_ratio: np.ndarray

    @classmethod
    def of(cls, band: Band) -> LeakWeights:
        sd = band.sd
        w = np.zeros_like(sd)
        w[1], w[2] = -1.0 / sd[1], 1.0 / sd[2]
        w /= np.sqrt(2.0)
        s_sd = np.sqrt(np.maximum(np.einsum("iz,zij,jz->z", w, band.cov, w), 1e-30))
        return cls(band, w[1], w[2], s_sd, np.maximum(sd[0], 1e-12))


def leak_statistics(ewma: np.ndarray, baseline: Band, var: float, var_ratio: float | None = None,
                    weights: LeakWeights | None = None) -> LeakStatistics:
    """From the EWMA (4, z) of the indicators' change from the mean of the baseline's load band they were compared
    with (rows as alert_baseline.INDICATORS) and ``var``, the figure's variance per unit of per-cycle variance (the
    EWMA's, ``ewma_variance``, plus the band mean's, 1 / its cycles; times ``sibling_reference_variance`` and the
    leak signature's ``LongRunVariance`` factor: service.alerts; ``var_ratio`` the compression ratio's, ``var`` if
    None). The leak signature
    s = (-dn_c / sd_c + dn_e / sd_e) / sqrt(2) is scaled by its own per-cycle spread from the band's covariance (the
    two exponents' scatter is correlated: one trapped-mass error moves both) and by the standard error sqrt(var).
    With ``var`` 1 the statistics of one cycle's change are that cycle's standardised figures. ``weights``: the
    band's ``LeakWeights`` if the caller keeps them (else worked out here). The compression ratio and the
    expansion deficit rows do not enter the signature (a non-finite one leaves it finite)."""
    lw = LeakWeights.of(baseline) if weights is None else weights
    s = lw.w1 * ewma[1] + lw.w2 * ewma[2]
    se = np.sqrt(var)
    se_ratio = se if var_ratio is None else np.sqrt(var_ratio)
    return LeakStatistics(z_leak=s / (lw.s_sd * se), effect=0.5 * (ewma[2] - ewma[1]),
                          z_ratio=ewma[0] / (lw.sd_ratio * se_ratio))


def leak_statistics_reference(ewma: np.ndarray, baseline: Band, var: float, var_ratio: float | None = None
                              ) -> LeakStatistics:
    """``leak_statistics`` as it was before the band's weights were kept (design note 72), each cycle from the band:
    the reference the tests hold it to."""
    sd = baseline.sd
    w = np.zeros_like(ewma)
    w[1], w[2] = -1.0 / sd[1], 1.0 / sd[2]
    w /= np.sqrt(2.0)
    s = np.sum(w * ewma, axis=0)
    s_sd = np.sqrt(np.maximum(np.einsum("iz,zij,jz->z", w, baseline.cov, w), 1e-30))
    se = np.sqrt(var)
    se_ratio = se if var_ratio is None else np.sqrt(var_ratio)
    return LeakStatistics(z_leak=s / (s_sd * se), effect=0.5 * (ewma[2] - ewma[1]),
                          z_ratio=ewma[0] / (np.maximum(sd[0], 1e-12) * se_ratio))


# ---- the interface ----------------------------------------------------------------------------------------------
class Decision:
    """One statistic's verdict this cycle. cylinder: 1-based, None for the engine; kind: the alert it raises (fixed
    when raised); on / off: the raise and clear conditions, k_on / k_off the consecutive cycles each needs; severity
    (info | warning | alarm: an open alert escalates, never de-escalates), message and evidence: the alert's, renewed
    every cycle while it is open.

    The message and evidence are what costs (formatting every cylinder's every cycle was most of the alert engine's
    time, design notes 31), and the engine reads them only when the statistic raises or its alert is open: a rule
    passes either both, or ``detail``, a callable giving (message, evidence) that is called at most once, during
    the same ``AlertEngine.update`` (so it may read the cycle's arrays as they are then).

    >>> d = Decision(2, "overheat", True, False, 3, 2, "warning", detail=lambda: ("cylinder 2 hot", {"t_c": 95.0}))
    >>> (d.on, d.message, d.evidence)
    (True, 'cylinder 2 hot', {'t_c': 95.0})
    """

    __slots__ = ("cylinder", "kind", "on", "off", "k_on", "k_off", "severity", "_message", "_evidence", "_detail")

    def __init__(self, cylinder: int | None, kind: str, on: bool, off: bool, k_on: int, k_off: int, severity: str,
                 message: str | None = None, evidence: dict | None = None, *,
                 detail: Callable[[], tuple[str, dict]] | None = None):
        if detail is None and (message is None or evidence is None):
            raise ValueError("a Decision needs its message and evidence, or a detail that gives them")
        self.cylinder, self.kind, self.on, self.off = cylinder, kind, on, off
        self.k_on, self.k_off, self.severity = k_on, k_off, severity
        self._message, self._evidence, self._detail = message, evidence, detail

    def _explain(self) -> None:
        if self._detail is not None:
            self._message, self._evidence = self._detail()
            self._detail = None

    @property
    def message(self) -> str:
        self._explain()
        return self._message

    @property
    def evidence(self) -> dict:
        self._explain()
        return self._evidence

    def __repr__(self) -> str:
        return (f"Decision({self.cylinder!r}, {self.kind!r}, on={self.on!r}, off={self.off!r}, k_on={self.k_on}, "
                f"k_off={self.k_off}, {self.severity!r})")


@dataclass(frozen=True)
class Hold:
    """The statistic has no value this cycle: its latch holds still (neither count moves) and its open alert, if
    any, takes ``evidence`` (why)."""

    cylinder: int | None
    evidence: dict


@dataclass(frozen=True)
class Pressure:
    """The engine's pressure statistics in a usable cycle. imep_pa: the engine's mean IMEP; held: why the statistics
    hold still this cycle (a load change settling, a load not commissioned yet) with the learner's learning_cycles,
    else None and ewma (4, z), the EWMA of the indicators' change from ``band``'s mean, against the siblings'
    median change (``change_against_siblings``; rows as INDICATORS), and ``stats`` (leak_statistics of it, its
    standard errors those of the EWMA and of the band's mean); var each cylinder's EWMA's variance per unit of
    per-cycle variance (``ewma_variance`` times ``sibling_reference_variance`` times the leak signature's
    long-run-variance factor; the band mean's is not in it: core leak_change adds it), var_ratio the compression
    ratio's; long_run the two factors (``LongRunVariance.factor``: leak signature, compression ratio)."""

    imep_pa: float
    held: str | None = None
    learning_cycles: int = 0
    ewma: np.ndarray | None = None
    stats: LeakStatistics | None = None
    band: Band | None = None
    var: float = float("nan")
    var_ratio: float = float("nan")
    long_run: tuple[float, float] = (1.0, 1.0)


class _Every:
    """Holds every cylinder (what a rule used on its own is told the engine watches: ``Context.watching``)."""

    def __contains__(self, cylinder: object) -> bool:
        return True


_EVERY, _NONE = _Every(), frozenset()


def _every(name: str) -> Container[int | None]:
    return _EVERY


def _none(name: str) -> Container[int | None]:
    return _NONE


@dataclass
class Context:
    """What the engine shares with its rules in one cycle. cyl_flags: each cylinder's flag kinds (z sets, the
    ``_cyl<k>`` stripped); engine_flags: the others; baseline_at_start: the baseline before this cycle's learning;
    baseline: after it (a rule may add to it, the friction references: the engine keeps it as the rules leave it);
    pressure: the pressure statistics (None: no usable pressure this cycle); latching(name): the cylinders whose
    latch for that statistic is raised (as the earlier stages of this cycle left it); watching(name): the cylinders
    for which the engine keeps a latch or an open alert for that statistic. Where it keeps none, a Decision that is
    not on and a Hold change nothing, and a rule may leave them out (the engine's default holds every cylinder: a
    rule used on its own returns all): with 20 cylinders and six rules most of a cycle's ~140 decisions were such,
    and making and applying them was a third of the alert engine's time (design note 45). Each is one container a
    rule asks once a cycle, not a call per cylinder (the engine keeps them by name; ~110 calls a genset-v20 cycle
    before, design note 100)."""

    cyl_flags: list[set[str]]
    engine_flags: set[str] = field(default_factory=set)
    baseline_at_start: Baseline | None = None
    baseline: Baseline | None = None
    pressure: Pressure | None = None
    latching: Callable[[str], Container[int | None]] = _none
    watching: Callable[[str], Container[int | None]] = _every
    _smoothed_status: tuple[CycleResult, FrictionStatus] | None = field(default=None, repr=False)

    @property
    def n_cyl(self) -> int:
        return len(self.cyl_flags)

    def smoothed_status(self, result: CycleResult) -> FrictionStatus:
        """``friction_status(result.smoothed, result.flags)``, worked out once a cycle for every rule that reads it
        (the ring and the friction rules: ~40-80 us a genset-v20 call)."""
        kept = self._smoothed_status
        if kept is None or kept[0] is not result:
            kept = self._smoothed_status = (result, friction_status(result.smoothed, result.flags))
        return kept[1]


class Rule(Protocol):
    """The interface every alert rule has (module doc)."""

    name: str
    rests_on_baseline: bool

    def update(self, result: CycleResult, ctx: Context) -> list[Decision | Hold]: ...
