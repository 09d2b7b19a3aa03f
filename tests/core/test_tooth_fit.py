"""The fused tooth fit (core.monitor.teeth.flywheel prepare_fit / fit_prepared / ToothLearner.update, core.monitor.teeth.tooth_fit) against the
plain numpy/scipy implementation it replaced (kept here as ``*_reference``): same FlywheelMotion, learner state and
pattern cache to 1e-10 relative (the bar of this speed work), on seeded cycles of the real sizes (genset-v20: 317
edges, 24 harmonics, 24 tooth nuisances + the drift pattern) and small ones (deutz-1cyl, k9k-4cyl)."""

from types import SimpleNamespace

import numba
import numpy as np
import pytest
import scipy.linalg
from frictionwatch.core.monitor.identify.parameters import tooth_patterns
from frictionwatch.core.monitor.teeth.flywheel import FitSetup, LearnerSettings, ToothLearner, fit_prepared, prepare_fit
from frictionwatch.core.monitor.teeth.tooth_fit import fit_cycle_teeth

FOUR_PI = 4.0 * np.pi
REL = 1e-10


@numba.njit(cache=True)
def _fit_design(tau, period, w1, n_drift, n_harm, design):
    """The former design kernel (part of the reference): [1, (u (u - 1)), cos(m w1 tau)..., sin(m w1 tau)...] per
    edge, angle-addition recurrence re-seeded with a direct cos/sin every 8 orders."""
    n = tau.shape[0]
    c0 = n_drift
    s0 = n_drift + n_harm
    for i in range(n):
        t = tau[i]
        design[i, 0] = 1.0
        if n_drift == 2:
            u = t / period
            design[i, 1] = u * (u - 1.0)
        c = 1.0
        s = 0.0
        c1 = 1.0
        s1 = 0.0
        for m in range(n_harm):
            if m % 8 == 0:
                a = t * (w1 * (m + 1))
                c = np.cos(a)
                s = np.sin(a)
                if m == 0:
                    c1 = c
                    s1 = s
            else:
                c, s = c * c1 - s * s1, s * c1 + c * s1
            design[i, c0 + m] = c
            design[i, s0 + m] = s


def prepare_fit_reference(ticks, tick_hz, n_harmonics, patterns, fit_harmonics, drift):
    n_edges = ticks.shape[0]
    m_fit = max(n_harmonics, fit_harmonics or n_harmonics)
    n_drift = 2 if drift else 1
    n_par = 2 * m_fit + n_drift
    tau = (ticks - ticks[0]).astype(np.float64) / tick_hz
    period = float(tau[-1])
    omega = FOUR_PI / period
    design = np.empty((n_edges, n_par))
    _fit_design(tau, period, 0.5 * omega, n_drift, m_fit, design)
    scale = np.sqrt(np.einsum("ij,ij->j", design, design))
    d = design / scale
    factor = scipy.linalg.lu_factor(d.T @ d, check_finite=False)
    c0, s0 = n_drift, n_drift + m_fit
    sol = scipy.linalg.lu_solve(factor, d.T @ patterns, check_finite=False) / scale[:, None]
    pat = sol[c0: c0 + n_harmonics] - 1j * sol[s0: s0 + n_harmonics]
    return SimpleNamespace(tau=tau, period=period, omega=omega, design=design, scale=scale, scaled=d, factor=factor,
                           n_harmonics=n_harmonics, m_fit=m_fit, n_drift=n_drift, pattern_harmonics=pat)


def fit_prepared_reference(setup, ang):
    phi = ang - ang[0] - setup.omega * setup.tau
    coef = scipy.linalg.lu_solve(setup.factor, setup.scaled.T @ phi, check_finite=False) / setup.scale
    resid = phi - setup.design @ coef
    m, c0, s0 = setup.n_harmonics, setup.n_drift, setup.n_drift + setup.m_fit
    return SimpleNamespace(period=setup.period, omega_mean=setup.omega, harmonics=coef[c0: c0 + m] - 1j * coef[s0: s0 + m],
                           offset=float(coef[0]), drift=float(coef[1]) if setup.n_drift == 2 else 0.0,
                           residual_rms=float(np.sqrt(np.mean(resid**2))), n_edges=tau_len(setup),
                           edge_residual=resid, pattern_harmonics=setup.pattern_harmonics)


def tau_len(setup):
    return int(setup.tau.shape[0])


def update_reference(correction, count, tooth_index, residual, memory):
    n = correction.shape[0]
    pos = np.asarray(tooth_index[:-1]) % n
    r = np.asarray(residual[:-1])
    total = np.bincount(pos, weights=r, minlength=n)
    hits = np.bincount(pos, minlength=n)
    seen = hits > 0
    g = max(1.0 - memory, 1.0 / (count + 1))
    c = correction.copy()
    c[seen] -= g * total[seen] / hits[seen]
    c[seen] -= c[seen].mean()
    return c, count + 1


def fit_cycle_teeth_reference(cycle, wheel_teeth, n_harmonics, n_nuisance, teeth, cache, drift_nuisance,
                              fit_harmonics, fit_drift, learn_teeth, tooth_memory, tooth_refit_cycles,
                              tooth_speed_step=np.inf):
    correction, count, last_period = teeth
    nominal = np.asarray(cycle.tooth_angle, dtype=np.float64)
    end = int(np.searchsorted(nominal, nominal[0] + FOUR_PI - 1e-6))
    ticks = cycle.tooth_ticks[: end + 1]
    pos = np.asarray(cycle.tooth_index[: end + 1]) % wheel_teeth
    nominal = nominal[: end + 1]
    if n_nuisance:
        rel_angle = nominal - nominal[0]
        if cache is not None and np.array_equal(cache[0], rel_angle):
            patterns = cache[1]
        else:
            patterns = tooth_patterns(nominal, n_nuisance // 2)
            cache = (rel_angle, patterns)
    else:
        patterns = np.zeros((nominal.size, 0))
    if drift_nuisance:
        u = (ticks - ticks[0]) / float(ticks[-1] - ticks[0])
        patterns = np.column_stack([patterns, u * (u - 1.0)])
    setup = prepare_fit_reference(ticks, cycle.tick_hz, n_harmonics, patterns, fit_harmonics, fit_drift)
    fly = fit_prepared_reference(setup, nominal + correction[pos])
    speed_moved = last_period > 0 and abs(last_period / fly.period - 1.0) > tooth_speed_step
    if learn_teeth and not speed_moved:
        correction, count = update_reference(correction, count, pos, fly.edge_residual, tooth_memory)
        if count <= tooth_refit_cycles:
            fly = fit_prepared_reference(setup, nominal + correction[pos])
    return fly, (correction, count, fly.period), float(nominal[0] + correction[pos[0]]), cache


def rel_diff(a, b):
    a, b = np.asarray(a), np.asarray(b)
    if a.size == 0 and b.size == 0:
        return 0.0
    return float(np.max(np.abs(a - b)) / max(np.max(np.abs(b)), 1e-300))


FIELDS = ("period", "omega_mean", "harmonics", "offset", "drift", "residual_rms", "n_edges", "edge_residual",
          "pattern_harmonics")


def assert_same_motion(new, ref, angle_max=0.0, rel=REL):
    """1e-10 relative on every field; the edge residual is a difference of angles of size ``angle_max`` (up to
    4 pi + the first edge's angle), so it also gets 16 ulps of those: once the learner feeds back, a 1e-16 change in
    a correction moves an edge angle by one ulp (1.8e-15 rad at 12 rad), ~3e-10 of a 6e-6 rad residual."""
    for f in FIELDS:
        a, b = getattr(new, f), getattr(ref, f)
        if f == "edge_residual":
            assert np.max(np.abs(a - b)) <= rel * np.max(np.abs(b)) + 16 * np.spacing(angle_max), f
        else:
            assert rel_diff(a, b) <= rel, f


def synthetic_cycles(wheel_teeth, gap, n_cycles, seed, rpm=1500.0, tick_hz=2e7):
    """Tooth edges of consecutive cycles: a wheel of ``wheel_teeth`` positions with ``gap`` missing teeth, a fixed
    tooth-spacing error (0.05 deg rms, the monitor's default prior), speed ripple at orders 0.5..6 and 25 ns timing
    jitter; the cycle starts at a varying wheel position like the assembler's (drivers.assembly.cycles)."""
    rng = np.random.default_rng(seed)
    pitch = 2 * np.pi / wheel_teeth
    err = np.radians(0.05) * rng.standard_normal(wheel_teeth)
    err -= err.mean()
    present = np.ones(wheel_teeth, bool)
    present[wheel_teeth - gap:] = False
    omega = rpm * np.pi / 30
    out = []
    for c in range(n_cycles):
        start = int(rng.integers(0, wheel_teeth - gap))
        idx = np.arange(start, start + 2 * wheel_teeth + 1)
        idx = idx[present[idx % wheel_teeth]]
        idx = idx[idx <= start + 2 * wheel_teeth]
        nominal = (idx - start) * pitch
        true = nominal + err[idx % wheel_teeth] - err[start]
        orders = np.arange(1, 13) * 0.5
        amp = 2e-3 / orders * (1 + 0.1 * rng.standard_normal(orders.size))
        ph = rng.uniform(0, 2 * np.pi, orders.size)
        period = FOUR_PI / omega * (1 + 0.01 * rng.standard_normal())
        # time of each edge from angle: t(theta) = theta/omega_c + ripple (a small angle-to-time map)
        x = true / FOUR_PI
        t = period * (x + np.sum(amp[:, None] * np.sin(2 * np.pi * orders[:, None] * 2 * x[None] + ph[:, None]),
                                 axis=0) / FOUR_PI * (1 - 0 * x))
        t = t - t[0] + 25e-9 * rng.standard_normal(t.size)
        t[0] = 0.0
        ticks = np.round(t * tick_hz).astype(np.int64) + 10_000_000 * (c + 1)
        out.append(SimpleNamespace(tooth_angle=nominal + 7.0, tooth_ticks=ticks, tooth_index=idx, tick_hz=tick_hz))
    return out


# (wheel positions, missing teeth, harmonics M, fit harmonics, nuisances): genset-v20 is 120-2 at 24 orders (the
# monitor's sizes: 317 edges, P = 49, 25 pattern columns); deutz-1cyl / k9k-4cyl style 60-2 wheels at 12 and 16
SIZES = [(160, 1, 24, 24, 24), (60, 2, 12, 12, 12), (60, 2, 16, 20, 16)]


@pytest.mark.parametrize("wheel_teeth,gap,m,m_fit,n_nuis", SIZES)
@pytest.mark.parametrize("fit_drift", [False, True])
def test_fit_cycle_teeth_matches_reference(wheel_teeth, gap, m, m_fit, n_nuis, fit_drift):
    check_against_reference(wheel_teeth, gap, m, m_fit, n_nuis, fit_drift, drift_nuisance=True, learn=True)


@pytest.mark.parametrize("n_nuis,drift_nuisance,learn", [(0, False, True), (0, True, False), (12, False, False)])
def test_fit_cycle_teeth_options_match_reference(n_nuis, drift_nuisance, learn):
    check_against_reference(60, 2, 12, 14, n_nuis, False, drift_nuisance, learn)


def test_fit_cycle_teeth_speed_step_matches_reference():
    """The learner skips a cycle whose period moved beyond tooth_speed_step from the last fitted one's: the
    synthetic cycles' periods scatter by 1 % rms, so a 1 % step skips some of the 8 and learns from others."""
    skipped = check_against_reference(60, 2, 12, 12, 12, False, True, True, speed_step=0.01)
    assert 0 < skipped < 7


def check_against_reference(wheel_teeth, gap, m, m_fit, n_nuis, fit_drift, drift_nuisance, learn,
                            speed_step=np.inf):
    cycles = synthetic_cycles(wheel_teeth, gap, 8, seed=wheel_teeth + m)
    # the monitor fits without the drift column (MonitorConfig.fit_drift=False): 1e-10. With it, the column is
    # nearly collinear with order 0.5 over one cycle (core.monitor.monitor docs): the scaled normal matrix has a condition
    # number 9e4..8e5 at these sizes (1.4..3.6 without) and either implementation is only good to ~1e-13 cond: 1e-6
    rel = 1e-6 if fit_drift else REL
    teeth_new = ToothLearner.empty(wheel_teeth)
    teeth_ref = (np.zeros(wheel_teeth), 0, 0.0)
    cache_new = cache_ref = None
    skipped = 0
    for cyc in cycles:
        args = (wheel_teeth, m, n_nuis)
        tail = (drift_nuisance, m_fit, fit_drift)
        learning = (learn, 1.0 - 1.0 / 100.0, 4, speed_step)
        count_before = teeth_new.count
        fly, teeth_new, th_new, cache_new = fit_cycle_teeth(cyc, *args, teeth_new, cache_new, *tail,
                                                            LearnerSettings(*learning))
        ref, teeth_ref, th_ref, cache_ref = fit_cycle_teeth_reference(cyc, *args, teeth_ref, cache_ref, *tail,
                                                                      *learning)
        assert_same_motion(fly, ref, float(np.max(np.abs(cyc.tooth_angle))), rel)
        assert teeth_new.count == teeth_ref[1] and teeth_new.period == pytest.approx(teeth_ref[2], rel=1e-14)
        skipped += learn and teeth_new.count == count_before
        assert rel_diff(teeth_new.correction, teeth_ref[0]) <= rel
        assert th_new == pytest.approx(th_ref, rel=1e-14)
        if n_nuis:
            assert np.array_equal(cache_new.edge_angles, cache_ref[0]) and np.array_equal(cache_new.patterns, cache_ref[1])
        else:
            assert cache_new is None and cache_ref is None
        assert fly.pattern_harmonics.shape == (m, n_nuis + int(drift_nuisance))
    return skipped


@pytest.mark.parametrize("seed", [0, 1])
def test_prepare_and_refit_match_reference_without_patterns(seed):
    cyc = synthetic_cycles(60, 2, 1, seed)[0]
    ang = cyc.tooth_angle
    setup = prepare_fit(cyc.tooth_ticks, cyc.tick_hz, 10, None, 12, drift=True)
    assert isinstance(setup, FitSetup) and setup.pattern_harmonics.shape == (10, 0)
    ref_setup = prepare_fit_reference(cyc.tooth_ticks, cyc.tick_hz, 10, np.zeros((ang.size, 0)), 12, True)
    assert_allclose_rel(setup.design, ref_setup.design)
    assert_allclose_rel(setup.scaled, ref_setup.scaled)
    for shift in (0.0, 1e-4):  # the refit reuses the setup with corrected angles
        a = ang + shift * np.sin(3 * ang)
        assert_same_motion(fit_prepared(setup, a), fit_prepared_reference(ref_setup, a))


def assert_allclose_rel(a, b):
    assert rel_diff(a, b) <= REL


def test_tooth_learner_update_matches_reference():
    rng = np.random.default_rng(5)
    n = 60
    learner = ToothLearner(1e-4 * rng.standard_normal(n), 3)
    idx = np.arange(17, 17 + 2 * n - 3)  # a gap: some positions hit once, the closing edge ignored
    resid = 1e-3 * rng.standard_normal(idx.size)
    new = learner.update(idx, resid, 0.99)
    want, count = update_reference(learner.correction, learner.count, idx, resid, 0.99)
    assert new.count == count == 4
    assert rel_diff(new.correction, want) <= 1e-13
    assert learner.correction is not new.correction  # frozen: the old state is untouched


def test_bad_edges_raise_value_error():
    cyc = synthetic_cycles(60, 2, 1, 3)[0]
    ticks = cyc.tooth_ticks.copy()
    ticks[5] = ticks[4]
    with pytest.raises(ValueError, match="strictly increasing"):
        prepare_fit(ticks, cyc.tick_hz, 10)
    setup = prepare_fit(cyc.tooth_ticks, cyc.tick_hz, 10)
    with pytest.raises(ValueError, match="720 deg"):
        fit_prepared(setup, cyc.tooth_angle * 0.99)
    bad = cyc.tooth_angle.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="strictly increasing"):
        fit_prepared(setup, bad)


def window_reference(nominal, cached_rel):
    end = int(np.searchsorted(nominal, nominal[0] + FOUR_PI - 1e-6))
    if end >= nominal.shape[0] or abs(nominal[end] - nominal[0] - FOUR_PI) > 1e-6:
        return -1, False, 0
    rel = nominal[: end + 1] - nominal[0]
    hit = bool(np.array_equal(cached_rel, rel))
    period = int(np.searchsorted(rel, 2 * np.pi - 1e-9, side="right"))
    ok = 0 < period and np.all(np.abs(rel[period:] - rel[: rel.size - period] - 2 * np.pi) <= 1e-9)
    return end, hit, period if ok else 0


@pytest.mark.parametrize("seed", range(4))
def test_cycle_window_matches_numpy(seed):
    """_cycle_window = np.searchsorted + np.array_equal of the relative angles + the revolution period."""
    from frictionwatch.core.monitor.teeth.tooth_fit import _cycle_window

    rng = np.random.default_rng(seed)
    wheel, gap = [(60, 2), (36, 1), (160, 1), (120, 0)][seed]
    cyc = synthetic_cycles(wheel, gap, 1, seed)[0]
    extra = np.concatenate([cyc.tooth_angle, cyc.tooth_angle[-1] + np.cumsum(rng.uniform(0.05, 0.1, 3))])
    rel = cyc.tooth_angle - cyc.tooth_angle[0]
    for nominal, cached in [(extra, rel), (extra, rel + 1e-15), (extra, rel[:-1]), (extra, np.zeros(0)),
                            (cyc.tooth_angle[:-2], rel), (extra * 1.001, rel)]:
        got = _cycle_window(np.ascontiguousarray(nominal), cached)
        assert tuple(got) == window_reference(nominal, cached)
    assert _cycle_window(extra, rel)[2] == wheel - gap  # the tooth rows repeat after one revolution of edges


LEARN = LearnerSettings(True, 0.99, 50)


def test_fit_cycle_teeth_bad_cycles_raise_value_error():
    """Each way a cycle's edges cannot be fitted is a ValueError (the monitor's 'bad_teeth' rejection)."""
    cyc = synthetic_cycles(60, 2, 1, 7)[0]
    args = (60, 12, 12, ToothLearner.empty(60), None, True, 12, False, LEARN)

    def with_(**kw):
        return SimpleNamespace(**{**vars(cyc), **kw})

    fly, teeth, _, cache = fit_cycle_teeth(cyc, *args)
    assert fly.n_edges == cyc.tooth_angle.size and teeth.count == 1
    again = fit_cycle_teeth(cyc, 60, 12, 12, teeth, cache, True, 12, False, LEARN)
    assert again[3] is cache  # a hit keeps the cache object
    for bad, match in [
        (with_(tooth_angle=cyc.tooth_angle[:-1]), "720 deg"),
        (with_(tooth_ticks=cyc.tooth_ticks[:-5]), "one entry per tooth angle"),
        (with_(tooth_ticks=np.concatenate([cyc.tooth_ticks[:5], cyc.tooth_ticks[4:-1]])), "strictly increasing"),
    ]:
        with pytest.raises(ValueError, match=match):
            fit_cycle_teeth(bad, *args)
    with pytest.raises(ValueError, match="cannot carry"):
        fit_cycle_teeth(cyc, 60, 60, 12, ToothLearner.empty(60), None, True, 60, False, LEARN)
    with pytest.raises(ValueError, match="positions"):
        fit_cycle_teeth(cyc, 60, 12, 12, ToothLearner.empty(59), None, True, 12, False, LEARN)
