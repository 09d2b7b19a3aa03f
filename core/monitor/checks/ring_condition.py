"""One ring-condition figure per cylinder, with its sigma (issue 29 item 3): a worn ring or blow-by caught in any
cylinder, whether it appeared after commissioning or was there from the first cycle.

Two references, each read from the evidence that exists for the cylinder:

    since       the change since the commissioning baseline (or since the baseline the alerts learnt): the leak
                effect's change (pressure, every cylinder, always) and, where the friction is measured, the change
                of its friction excess over its measured siblings. Precise (a cylinder's own persistent offset
                cancels) but blind to what was there when the baseline was learnt.
    siblings    the deviation from the siblings now, without a baseline: the cylinder's windowed leak effect
                against its siblings' centre, allowing for the spread healthy cylinders keep (fuel spread, heat
                transfer; the shaft's twist is not in it where the monitor reads each cylinder at its own throw's
                angle, core.monitor.checks.ring_pressure.ThrowMotion: ``leak_allowance`` or the other cylinders'
                own spread, the larger)
                and, where measured, its friction excess over its siblings against ``friction_allowance``.

Each piece of evidence is put in units of the change that matters (``leak_scale`` of leak effect, ``friction_scale``
of friction excess: 1.0 is a worn ring at the alerts' floor), the pieces of one reference are combined by inverse
variance, and the figure is the reference whose ratio figure / sigma is the larger (``reference`` says which: 0 since,
1 siblings). The leak effect is (n_expansion_dev - n_compression_dev) / 2 of core.monitor.checks.ring_pressure: a leak
lowers the compression exponent and raises the expansion exponent against the siblings; a pressure gain error of the
cylinder's sensor cancels in both exponents (so it never reads as a leak); a TDC error of one cylinder bends both
exponents like a leak (the caller names it a sensor fault where the sensor checks flag it; where they do not, the
leak against the siblings is given as the TDC error that would read the same, ``TDC_LEAK_PER_DEG``: these
indicators cannot tell the two apart, and on an uncommissioned engine a per-cylinder TDC error of 0.2 deg is within
the installation's assumed tolerance).

How the siblings decide (``sibling_excess``): with four or more cylinders the centre is the median of the others and
the spread the others' median absolute deviation (one faulty cylinder moves neither). With three, a cylinder is a
minority when it stands off the mean of the other two while those two agree with each other: their half-difference
enters the spread, so when two cylinders disagree with each other neither the third nor they are named. With two
there is no minority (one against the other is not a majority): the sibling reference is NaN and only the change
since a baseline can name a cylinder; likewise with one.

Arrays in, arrays out, SI / dimensionless; the only state is the sibling window (``SiblingWindow``, explicit data:
``update_window`` takes it and gives it back). Plain numpy but for the sibling medians (one kernel,
``sibling_excess``, beside its readable reference ``sibling_excess_reference``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from frictionwatch.core.monitor.checks.ring_condition_kernels import ring_condition_kernel, sibling_kernel
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned

SINCE, SIBLINGS = 0, 1
_TUNED = read_tuned(MONITOR_RECORD)  # leak_allowance, hand-set, with its provenance (core.tuned)
# leak effect [exponent units] a TDC error of one cylinder of +1 deg reads as (the trace read late bends both
# polytropes like a leak): k9k-4cyl seed 5, 1700 rpm / 0.69, tdc_offset 0.5 deg on cylinder 2, uncommissioned, read
# +0.0113 against its siblings (bench/ring_condition.py healthy --mismatch tdc): 0.0227 / deg; genset-v20's windows
# 0.1 deg -> dn_c -0.0019, dn_e +0.0023 (core.monitor.checks.ring_pressure): 0.021 / deg
TDC_LEAK_PER_DEG = 0.022
REFERENCES = ("since_baseline", "against_siblings")


@dataclass(frozen=True)
class RingConditionSettings:
    """window: EWMA cycles of the sibling window of the leak effect; warmup: cycles before the sibling reference has
    a value. leak_scale: the leak effect [exponent units] that is one unit of the figure (service AlertConfig's
    leak_floor, 0.001: a 3 % leak on K9K read 0.0026). friction_scale: the friction excess over the siblings
    (relative) that is one unit (0.1: F1-F3 x 1.3 raises a cylinder's friction by ~15-20 %).
    leak_allowance: 1 sigma of the windowed leak effect of a healthy cylinder against its siblings (what no window
    removes). friction_allowance: the same for a measured friction's excess over its siblings (calibration, fuel
    spread). Tuned by bench/ring_condition.py on healthy runs of k9k-4cyl (seed 7, 1700 rpm / 0.69) and
    maruti-3cyl (seed 7, 3000 rpm / 0.8) with their load steps; see the numbers' own comments."""

    window: float = 200.0
    warmup: int = 100
    leak_scale: float = 0.001
    friction_scale: float = 0.1
    # healthy k9k-4cyl seed 7 and maruti-3cyl seed 7 (3 % COV, 3000 cycles, load steps 1.0 <-> 0.6): windowed
    # sibling leak effect at most 0.00058 (k9k) and 0.00123 (maruti cylinder 2, at 60 % load) off its siblings
    # (bench/ring_condition.py healthy runs, before the throw-angle reading); 0.001 as 1 sigma. Not tuned on
    # genset-v20 (validation only): read at its throws' angles its healthy cylinders keep SD 0.0003-0.00045 of the
    # sibling median (seeds 7, 3, 11; at the flywheel's angle 0.0037: design note 32); where siblings scatter more
    # their own MAD spread is used
    leak_allowance: float = _TUNED["RING_LEAK_ALLOWANCE"].value
    # the friction excess of a healthy measured cylinder over its siblings: the calibration's TDC / gain share
    # (uncalibrated, ~10 % of a cylinder's friction on K9K; core/model/calibration.py) -- a prior, not tuned
    friction_allowance: float = 0.1


DEFAULT = RingConditionSettings()


class SiblingWindow(NamedTuple):
    """The sibling reference's state: EWMA mean (z,) and variance (z,) of each cylinder's leak effect, the cycles
    folded."""

    mean: np.ndarray
    var: np.ndarray
    count: int

    @staticmethod
    def empty(n_cyl: int) -> SiblingWindow:
        return SiblingWindow(np.zeros(n_cyl), np.zeros(n_cyl), 0)


@dataclass(frozen=True)
class RingCondition:
    """Per cylinder (z,): ``figure`` in units of a worn ring at the floor (>= 1: as large as what matters) and its
    1 sigma; ``reference`` (int, SINCE or SIBLINGS; -1: no evidence); the two references' own figures and sigmas
    (``since``, ``since_sigma``, ``siblings``, ``siblings_sigma``: NaN where a reference has no value) and the
    evidence under them: ``leak_change`` and its sigma, ``leak_siblings`` and its sigma [exponent units],
    ``friction_change`` / ``friction_siblings`` (relative excess; NaN where the friction is not measured)."""

    figure: np.ndarray
    sigma: np.ndarray
    reference: np.ndarray
    since: np.ndarray
    since_sigma: np.ndarray
    siblings: np.ndarray
    siblings_sigma: np.ndarray
    leak_change: np.ndarray
    leak_change_sigma: np.ndarray
    leak_siblings: np.ndarray
    leak_siblings_sigma: np.ndarray
    friction_change: np.ndarray
    friction_siblings: np.ndarray

    @property
    def z(self) -> np.ndarray:
        """(z,) figure / sigma (NaN where there is none)."""
        with np.errstate(divide="ignore", invalid="ignore"):
            return self.figure / self.sigma

    def evidence(self, k: int) -> dict:
        """Cylinder k's (0-based) figures as a JSON-able dict (None for NaN)."""
        def num(v: float) -> float | None:
            return float(v) if np.isfinite(v) else None
        ref = int(self.reference[k])
        return {"ring_condition": num(self.figure[k]), "ring_condition_sigma": num(self.sigma[k]),
                "ring_condition_reference": REFERENCES[ref] if ref >= 0 else None,
                "ring_condition_since_baseline": num(self.since[k]),
                "ring_condition_since_baseline_sigma": num(self.since_sigma[k]),
                "ring_condition_against_siblings": num(self.siblings[k]),
                "ring_condition_against_siblings_sigma": num(self.siblings_sigma[k]),
                "leak_effect_change": num(self.leak_change[k]),
                "leak_effect_change_sigma": num(self.leak_change_sigma[k]),
                "leak_effect_against_siblings": num(self.leak_siblings[k]),
                "leak_effect_against_siblings_sigma": num(self.leak_siblings_sigma[k]),
                "friction_excess_change": num(self.friction_change[k]),
                "friction_excess_against_siblings": num(self.friction_siblings[k]),
                "tdc_equivalent_deg": num(self.leak_siblings[k] / TDC_LEAK_PER_DEG)}


def leak_effect(n_compression_dev: np.ndarray, n_expansion_dev: np.ndarray) -> np.ndarray:
    """(z,) the leak effect (n_expansion_dev - n_compression_dev) / 2 of each cylinder [exponent units]: > 0 where the
    compression exponent is below its siblings' and the expansion exponent above (trapped mass lost past the rings)."""
    return 0.5 * (np.asarray(n_expansion_dev, dtype=np.float64) - np.asarray(n_compression_dev, dtype=np.float64))


def update_window(window: SiblingWindow, effect: np.ndarray, settings: RingConditionSettings = DEFAULT
                  ) -> SiblingWindow:
    """The sibling window after one usable cycle's leak effect (z,) (a NaN entry leaves that cylinder's unchanged).
    An EWMA over ``settings.window`` cycles (a running mean until then) and the variance about it."""
    x = np.asarray(effect, dtype=np.float64)
    n = window.count + 1
    g = max(1.0 / settings.window, 1.0 / n)
    ok = np.isfinite(x)
    d = np.where(ok, x - window.mean, 0.0)
    if window.count == 0:
        return SiblingWindow(np.where(ok, x, 0.0), np.zeros_like(x), n)
    return SiblingWindow(window.mean + g * d, (1.0 - g) * (window.var + g * d * d), n)


def window_sigma(window: SiblingWindow, settings: RingConditionSettings = DEFAULT) -> np.ndarray:
    """(z,) the standard error of the window's mean: its per-cycle spread times sqrt(g / (2 - g)) for independent
    cycles (a running mean: 1 / sqrt(n))."""
    g = max(1.0 / settings.window, 1.0 / max(window.count, 1))
    return np.sqrt(np.maximum(window.var, 0.0) * g / (2.0 - g))


def sibling_excess(x: np.ndarray, se: np.ndarray, allowance: float) -> tuple[np.ndarray, np.ndarray]:
    """Each cylinder's x (z,) against its siblings (module doc): (x_k - centre of the others, its 1 sigma), with
    se (z,) the standard error of each x and ``allowance`` the spread a healthy cylinder keeps from its siblings.
    NaN where there is no minority to decide (z < 3, or fewer than two finite siblings).

    >>> dev, s = sibling_excess(np.array([0.004, 0.0, 0.0002]), np.zeros(3), 0.001)
    >>> np.round(dev / s, 2).tolist()    # cylinder 1 stands off two that agree
    [3.88, -0.64, -0.52]
    >>> dev, s = sibling_excess(np.array([0.004, 0.0, 0.004]), np.zeros(3), 0.001)
    >>> np.round(dev / s, 2).tolist()    # two against one: the healthy minority is not a fault (negative)
    [0.58, -4.0, 0.58]
    """
    x = np.ascontiguousarray(x, dtype=np.float64)
    se = np.ascontiguousarray(se, dtype=np.float64)
    dev, sig = np.full(x.shape[0], np.nan), np.full(x.shape[0], np.nan)
    if x.shape[0] >= 3:
        # one kernel for the z medians (``sibling_excess_reference``'s numbers): as numpy, one matrix of every
        # cylinder's others and one sort, it cost ~80 us a genset-v20 cycle (load ~5), 9 % of serve's busy time
        # with 4 gensets (py-spy), the ring rule's largest part
        sibling_kernel(x, se, float(allowance), dev, sig)
    return dev, sig


def sibling_excess_reference(x: np.ndarray, se: np.ndarray, allowance: float) -> tuple[np.ndarray, np.ndarray]:
    """``sibling_excess`` one cylinder at a time, as the module doc reads: the readable reference its tests compare
    with (rtol 1e-12)."""
    x = np.asarray(x, dtype=np.float64)
    se = np.asarray(se, dtype=np.float64)
    z = x.shape[0]
    dev, sig = np.full(z, np.nan), np.full(z, np.nan)
    if z < 3:
        return dev, sig
    for k in range(z):
        others = np.delete(x, k)
        o_se = np.delete(se, k)
        ok = np.isfinite(others)
        if not np.isfinite(x[k]) or ok.sum() < 2:
            continue
        o, o_se = others[ok], o_se[ok]
        if o.shape[0] == 2:  # three cylinders: the mean of the two others, their disagreement as spread
            centre = 0.5 * (o[0] + o[1])
            spread = abs(o[0] - o[1]) / np.sqrt(2.0)
            centre_var = 0.25 * (o_se[0] ** 2 + o_se[1] ** 2) + 0.5 * spread ** 2
        else:
            centre = float(np.median(o))
            spread = 1.4826 * float(np.median(np.abs(o - centre)))
            # the median's own sigma from the others' measured scatter (as the two others' for three cylinders);
            # the allowance is the suspect's own healthy offset, counted once below
            centre_var = (np.pi / 2.0) * (spread ** 2 + float(np.mean(o_se ** 2))) / o.shape[0]
        dev[k] = x[k] - centre
        sig[k] = np.sqrt(se[k] ** 2 + max(spread, allowance) ** 2 + centre_var)
    return dev, sig


def friction_excess(torque: np.ndarray, sigma: np.ndarray, measured: np.ndarray, *, screened: bool = True
                    ) -> tuple[np.ndarray, np.ndarray]:
    """(excess, sigma) (z,): each measured cylinder's friction torque over its measured siblings' mean, minus 1, with
    the combined 1 sigma (the siblings' mean's sigma over their count). NaN where the cylinder is not measured or
    has fewer than two measured siblings.

    ``screened`` (the ring-condition figure's use): a cylinder with a non-finite torque or sigma is not measured, and
    a cylinder whose siblings' mean is not positive gets NaN. False (service FrictionRule's, whose numbers are kept as
    they were): ``measured`` as it is -- a non-finite torque or sigma enters its siblings' means (NaN), a reference of
    zero or below is divided by.

    Every leave-one-out mean in one reduction over an (n, n - 1) index matrix (row j: the measured cylinders but the
    j-th): the same sums as ``friction_excess_reference``'s np.mean per cylinder (a row is summed as the 1-D array
    would be), one call instead of n (genset-v20's 20: ~200 us to ~20, design note 73).

    >>> e, s = friction_excess(np.array([6.0, 5.0, 5.0, 5.0]), np.full(4, 0.1), np.ones(4, bool))
    >>> np.round(e, 3).tolist(), round(float(s[0]), 4)
    ([0.2, -0.062, -0.062, -0.062], 0.0231)
    """
    t = np.asarray(torque, dtype=np.float64)
    s = np.asarray(sigma, dtype=np.float64)
    m = np.asarray(measured, dtype=bool)
    if screened:
        m = m & np.isfinite(t) & np.isfinite(s)
    z = t.shape[0]
    exc, sig = np.full(z, np.nan), np.full(z, np.nan)
    idx = np.flatnonzero(m)
    n = idx.size
    if n < 3:  # each needs two measured siblings
        return exc, sig
    cols = np.arange(n - 1)
    others = idx[cols + (cols >= np.arange(n)[:, None])]  # row j: idx without its j-th
    with np.errstate(all="ignore"):  # unscreened: inf - inf, x / 0 give what they give (NaN, inf), quietly
        ref = np.add.reduce(t[others], axis=1) / (n - 1)
        sib2 = np.add.reduce(s[others] ** 2, axis=1) / (n - 1)
        if screened:  # a reference of zero or below (or NaN) has no excess
            ok = ref > 0
            idx, ref, sib2 = idx[ok], ref[ok], sib2[ok]
        exc[idx] = t[idx] / ref - 1.0
        sig[idx] = np.sqrt(s[idx] ** 2 + sib2 / (n - 1)) / ref
    return exc, sig


def friction_excess_reference(torque: np.ndarray, sigma: np.ndarray, measured: np.ndarray, *,
                              screened: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """``friction_excess`` one cylinder at a time, a np.mean of its siblings each: the readable reference its tests
    compare with (rtol 1e-12)."""
    t = np.asarray(torque, dtype=np.float64)
    s = np.asarray(sigma, dtype=np.float64)
    m = np.asarray(measured, dtype=bool)
    if screened:
        m = m & np.isfinite(t) & np.isfinite(s)
    z = t.shape[0]
    exc, sig = np.full(z, np.nan), np.full(z, np.nan)
    for k in np.flatnonzero(m):
        others = np.flatnonzero(m)
        others = others[others != k]
        if others.size < 2:
            continue
        with np.errstate(all="ignore"):
            ref = float(np.mean(t[others]))
            if screened and not ref > 0:
                continue
            exc[k] = t[k] / ref - 1.0
            sig[k] = np.sqrt(s[k] ** 2 + float(np.mean(s[others] ** 2)) / others.size) / ref
    return exc, sig


def combine(values: np.ndarray, sigmas: np.ndarray, scales: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Inverse-variance combination of m pieces of evidence (m, z) with sigmas (m, z), each divided by its scale
    (m,) first: (figure (z,), sigma (z,)); NaN pieces are left out, NaN where none is left.

    >>> f, s = combine(np.array([[0.002], [0.2]]), np.array([[0.0005], [0.05]]), np.array([0.001, 0.1]))
    >>> round(float(f[0]), 3), round(float(s[0]), 3)
    (2.0, 0.354)
    """
    v = np.asarray(values, dtype=np.float64) / np.asarray(scales, dtype=np.float64)[:, None]
    s = np.asarray(sigmas, dtype=np.float64) / np.asarray(scales, dtype=np.float64)[:, None]
    ok = np.isfinite(v) & np.isfinite(s) & (s > 0)
    w = np.where(ok, 1.0 / np.where(ok, s, 1.0) ** 2, 0.0)
    wsum = w.sum(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        fig = np.where(wsum > 0, (w * np.where(ok, v, 0.0)).sum(axis=0) / wsum, np.nan)
        sig = np.where(wsum > 0, 1.0 / np.sqrt(wsum), np.nan)
    return fig, sig


def ring_condition(leak_change: np.ndarray, leak_change_sigma: np.ndarray, window: SiblingWindow,
                   friction_change: np.ndarray, friction_change_sigma: np.ndarray,
                   friction_now: np.ndarray, friction_now_sigma: np.ndarray,
                   settings: RingConditionSettings = DEFAULT, siblings: bool = True) -> RingCondition:
    """``ring_condition_reference``'s figure by one kernel (core.monitor.checks.ring_condition_kernels; its ~15
    numpy calls were ~110 us a genset-v20 cycle in serve, design note 86; tests/core/test_ring_condition.py: equal
    within rtol 1e-14)."""
    lc, lc_s = _f(leak_change), _f(leak_change_sigma)
    fc = _f(friction_change)
    out, ref = ring_condition_kernel(
        (lc, lc_s, fc, _f(friction_change_sigma), _f(friction_now), _f(friction_now_sigma)), _f(window.mean),
        _f(window.var), np.array([settings.leak_scale, settings.friction_scale, settings.window,
                                  settings.leak_allowance, settings.friction_allowance]),
        np.array([window.count, settings.warmup, siblings], dtype=np.int64))
    return RingCondition(out[0], out[1], ref, out[2], out[3], out[4], out[5], lc, lc_s, out[6], out[7], fc, out[8])


def _f(a: np.ndarray) -> np.ndarray:
    """``a`` as a C-ordered float64 array (itself when it is one)."""
    return np.ascontiguousarray(a, dtype=np.float64)


def ring_condition_reference(leak_change: np.ndarray, leak_change_sigma: np.ndarray, window: SiblingWindow,
                   friction_change: np.ndarray, friction_change_sigma: np.ndarray,
                   friction_now: np.ndarray, friction_now_sigma: np.ndarray,
                   settings: RingConditionSettings = DEFAULT, siblings: bool = True) -> RingCondition:
    """The ring condition of every cylinder (module doc) from: the leak effect's change since the baseline (z,) and
    its sigma (NaN: no baseline at this load); the sibling window of the leak effect; the friction excess's change
    since its baseline (z,) and its sigma, and the friction excess over the siblings now (z,) and its sigma (NaN
    where not measured: ``friction_excess``). ``siblings`` False leaves the sibling reference out (NaN): after an
    operator declared the present state normal (a rebaseline), the siblings would name what was declared. The plain
    numpy reference of ``ring_condition``."""
    z = window.mean.shape[0]
    scales = np.array([settings.leak_scale, settings.friction_scale])
    since, since_s = combine(np.vstack([leak_change, friction_change]),
                             np.vstack([leak_change_sigma, friction_change_sigma]), scales)
    if siblings and window.count >= settings.warmup:
        leak_sib, leak_sib_s = sibling_excess(window.mean, window_sigma(window, settings), settings.leak_allowance)
    else:
        leak_sib, leak_sib_s = np.full(z, np.nan), np.full(z, np.nan)
    # against the siblings the friction only adds to a leak that is there: an uncalibrated cylinder's gain error
    # books its indicated work as friction (3 % on a K9K cylinder read +46 %) and leaves both exponents alone
    fr_now = np.where(siblings & (leak_sib > 0.0), np.asarray(friction_now, dtype=np.float64), np.nan)
    fr_now_s = np.sqrt(np.asarray(friction_now_sigma, dtype=np.float64) ** 2 + settings.friction_allowance ** 2)
    sib, sib_s = combine(np.vstack([leak_sib, fr_now]), np.vstack([leak_sib_s, fr_now_s]), scales)
    with np.errstate(divide="ignore", invalid="ignore"):
        z_since = np.where(np.isfinite(since), since / since_s, -np.inf)
        z_sib = np.where(np.isfinite(sib), sib / sib_s, -np.inf)
    use_sib = z_sib > z_since
    ref = np.where(np.isfinite(since) | np.isfinite(sib), np.where(use_sib, SIBLINGS, SINCE), -1)
    figure = np.where(use_sib, sib, since)
    sigma = np.where(use_sib, sib_s, since_s)
    return RingCondition(figure, sigma, ref.astype(np.int64), since, since_s, sib, sib_s,
                         np.asarray(leak_change, dtype=np.float64), np.asarray(leak_change_sigma, dtype=np.float64),
                         leak_sib, leak_sib_s, np.asarray(friction_change, dtype=np.float64), fr_now)


def leak_change(ewma: np.ndarray, cov: np.ndarray, ewma_var: float, baseline_cycles: int) -> tuple[np.ndarray, np.ndarray]:
    """The leak effect's change since a baseline and its 1 sigma (z,): from the EWMA (4, z) of the ring indicators'
    change from the baseline band's mean (rows compression_ratio, n_compression_dev, n_expansion_dev,
    expansion_deficit: service.alert_baseline.INDICATORS) with ``ewma_var`` its variance per unit of per-cycle variance
    (g / (2 - g) at a fixed factor g for independent cycles; the caller's, service.alert_interface.Pressure.var, holds
    the healthy cycles' long-run-variance factor too: design note 71), and that band's per-cycle covariance (z, 4, 4)
    over ``baseline_cycles``: the EWMA's standard error and the band mean's own (as for independent cycles), both of
    the per-cycle spread of (dn_e - dn_c) / 2.

    >>> cov = np.zeros((1, 4, 4)); cov[0, 1, 1] = cov[0, 2, 2] = 4e-6
    >>> c, s = leak_change(np.array([[0.0], [-0.001], [0.001], [0.0]]), cov, 0.02 / 1.98, 200)
    >>> round(float(c[0]), 4), round(float(s[0]), 6)
    (0.001, 0.000174)
    """
    e = np.asarray(ewma, dtype=np.float64)
    c = np.asarray(cov, dtype=np.float64)
    change = 0.5 * (e[2] - e[1])
    var = 0.25 * (c[:, 1, 1] + c[:, 2, 2] - 2.0 * c[:, 1, 2])
    se2 = ewma_var + 1.0 / max(int(baseline_cycles), 1)
    return change, np.sqrt(np.maximum(var, 0.0) * se2)
