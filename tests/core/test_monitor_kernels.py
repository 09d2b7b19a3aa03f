"""The monitor's per-cycle kernels (noise model, Eq. 6 sharing and its prior rows, the reported estimate, the result's
traces) against their plain-numpy references, written here. Seeded inputs of the real sizes (genset-v20: P = 47 with
24 nuisances, M = 24, z = 20, 512 time samples, 720 grid points) and small ones (1 and 4 cylinders).
Tolerances: the kernels sum in plain order where numpy sums pairwise or through BLAS, so sums of up to ~50 terms
differ by a few ulps of their largest term; 1e-12 relative (1e-14 for the short Eq. 6 sums) leaves room for that
and for nothing else. Masks and interpolation (no sums) are compared exactly."""

import numpy as np
import pytest
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.monitor.identify.estimate import ReportLimits, friction_estimate
from frictionwatch.core.monitor.identify.noise_model import NoiseSettings, ResidualStats, whitened_rows
from frictionwatch.core.monitor.identify.parameters import (
    CycleRows,
    PriorNormal,
    SharedLoss,
    firing_mask,
    parameter_layout,
    share_mean_loss,
)
from frictionwatch.core.monitor.identify.posterior import Posterior
from frictionwatch.core.monitor.report.cycle_report import report_traces, speed_power, speed_residual
from frictionwatch.core.monitor.report.grid_rows import rows_on_grid
from frictionwatch.core.monitor.report.results import FrictionEstimate
from frictionwatch.core.monitor.teeth.flywheel import FlywheelMotion
from numpy.testing import assert_allclose, assert_array_equal

FOUR_PI = 4.0 * np.pi
SIZES = (("genset-v20", 24, 512), ("k9k-4cyl", 16, 256), ("deutz-1cyl", 12, 128))  # engine, M, n_t


# ---- references (the code before the kernels) -------------------------------------------------------------


def firing_mask_reference(indicated_mean, fraction=0.15):
    t = np.asarray(indicated_mean, dtype=np.float64)
    pos = np.sort(t[t > 0])
    n = pos.size
    if n == 0:
        return np.zeros(t.shape, dtype=bool)
    med = pos[n // 2] if n % 2 else 0.5 * (pos[n // 2 - 1] + pos[n // 2])
    return t > fraction * med


def share_mean_loss_reference(friction_total, indicated_mean, motored_friction, spread=0.15, motored_spread=0.3,
                              fraction=0.15):
    t_i = np.asarray(indicated_mean, dtype=np.float64)
    fire = firing_mask_reference(t_i, fraction)
    motored = ~fire
    n_ml = int(np.count_nonzero(motored))
    if n_ml == t_i.size:
        out = np.full(t_i.shape, float(motored_friction))
        sig = np.full(t_i.shape, motored_spread * abs(motored_friction))
        return SharedLoss(friction_mean=out, sigma=sig, motored=motored)
    t_fire = t_i[fire].sum()
    t_f_fire = friction_total - n_ml * motored_friction
    out = np.where(fire, t_f_fire * t_i / t_fire, motored_friction)
    sig = np.where(fire, spread * np.abs(out), motored_spread * abs(motored_friction))
    return SharedLoss(friction_mean=out, sigma=sig, motored=motored)


def with_share_reference(n_base, r_base, cylinder_rows, share):
    if not np.all(np.isfinite(share.friction_mean)):
        return n_base, r_base
    sig = np.maximum(share.sigma, 1e-6)
    w = cylinder_rows / sig[:, None]
    return n_base + w.T @ w, r_base + w.T @ (share.friction_mean / sig)


def _qf(rows, cov):
    return np.einsum("qp,qp->q", rows @ cov, rows)


def friction_estimate_reference(spec, layout, post, basis_mean, prior_mean, resolve_rel, coefficient_snr,
                                min_data_gain=0.0, cylinder_rows=None):
    z = spec.n_cyl
    theta = post.params
    a = layout.coefficients(theta)
    a_sig = layout.prior * np.sqrt(np.clip(np.diag(post.covariance), 0.0, None))[layout.group]
    a_norm = a * basis_mean
    a_norm_sig = a_sig * basis_mean
    rows = layout.cylinder_rows(basis_mean) if cylinder_rows is None else cylinder_rows
    t_cyl = rows @ theta
    t_sig = np.sqrt(np.clip(_qf(rows, post.covariance), 0.0, None))
    total_row = rows.sum(axis=0)
    t_tot = float(total_row @ theta)
    t_tot_sig = float(np.sqrt(np.clip(_qf(total_row[None], post.covariance), 0.0, None))[0])
    dev = rows - rows.sum(axis=0) / z
    p_, r_ = _qf(dev, post.cov_statistical), _qf(dev, post.cov_reference)
    pinned = r_ <= 1e-12 * max(float(np.max(r_, initial=0.0)), 1e-300) + 1e-300
    gain = np.where(pinned, 1.0, np.clip(1.0 - p_ / np.maximum(r_, 1e-300), 0.0, 1.0))
    resolved = (t_sig <= resolve_rel * np.abs(t_cyl)) & (gain >= min_data_gain)
    dp, dr = np.diag(post.cov_statistical), np.diag(post.cov_reference)
    pinned_p = dr <= 1e-12 * max(float(np.max(dr, initial=0.0)), 1e-300) + 1e-300
    gain_p = np.where(pinned_p, 1.0, np.clip(1.0 - dp / np.maximum(dr, 1e-300), 0.0, 1.0))[layout.group]
    coef_ok = (a_norm > coefficient_snr * a_norm_sig) & (layout.prior > 0) & (gain_p >= min_data_gain)
    to_cyl, to_eng = FOUR_PI / spec.displacement_cyl, FOUR_PI / spec.displacement
    return FrictionEstimate(
        friction_torque_mean=np.where(resolved, t_cyl, np.nan), friction_torque_mean_sigma=t_sig,
        fmep=np.where(resolved, t_cyl * to_cyl, np.nan), fmep_sigma=t_sig * to_cyl,
        coefficients=np.where(coef_ok, a, np.nan), coefficients_sigma=a_sig,
        coefficients_normalised=np.where(coef_ok, a_norm, np.nan), coefficients_normalised_sigma=a_norm_sig,
        resolved=resolved, coefficient_resolved=coef_ok, total_friction_torque=t_tot,
        total_friction_torque_sigma=t_tot_sig, total_fmep=t_tot * to_eng, total_fmep_sigma=t_tot_sig * to_eng,
        prior_friction_torque_mean=np.asarray(prior_mean, dtype=np.float64).reshape(z), data_gain=gain,
        weight=float(post.weight), chi2_reduced=float(post.chi2_reduced))


def noise_rows_reference(design, target, theta, freq, drift_harm, use_drift, stats, memory, balance, mean_row,
                         floor, t_i, drift_var, period, harmonics, model_rel_error, sys_balance):
    """The inline steps of process_cycle before the kernel."""
    resid = target - design @ theta
    drift_col = 1j * freq * drift_harm if use_drift else None
    if drift_col is not None:
        d = drift_col
        resid = resid - d * (np.vdot(d, resid).real / max(float(np.vdot(d, d).real), 1e-300))
    bal_resid = balance - float(mean_row @ theta) if np.isfinite(balance) else 0.0
    stats = stats.update(resid, bal_resid, memory)
    sigma = np.sqrt(np.maximum(stats.var, floor))
    sigma_bal = np.sqrt(max(stats.balance_var, (0.002 * t_i) ** 2, 1e-6)) if stats.count > 2 else 0.05 * abs(t_i)
    a = np.concatenate([design.real, design.imag]) / np.concatenate([sigma, sigma])[:, None]
    y = np.concatenate([target.real, target.imag]) / np.concatenate([sigma, sigma])
    if drift_col is not None and drift_var > 0:
        d = drift_col
        dw = np.concatenate([d.real, d.imag]) / np.concatenate([sigma, sigma])
        nd = float(dw @ dw)
        s2 = drift_var * (0.5 * period) ** 2
        if nd > 0:
            c = (1.0 - 1.0 / np.sqrt(1.0 + s2 * nd)) / nd
            a = a - c * np.outer(dw, dw @ a)
            y = y - c * dw * (dw @ y)
    inv_sigma = np.concatenate([1.0 / sigma, 1.0 / sigma, [1.0 / sigma_bal]])
    if np.isfinite(balance):
        a = np.vstack([a, mean_row / sigma_bal])
        y = np.append(y, balance / sigma_bal)
    else:
        a = np.vstack([a, np.zeros(a.shape[1])])
        y = np.append(y, 0.0)
    speed = 1j * freq * harmonics
    half = np.maximum(np.abs(stats.mean) ** 2, (model_rel_error * np.abs(speed)) ** 2) / 2.0
    sys_var = np.concatenate([half, half, [sys_balance]])
    return stats, a, y, inv_sigma, sys_var


def traces_reference(grid, theta_fly, coef, basis, extra):
    per_cyl_t = np.einsum("kl,klt->kt", coef, basis)
    values = np.concatenate([per_cyl_t, extra])
    x = np.append(theta_fly, theta_fly[0] + FOUR_PI)
    u = theta_fly[0] + np.mod(grid - theta_fly[0], FOUR_PI)
    out = np.array([np.interp(u, x, np.append(r, r[0])) for r in values])
    z = coef.shape[0]
    return out[:z], out[:z].sum(axis=0), out[z:]


# ---- helpers ------------------------------------------------------------------------------------------------


def _spd(rng, p, scale=1.0):
    b = rng.normal(size=(p, p + 3))
    return scale * (b @ b.T / p + 0.1 * np.eye(p))


def _posterior(rng, p):
    cov_stat = _spd(rng, p, 1e-3)
    return Posterior(params=rng.uniform(0.5, 1.5, p), covariance=cov_stat + _spd(rng, p, 1e-4),
                     cov_statistical=cov_stat, chi2_reduced=1.3, weight=42.0,
                     cov_reference=cov_stat + _spd(rng, p, 3e-3))


def _nuisances(spec, m):
    return 2 * (m // 2) if spec.n_cyl > 1 else 0


# ---- tests --------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("seed", range(6))
def test_share_and_firing_mask_match_reference(seed):
    rng = np.random.default_rng(seed)
    z = (1, 4, 20, 20, 6, 3)[seed]
    t_i = rng.uniform(50.0, 200.0, z)
    if seed == 2:
        t_i[[3, 11]] = rng.uniform(-5.0, 2.0, 2)  # two misfiring cylinders
    if seed == 4:
        t_i[:] = -1.0  # nothing fires
    if seed == 5:
        t_i[1] = 0.0
    for total in (rng.uniform(20, 90), float("nan")):
        got = share_mean_loss(total, t_i, 1.7, spread=0.3)
        ref = share_mean_loss_reference(total, t_i, 1.7, spread=0.3)
        assert_array_equal(got.motored, ref.motored)
        for f in ("friction_mean", "sigma"):  # the firing cylinders' sum: plain vs pairwise order
            assert_allclose(getattr(got, f), getattr(ref, f), rtol=1e-14)
    assert_array_equal(firing_mask(t_i), firing_mask_reference(t_i))
    assert_array_equal(firing_mask(t_i, 0.9), firing_mask_reference(t_i, 0.9))


@pytest.mark.parametrize("name", [s[0] for s in SIZES])
def test_share_normal_matches_reference(name):
    spec = load_engine(name)
    layout = parameter_layout(spec)
    rng = np.random.default_rng(3)
    p_f, z = layout.n_params, spec.n_cyl
    p = p_f + _nuisances(spec, 24)
    n_base, r_base = _spd(rng, p), rng.normal(size=p)
    rows = layout.cylinder_rows(rng.uniform(0.1, 3.0, (z, 6)))
    share = share_mean_loss_reference(60.0, rng.uniform(50, 100, z), 1.5, 0.3)
    prior = PriorNormal((1.0, 0.05, 0.15), n_base, r_base)
    n_out, r_out = prior.with_share(rows, share)
    full = np.zeros((z, p))
    full[:, :p_f] = rows
    n_ref, r_ref = with_share_reference(n_base, r_base, full, share)
    assert_allclose(n_out, n_ref, rtol=1e-13, atol=1e-13 * np.abs(n_ref).max())
    assert_allclose(r_out, r_ref, rtol=1e-13, atol=1e-13 * np.abs(r_ref).max())
    assert_array_equal(n_out[p_f:], n_base[p_f:])  # nuisance blocks untouched
    bad = SharedLoss(np.full(z, np.nan), np.ones(z), np.zeros(z, bool))
    n_bad, r_bad = prior.with_share(rows, bad)  # a share that is not finite adds nothing
    assert n_bad is n_base and r_bad is r_base


@pytest.mark.parametrize("name", [s[0] for s in SIZES])
@pytest.mark.parametrize("seed", range(3))
def test_friction_estimate_matches_reference(name, seed):
    spec = load_engine(name)
    layout = parameter_layout(spec)
    rng = np.random.default_rng(seed)
    p_f, z = layout.n_params, spec.n_cyl
    full = _posterior(rng, p_f + _nuisances(spec, 24))
    post = full.head(p_f)  # as the monitor passes it: views of the full matrices
    basis_mean = rng.uniform(0.1, 3.0, (z, 6))
    rows = layout.cylinder_rows(basis_mean)
    prior_mean = rng.uniform(1.0, 5.0, z)
    for args in ((0.10, 2.0, 0.5), (0.5, 0.5, 0.0), (1e-3, 10.0, 0.9)):  # resolved / unresolved mixes
        limits = ReportLimits(*args)
        got = friction_estimate(spec, layout, post, basis_mean, prior_mean, limits, rows)
        ref = friction_estimate_reference(spec, layout, post, basis_mean, prior_mean, *args, rows)
        for f in FrictionEstimate.__dataclass_fields__:
            g, r = np.asarray(getattr(got, f)), np.asarray(getattr(ref, f))
            if r.dtype.kind == "O":  # the calibration's part: None from both (added after, in the identification)
                assert getattr(got, f) is None and getattr(ref, f) is None, f
            elif r.dtype.kind == "U":  # source: "data" from both (withholding happens after, in the identification)
                assert_array_equal(g, r, err_msg=f)
            elif r.dtype == bool:
                assert_array_equal(g, r, err_msg=f)
            else:
                assert_array_equal(np.isnan(g), np.isnan(r), err_msg=f)
                assert_allclose(g, r, rtol=1e-12, atol=1e-12 * np.nanmax(np.abs(r), initial=0.0), err_msg=f)
        got2 = friction_estimate(spec, layout, post, basis_mean, prior_mean, limits)  # rows from the layout
        assert_allclose(got2.fmep_sigma, got.fmep_sigma, rtol=1e-14)
        # the monitor's call: the full posterior (friction first, then nuisances), its leading block reported
        got3 = friction_estimate(spec, layout, full, basis_mean, prior_mean, limits, rows)
        for f in FrictionEstimate.__dataclass_fields__:
            g, r = np.asarray(getattr(got3, f)), np.asarray(getattr(got, f))
            if r.dtype.kind == "O":
                assert getattr(got3, f) is None and getattr(got, f) is None, f
            elif r.dtype == bool or r.dtype.kind == "U":
                assert_array_equal(g, r, err_msg=f)
            else:
                assert_allclose(g, r, rtol=1e-14, err_msg=f)


@pytest.mark.parametrize("name,m,n_t", SIZES)
@pytest.mark.parametrize("case", ["steady", "first", "no_load", "no_drift"])
def test_noise_rows_match_reference(name, m, n_t, case):
    spec = load_engine(name)
    rng = np.random.default_rng(7)
    p = parameter_layout(spec).n_params + _nuisances(spec, m)
    design = rng.normal(size=(m, p)) + 1j * rng.normal(size=(m, p))
    target = rng.normal(size=m) + 1j * rng.normal(size=m)
    theta = rng.uniform(0.5, 1.5, p)
    freq = 0.5 * 157.0 * np.arange(1, m + 1)
    drift_harm = 1e-4 * (rng.normal(size=m) + 1j * rng.normal(size=m))
    harmonics = 1e-3 * (rng.normal(size=m) + 1j * rng.normal(size=m))
    count = 0 if case == "first" else 37
    stats = ResidualStats(mean=0.01 * (rng.normal(size=m) + 1j * rng.normal(size=m)),
                          var=rng.uniform(1e-4, 1e-3, m), balance_mean=0.3, balance_var=2.0, count=count)
    balance = float("nan") if case == "no_load" else 55.0
    use_drift = case != "no_drift"
    floor = freq**2 * 2.0 * 1e-5**2 / 300 + 1e-12
    mean_row = rng.normal(size=p)
    period = FOUR_PI / 157.0
    ref = noise_rows_reference(design, target, theta, freq, drift_harm, use_drift, stats, 0.99, balance, mean_row,
                               floor, 600.0, 0.04, period, harmonics, 0.003, 7.5)
    fly = FlywheelMotion(period=period, omega_mean=157.0, harmonics=harmonics, offset=0.0, drift=0.0,
                         residual_rms=1e-5, n_edges=300, edge_residual=np.zeros(300),
                         pattern_harmonics=np.column_stack([np.zeros(m), drift_harm]))
    rows = CycleRows(design=design, target=target, mean_row=mean_row, mean_target=float("nan"),
                     cylinder_rows=np.zeros((spec.n_cyl, p)))
    got = whitened_rows(NoiseSettings(0.99, 0.003, use_drift, 7.5), stats, fly, rows, theta, balance, 600.0, 0.04)
    assert got.stats.count == ref[0].count
    assert_allclose(got.freq, freq, rtol=1e-15)
    assert (got.drift_col is None) == (not use_drift)
    for g, want in ((got.stats.mean, ref[0].mean), (got.stats.var, ref[0].var),
                    (got.stats.balance_mean, ref[0].balance_mean), (got.stats.balance_var, ref[0].balance_var),
                    (got.a, ref[1]), (got.y, ref[2]), (got.inv_sigma, ref[3]), (got.sys_var, ref[4])):
        assert_allclose(g, want, rtol=1e-12, atol=1e-12 * np.max(np.abs(want)))


@pytest.mark.parametrize("name,m,n_t", SIZES)
def test_report_traces_and_residual_match_reference(name, m, n_t):
    spec = load_engine(name)
    rng = np.random.default_rng(11)
    z = spec.n_cyl
    grid = np.arange(720) * (FOUR_PI / 720)
    th0 = rng.uniform(-0.2, 0.2)
    theta_fly = th0 + np.arange(n_t) * (FOUR_PI / n_t) + 0.01 * np.sin(np.arange(n_t) * (2 * np.pi / n_t))
    j = int(np.argmin(np.abs(theta_fly - grid[100])))
    if grid[99] < theta_fly[j] < grid[101]:
        grid[100] = theta_fly[j]  # an exact hit on a sample
    coef = rng.uniform(0.0, 2.0, (z, 6))
    basis = rng.normal(size=(z, 6, n_t))
    extra = rng.normal(size=(2, n_t))
    cyl_time, on_grid = np.empty((z, n_t)), np.empty((3, 720))
    report_traces(grid, theta_fly, coef, np.ascontiguousarray(basis.transpose(1, 0, 2)), extra, cyl_time, on_grid)
    r_cyl, r_total, r_ex = traces_reference(grid, theta_fly, coef, basis, extra)
    assert_allclose(cyl_time, np.einsum("kl,klt->kt", coef, basis), rtol=1e-13, atol=1e-13)
    cyl = np.empty((z, 720))
    rows_on_grid(grid, theta_fly, cyl_time, cyl)  # the per-cylinder traces, asked for later: bit for bit
    assert_array_equal(cyl, r_cyl)
    # the total is summed on the time grid before the (linear) interpolation: equal up to rounding
    assert_allclose(on_grid[0], r_total, rtol=1e-13, atol=1e-13 * np.abs(r_total).max())
    assert_array_equal(on_grid[1:], r_ex)

    p_f = parameter_layout(spec).n_params
    p = p_f + _nuisances(spec, m)
    design = rng.normal(size=(m, p)) + 1j * rng.normal(size=(m, p))
    target = rng.normal(size=m) + 1j * rng.normal(size=m)
    theta = rng.uniform(0.5, 1.5, p)
    drift = rng.normal(size=m) + 1j * rng.normal(size=m)
    for use in (True, False):
        out = np.empty((2, m), complex)
        sq = speed_residual(design, target, theta, p_f, drift, use, out)
        resid = target - design @ theta
        if use:
            resid = resid - drift * (np.vdot(drift, resid).real / np.vdot(drift, drift).real)
        assert_allclose(out[1], resid, rtol=1e-12, atol=1e-12 * np.abs(resid).max())
        assert_allclose(out[0], design[:, p_f:] @ theta[p_f:], rtol=1e-12, atol=1e-12)
        assert_allclose(sq, np.sum(np.abs(resid) ** 2), rtol=1e-12)
    freq = 0.5 * 157.0 * np.arange(1, m + 1)
    h = rng.normal(size=m) + 1j * rng.normal(size=m)
    # np.abs of a complex number is not always libm's hypot: equal to the last bit or two
    assert_allclose(speed_power(freq, h), np.sum(np.abs(1j * freq * h) ** 2), rtol=1e-14)


def test_peak_pressure_finite_counts_and_matches_peak_pressure():
    from frictionwatch.core.model.indicated import _peak_pressure_finite, peak_pressure

    rng = np.random.default_rng(5)
    theta = np.arange(720) * (FOUR_PI / 720)
    p = 1e5 + 50e5 * rng.random((20, 720))
    phases = rng.uniform(0, FOUR_PI, 20)
    p[0, [100, 300, 301]] = 60e5  # ties: the first maximum counts, as np.argmax
    p[1, 0], p[2, 719] = 70e5, 70e5  # maxima on the ends: the parabola wraps
    p[4, 200:260] = 55e5  # a flat top
    pmax, ang = np.empty(20), np.empty(20)
    assert _peak_pressure_finite(theta, p, phases, pmax, ang) == 0
    ref = peak_pressure(theta, p, phases)
    assert_array_equal(pmax, ref[0])
    assert_array_equal(ang, ref[1])
    p[3, 10] = np.nan
    p[7, 700:702] = np.inf
    assert _peak_pressure_finite(theta, p, phases, pmax, ang) == 3


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
@pytest.mark.parametrize("where", [0, 1, 7, 8, 14399])
def test_all_finite_sees_one_bad_sample_anywhere(bad, where):
    from frictionwatch.core.model.indicated import _all_finite

    x = np.random.default_rng(where).normal(0.0, 1e300, 14400)  # large finite values stay finite: x * 0 == 0
    x[::97] = -0.0
    assert _all_finite(x)
    x[where] = bad
    assert not _all_finite(x)
