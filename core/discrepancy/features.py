"""Find: where the model and the measurement disagree, and by how much (the gap).

A missing effect repeats from cycle to cycle; noise does not. So every figure here is of the *coherent* residual:
the mean over cycles of a residual feature, with its noise variance (per-cycle scatter / N) removed or stated. A log
at several operating points (Residuals.groups) is that per operating point: each point's own mean and scatter,
their coherent powers summed with the point's share of the cycles as its weight (one point: as before).

    noise_scale(res)          per-feature per-cycle scatter (robust), the whitening of the fit
    gap(res, scale)           sqrt(sum_j (mean_j^2 - var_j / N) / scale_j^2): the coherent misfit in units of the
                              per-cycle noise; 0 when the model explains all that repeats
    localise(res, spec, scale) orders (half orders point at the cam), crank-angle windows per cylinder, the
                              balance, trends against speed and load: a JSON-able dict
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from frictionwatch.core.discrepancy.residuals import Residuals
from frictionwatch.core.discrepancy.tuned import tuned_constants
from frictionwatch.core.model.engine import EngineSpec

RPM_PER_RAD_S = 30.0 / np.pi
SIGNIFICANT = 4.0  # a coherent figure is reported as significant above this many sigmas of its mean
# The model-error floors and their rms, tuned numbers with their provenance in tuned.json (core.discrepancy.tuned:
# the logs, the figure, the run that wrote them; none of them a log that validates them).
# NULL_OWN, NULL_FLOOR: the floor of the speed residual at engine order m [rpm] is NULL_OWN x the measured amplitude
# at m plus NULL_FLOOR x the largest measured harmonic. A coherent residual is significant only above it, whatever
# its sigma: healthy logs carry a coherent residual that is the monitor's model, not a missing effect (the plant's
# discretisation, the tooth learner, the pinned friction at the firing orders). Validated on bench/discrepancy_null.py
# VALIDATE (other seeds and points) and FAULTS (the floor must not hide them).
# NULL_BALANCE: the floor of the mean torque-balance residual, relative to the friction the balance measured: a
# balance residual is significant only above it (balance_residual); validated on the hidden-effect matrix.
# NULL_KINETIC: the balance's floor at a point also grows with the point's mean kinetic term (Residuals.kinetic): the
# monitor reads the shaft line's energy change from the flywheel's speed at one crank angle with a rigid J, and where
# the speed still settles after a step that reading is off by a share of the term (maruti 1500 rpm after a step from
# 4000: +0.34 N m against a mean kinetic term of -2.1, the truth's friction equal to the model's; design note 68).
# Tuned on healthy two-point logs (bench.discrepancy_null --tune-kinetic --write;
# bench.discrepancy_balance_points.BALANCE_TUNE_SEEDS).
# FLOOR_RMS (speed by its floor's kind, balance; FloorRms): the rms healthy coherent residual as a fraction of those
# floors (a floor is a threshold, the largest healthy residual x 1.5; a found parameter's sigma needs the typical
# model error). The
# balance's was 0 until note 79: tuned when the balance's scatter hid its bias; after note 69 (3.3x less scatter) the
# same logs read 0.31 of NULL_BALANCE x the friction, and without it a ring sized by the balance read 2.8 sigma off.
_TUNED = tuned_constants()
NULL_OWN = _TUNED["NULL_OWN"].value
NULL_FLOOR = _TUNED["NULL_FLOOR"].value
NULL_BALANCE = _TUNED["NULL_BALANCE"].value
# 0 without its record (not tuned): the floor is NULL_BALANCE's alone, as before note 68
NULL_KINETIC = _TUNED["NULL_KINETIC"].value if "NULL_KINETIC" in _TUNED else 0.0
# The speed's rms is one per kind of floor (design note 128): an order whose own measured amplitude is below
# SMALL_ORDER x the largest has a floor that is mostly NULL_FLOOR's share of the largest harmonic ("share"), the others
# mostly NULL_OWN's of their own ("own"; the firing orders); one rms for both was set by the many small orders, so a
# move of NULL_FLOOR moved the model error at the firing orders the other way (note 122). Without the two records
# (FLOOR_RMS_SPEED_SHARE, FLOOR_RMS_SPEED_OWN) both kinds take FLOOR_RMS_SPEED's.
SMALL_ORDER = 0.1


class FloorRms(NamedTuple):
    """The rms healthy coherent residual as a fraction of its floor: a speed order's by its floor's kind, the
    balance's."""

    share: float
    own: float
    balance: float


_SPEED_RMS = _TUNED["FLOOR_RMS_SPEED"].value
FLOOR_RMS = FloorRms(_TUNED["FLOOR_RMS_SPEED_SHARE"].value if "FLOOR_RMS_SPEED_SHARE" in _TUNED else _SPEED_RMS,
                     _TUNED["FLOOR_RMS_SPEED_OWN"].value if "FLOOR_RMS_SPEED_OWN" in _TUNED else _SPEED_RMS,
                     _TUNED["FLOOR_RMS_BALANCE"].value)
# GAP_NULL: the speed channel's held-out gap beyond this many times the healthy gap at the log's amplitudes
# (``healthy_gap``) is a discrepancy even inside every order's floor; the largest healthy ratio on
# bench/discrepancy_null.py TUNE x MARGIN (--tune-gap --write), validated on its VALIDATE logs and the matrices'
# healthy rows (design note 48)
GAP_NULL = _TUNED["GAP_NULL"].value if "GAP_NULL" in _TUNED else float("inf")


def _group_slices(groups: np.ndarray | None, n: int) -> list[np.ndarray]:
    """The row indices of each operating-point group (all rows: one group; a label < 0, between points, none)."""
    if groups is None or n == 0:
        return [np.arange(n)]
    return [np.flatnonzero(groups == g) for g in np.unique(groups) if g >= 0]


def noise_scale(res: Residuals) -> np.ndarray:
    """(F,) per-cycle scatter of each feature about its operating point's median (1.4826 x median absolute deviation,
    pooled over the points with at least three cycles; Re and Im of one harmonic share theirs), floored at a small
    fraction of the largest so that no feature gets an infinite weight."""
    x = res.features()
    parts = [i for i in _group_slices(res.group, x.shape[0]) if i.size >= 3] or [np.arange(x.shape[0])]
    dev = np.concatenate([x[i] - np.median(x[i], axis=0) for i in parts])
    mad = 1.4826 * np.median(np.abs(dev), axis=0)
    m = res.harmonics.shape[1]
    pair = np.sqrt(0.5 * (mad[:m] ** 2 + mad[m:2 * m] ** 2))
    out = np.concatenate([pair, pair, mad[2 * m:]])
    floor = 1e-3 * max(float(out[:2 * m].max(initial=0.0)), 1e-12)
    out[:2 * m] = np.maximum(out[:2 * m], floor)
    out[2 * m:] = np.maximum(out[2 * m:], 1e-6)
    return out


def coherent_power(x: np.ndarray, groups: np.ndarray | None = None) -> np.ndarray:
    """(F,) mean_j^2 - var_j / N of each column of x (N, F) over its rows: the noise-corrected coherent power; with
    ``groups`` (N,), sum_g (N_g / N)(mean_gj^2 - var_gj / N_g) over the operating points (a point of one row, whose
    noise cannot be told, adds nothing; rows between points, label < 0, neither)."""
    parts = _group_slices(groups, x.shape[0])
    if len(parts) > 1:
        parts = [i for i in parts if i.size >= 2]
    n = sum(i.size for i in parts)
    out = np.zeros(x.shape[1])
    for i in parts:
        xi = x[i]
        mean = xi.mean(axis=0)
        var = xi.var(axis=0, ddof=1) if i.size > 1 else np.zeros_like(mean)
        out += (i.size / n) * (mean**2 - var / i.size)
    return out


def coherent_terms(res: Residuals, scale: np.ndarray) -> np.ndarray:
    """(F,) (mean_j^2 - var_j / N) / scale_j^2 of each feature over the cycles (the noise-corrected coherent power),
    per operating point and weighted by its cycles (coherent_power)."""
    return coherent_power(res.features(), res.group) / scale**2


def gap(res: Residuals, scale: np.ndarray) -> float:
    return float(np.sqrt(max(coherent_terms(res, scale).sum(), 0.0)))


def cost(res: Residuals, scale: np.ndarray) -> float:
    """Sum over cycles and features of the whitened squared residual (what the least-squares fit minimises)."""
    return float(np.sum((res.features() / scale) ** 2))


def healthy_gap(res: Residuals, scale: np.ndarray, rms: FloorRms = FLOOR_RMS,
                null: tuple[float, float] | None = None) -> dict:
    """The speed channel's coherent gap (``gap`` over the flywheel-speed features alone) against the gap a healthy
    log shows at this log's amplitudes: the rms model error of each whitened speed feature (``feature_floor``: each
    order's floor x the rms of its kind, FLOOR_RMS), summed as the gap sums them. A floor is a threshold (the largest
    healthy residual x 1.5, NULL_OWN of the order's own amplitude); this is the typical healthy error, so a gap many
    times it is a discrepancy even where every order lies inside its floor (deutz 3000 rpm seed 2, a 5 % load ripple at
    order 0.5, the single cylinder's firing order: gap 20.7 against 4.2 here, the healthy log's 2.7). ``orders``:
    the engine orders that carry it, each whose own coherent amplitude (whitened) exceeds the whole healthy gap (else
    the largest). ``localise`` adds ``firing``: which of them are firing orders (multiples of n_cyl / 2), where the
    floor is widest. ``rms``, ``null``: the floors' in place of those in force (``feature_floor``; the tuning bench's,
    which states GAP_NULL against the floors it writes)."""
    m = res.harmonics.shape[1]
    terms = coherent_terms(res, scale)[:2 * m]
    per_order = np.maximum(terms[:m] + terms[m:], 0.0)
    speed = float(np.sqrt(per_order.sum()))
    normal = float(np.sqrt(np.sum(feature_floor(res, scale, rms, null)[:2 * m] ** 2)))
    idx = np.flatnonzero(np.sqrt(per_order) > normal)
    if idx.size == 0:
        idx = np.array([int(np.argmax(per_order))])
    idx = idx[np.argsort(-per_order[idx])]
    ratio = speed / normal if normal > 0 else (float("inf") if speed > 0 else 0.0)
    return {"speed_gap": speed, "healthy_gap": normal, "ratio": ratio, "beyond": bool(ratio > GAP_NULL),
            "orders": [(int(i) + 1) / 2 for i in idx]}


def _mean_sigma(x: np.ndarray) -> tuple[float, float]:
    n = x.shape[0]
    return float(x.mean()), float(x.std(ddof=1) / np.sqrt(n)) if n > 1 else float("inf")


def _point_rms(res: Residuals, floor_of) -> np.ndarray:
    """A floor over several operating points: sqrt(sum_g w_g floor_g^2), each point's own floor (``floor_of`` its row
    indices) weighted by its share of the cycles, as ``coherent_power`` weights each point's residual power; one
    point: its floor. A floor from the pooled cycles instead mixes the points' amplitudes: k9k stepping 3000 rpm 0.9
    <-> 1800 rpm 0.6, order 2 (near the shaft line's resonance at 1800) carries ~4x the amplitude at 1800, and the
    pooled floor, weighted the other way, read a healthy log's gap at 8.6x a healthy log's (design note 58)."""
    parts = _group_slices(res.group, res.n_cycles)
    if len(parts) > 1:
        parts = [i for i in parts if i.size >= 2]
    if len(parts) <= 1:
        return floor_of(parts[0] if parts else np.arange(res.n_cycles))
    n = sum(i.size for i in parts)
    return np.sqrt(sum((i.size / n) * floor_of(i) ** 2 for i in parts))


def _point_floor_rpm(mean: np.ndarray, null: tuple[float, float]) -> np.ndarray:
    """One operating point's floor [rpm] from its mean measured amplitudes ``mean`` (M,) [rpm]."""
    own, largest = null
    return own * mean + largest * float(mean.max(initial=0.0))


def small_orders(mean: np.ndarray) -> np.ndarray:
    """(M,) whether each order's floor is of the "share" kind (FloorRms): its own mean measured amplitude ``mean``
    below SMALL_ORDER x the largest (the orders bench.discrepancy_null tunes NULL_FLOOR on; the others NULL_OWN)."""
    return mean < SMALL_ORDER * float(mean.max(initial=0.0))


def speed_floor_rpm(res: Residuals, null: tuple[float, float] | None = None) -> np.ndarray:
    """(M,) the model-error floor of a coherent speed residual at each engine order [rpm]: NULL_OWN x the mean measured
    amplitude there + NULL_FLOOR x the largest (zeros where the residuals do not carry the measured speed); over
    several operating points each point's own, combined by ``_point_rms``. ``null``: (own, floor) in their place (the
    tuning bench's, which states the floors it is about to write)."""
    m = res.harmonics.shape[1]
    if res.measured is None or not res.measured.size:
        return np.zeros(m)
    null = (NULL_OWN, NULL_FLOOR) if null is None else null
    return _point_rms(res, lambda i: _point_floor_rpm(res.measured[i].mean(axis=0) * RPM_PER_RAD_S, null))


def speed_model_error_rpm(res: Residuals, rms: FloorRms = FLOOR_RMS,
                          null: tuple[float, float] | None = None) -> np.ndarray:
    """(M,) the rms model error of a coherent speed residual at each engine order [rpm]: its floor
    (``speed_floor_rpm``) x the rms of the floor's kind (``small_orders``: ``rms.share`` where the floor is the
    largest harmonic's share, ``rms.own`` where it is the order's own), each operating point's with its own kinds,
    combined by ``_point_rms``."""
    m = res.harmonics.shape[1]
    if res.measured is None or not res.measured.size:
        return np.zeros(m)
    null = (NULL_OWN, NULL_FLOOR) if null is None else null

    def error_of(i: np.ndarray) -> np.ndarray:
        mean = res.measured[i].mean(axis=0) * RPM_PER_RAD_S
        return np.where(small_orders(mean), rms.share, rms.own) * _point_floor_rpm(mean, null)

    return _point_rms(res, error_of)


def feature_floor(res: Residuals, scale: np.ndarray, rms: FloorRms = FLOOR_RMS,
                  null: tuple[float, float] | None = None) -> np.ndarray:
    """(F,) the rms model error of each whitened feature (Residuals.features / scale): a coherent error of a speed
    order's model error (``speed_model_error_rpm``: its floor x the rms of the floor's kind) at an unknown phase puts
    it/sqrt(2) into each of Re and Im of the harmonic; the balance feature's is ``rms.balance`` x its floor
    (NULL_BALANCE x the measured friction). What a fitted parameter's sigma cannot average away with more cycles
    (core.discrepancy.fit.parameter_sigma). ``null``: the speed floor's (NULL_OWN, NULL_FLOOR) in their place."""
    per_component = speed_model_error_rpm(res, rms, null) / RPM_PER_RAD_S / np.sqrt(2.0)
    return np.concatenate([per_component, per_component, [rms.balance * balance_floor_nm(res)]]) / scale


def _point_means(x: np.ndarray, groups: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per operating point with at least two rows: the mean of x (N, ...) over its rows, its share of those rows, and
    the pooled within-point variance (ddof 1 per point); one point: x's mean, 1 and its variance."""
    parts = [i for i in _group_slices(groups, x.shape[0]) if i.size >= 2] or [np.arange(x.shape[0])]
    means = np.array([x[i].mean(axis=0) for i in parts])
    weights = np.array([i.size for i in parts], dtype=np.float64)
    dof = max(float(sum(i.size - 1 for i in parts)), 1.0)
    var = sum(((x[i] - x[i].mean(axis=0)) ** 2).sum(axis=0) for i in parts) / dof
    return means, weights / weights.sum(), var


def pattern_sigma_rpm(res: Residuals) -> np.ndarray:
    """(M,) [rpm] the spread of each order's coherent speed residual that the in-band tooth pattern's unconverged
    estimate can explain: the mean over the cycles of each cycle's spread (Residuals.pattern_sigma, the nuisances'
    posterior through their columns; core.monitor.teeth.pattern_spread); zeros where the residuals do not carry it.
    The estimate's error moves slowly from cycle to cycle, so the errors of the cycles are nearly one error: the
    mean of their sigmas is the sigma of their mean when they are fully correlated, and its upper bound otherwise
    (averaging over the cycles does not shrink it; design note 118)."""
    if res.pattern_sigma is None or not res.pattern_sigma.size:
        return np.zeros(res.harmonics.shape[1])
    return res.pattern_sigma.mean(axis=0) * RPM_PER_RAD_S


def order_table(res: Residuals) -> list[dict]:
    """Each engine order m/2: the coherent amplitude of the speed residual [rpm] (over several operating points, the
    rms of each point's mean weighted by its cycles: a residual whose phase turns between points does not cancel),
    its sigma and whether it is significant (> SIGNIFICANT sigmas and above the model-error floor,
    ``speed_floor_rpm``); the phase is that of the mean over all cycles. The sigma is the noise's (``noise_sigma_rpm``:
    the scatter within the points over sqrt(N)) and the tooth pattern's (``pattern_sigma_rpm``: what the in-band
    nuisances' remaining uncertainty can put there, the same in every cycle) in quadrature: an order a still
    uncertain tooth pattern can explain is not significant (design note 118)."""
    h = res.harmonics
    n = h.shape[0]
    m_all = h.shape[1]
    means, w, var = _point_means(np.concatenate([h.real, h.imag], axis=1), res.group)
    amp_all = np.sqrt(w @ (means[:, :m_all] ** 2 + means[:, m_all:] ** 2))
    sig = np.sqrt((var[:m_all] + var[m_all:]) / max(n, 2))
    pattern = pattern_sigma_rpm(res)
    mean = h.mean(axis=0)
    floor = speed_floor_rpm(res)
    out = []
    for m in range(h.shape[1]):
        amp, s_noise = amp_all[m] * RPM_PER_RAD_S, sig[m] * RPM_PER_RAD_S
        s = float(np.hypot(s_noise, pattern[m]))
        out.append({"order": (m + 1) / 2, "amplitude_rpm": amp, "sigma_rpm": s, "noise_sigma_rpm": s_noise,
                    "pattern_sigma_rpm": float(pattern[m]), "phase_deg": float(np.degrees(np.angle(mean[m]))),
                    "floor_rpm": float(floor[m]), "significant": bool(amp > SIGNIFICANT * s and amp > floor[m]),
                    "half_order": (m + 1) % 2 == 1})
    return out


def cylinder_windows(res: Residuals, spec: EngineSpec) -> list[dict]:
    """The cycle-mean residual speed's rms in each cylinder's expansion window (its firing TDC to 180 deg after)
    [rpm], and its share of the cycle's: where along the firing order the model and the engine part."""
    mean = res.speed.mean(axis=0)
    total = float(np.sqrt(np.mean(mean**2)))
    out = []
    for k in range(spec.n_cyl):
        local = np.mod(res.angles - spec.firing_angles[k], 4.0 * np.pi)
        w = local < np.pi
        rms = float(np.sqrt(np.mean(mean[w] ** 2))) if w.any() else 0.0
        out.append({"cylinder": k + 1, "rms_rpm": rms * RPM_PER_RAD_S,
                    "relative": rms / total if total > 0 else 0.0})
    return out


def trends(res: Residuals) -> dict:
    """Slopes of the balance residual and of the coherent speed-residual amplitude against speed and load (least
    squares over cycles, with sigmas); None where the log does not vary enough to tell."""
    out: dict = {}
    ok = np.isfinite(res.balance)
    amp = np.sqrt(np.sum(np.abs(res.harmonics) ** 2, axis=1)) * RPM_PER_RAD_S
    for name, x, unit in (("speed", res.omega * RPM_PER_RAD_S, "rpm"), ("load", res.load, "N m")):
        good = ok & np.isfinite(x)
        if good.sum() < 6 or np.ptp(x[good]) <= 1e-3 * max(abs(float(np.mean(x[good]))), 1.0):
            out[name] = None
            continue
        a = np.column_stack([np.ones(good.sum()), x[good] - x[good].mean()])
        entry = {"unit": unit}
        for label, y in (("balance_nm_per_unit", res.balance[good]), ("speed_residual_rpm_per_unit", amp[good])):
            coef, *_ = np.linalg.lstsq(a, y, rcond=None)
            resid = y - a @ coef
            cov = np.linalg.inv(a.T @ a) * (resid @ resid) / max(len(y) - 2, 1)
            entry[label] = float(coef[1])
            entry[label + "_sigma"] = float(np.sqrt(cov[1, 1]))
        out[name] = entry
    return out


def balance_point_floor_nm(friction: np.ndarray, kinetic: np.ndarray | None) -> float:
    """The model-error floor of one operating point's mean torque-balance residual [N m] from its cycles' measured
    friction and kinetic terms (N m, NaN skipped): NULL_BALANCE x |mean friction| and NULL_KINETIC x |mean kinetic
    term| in quadrature. The second is the transient balance's own error: a point whose speed still settles after a
    step carries a kinetic term the flywheel's one-angle speed reads off by a share of it (design note 68); at a
    steady point it is ~0 and the floor NULL_BALANCE's, as tuned on one-point logs."""
    ok = np.isfinite(friction)
    floor = NULL_BALANCE * abs(float(np.mean(friction[ok]))) if np.any(ok) else 0.0
    if kinetic is not None and np.any(np.isfinite(kinetic)):
        floor = float(np.hypot(floor, NULL_KINETIC * abs(float(np.mean(kinetic[np.isfinite(kinetic)])))))
    return floor


def balance_floor_nm(res: Residuals) -> float:
    """The model-error floor of the mean torque-balance residual [N m]: ``balance_point_floor_nm`` of the cycles
    (0 where the residuals do not carry the friction); over several operating points each point's own, combined by
    ``_point_rms`` (as the balance's rms over the points is)."""
    if res.friction is None:
        return 0.0

    def floor_of(i: np.ndarray) -> np.ndarray:
        return np.array(balance_point_floor_nm(res.friction[i], None if res.kinetic is None else res.kinetic[i]))

    return float(_point_rms(res, floor_of))


def balance_residual(res: Residuals) -> dict:
    """The mean torque-balance residual over the cycles [N m], its sigma, its model-error floor and whether it is
    significant (beyond SIGNIFICANT of its sigma and above the floor, as a speed order is: the balance of a healthy
    log carries the model's own error too); NaN and inf with fewer than two finite cycles. Over several operating
    points the test is on ``rms_nm``, each point's mean weighted by its cycles (a friction law that the model has
    wrong may read + at one load and - at another), and ``points`` lists them; one point: rms_nm = |mean_nm|."""
    ok = np.isfinite(res.balance)
    bal, bal_sig = _mean_sigma(res.balance[ok]) if ok.sum() > 1 else (float("nan"), float("inf"))
    floor = balance_floor_nm(res)
    out = {"mean_nm": bal, "sigma_nm": bal_sig, "floor_nm": floor, "rms_nm": abs(bal)}
    groups = None if res.group is None else res.group[ok]
    if ok.sum() > 1 and groups is not None and np.unique(groups).size > 1:
        means, w, var = _point_means(np.column_stack([res.balance[ok], res.load[ok], res.omega[ok]]), groups)
        out["rms_nm"] = float(np.sqrt(w @ means[:, 0] ** 2))
        out["sigma_nm"] = bal_sig = float(np.sqrt(var[0] / ok.sum()))
        out["points"] = [{"rpm": float(om * RPM_PER_RAD_S), "load_nm": float(ld), "mean_nm": float(b),
                          "share": float(s)} for (b, ld, om), s in zip(means, w, strict=True)]
    out["significant"] = bool(np.isfinite(bal) and out["rms_nm"] > SIGNIFICANT * bal_sig and out["rms_nm"] > floor)
    return out


def _measured_friction(res: Residuals, spec: EngineSpec) -> dict | None:
    """The engine's friction the mean balance measured over the cycles [N m] and as FMEP [bar] (one definition:
    EngineSpec.torque_to_mep): what ``analyze`` would report of it under this model."""
    ok = res.friction is not None and np.isfinite(res.friction)
    if res.friction is None or not np.any(ok):
        return None
    mean, sigma = _mean_sigma(res.friction[ok])
    return {"mean_nm": mean, "sigma_nm": sigma, "fmep_bar": spec.torque_to_mep(mean) / 1e5,
            "fmep_sigma_bar": spec.torque_to_mep(sigma) / 1e5}


def localise(res: Residuals, spec: EngineSpec, scale: np.ndarray) -> dict:
    """Find: the coherent residual by engine order, crank-angle window and cylinder, the balance, the trends and
    per channel (flywheel encoder: the speed residual; pressure and load sensors: the balance residual)."""
    balance = balance_residual(res)
    mean_speed = res.speed.mean(axis=0)
    peak = int(np.argmax(np.abs(mean_speed)))
    terms = coherent_terms(res, scale)
    m = res.harmonics.shape[1]
    orders = order_table(res)
    hg = healthy_gap(res, scale)
    return {
        "cycles": res.n_cycles,
        "cycles_between_points": res.between_points,  # a load step's, left out of every figure
        # the operating points the cycles ran at (Residuals.group): one, and a friction law sized to agree with the
        # model's there cannot show in the mean friction (Discovery.one_operating_point)
        "operating_points": 1 if res.group is None else max(int(np.unique(res.group[res.group >= 0]).size), 1),
        "load_nm": float(np.nanmean(res.load)) if res.n_cycles else float("nan"),  # the measured load torque
        "gap": gap(res, scale),
        "orders": orders,
        "significant_orders": [o["order"] for o in orders if o["significant"]],
        "half_order_share": float(max(terms[:m][0::2].sum() + terms[m:2 * m][0::2].sum(), 0.0)
                                  / max(terms[:2 * m].sum(), 1e-12)) if terms[:2 * m].sum() > 0 else 0.0,
        "angle": {"peak_deg": float(np.degrees(res.angles[peak])),
                  "peak_rpm": float(mean_speed[peak] * RPM_PER_RAD_S),
                  "rms_rpm": float(np.sqrt(np.mean(mean_speed**2)) * RPM_PER_RAD_S)},
        "cylinders": cylinder_windows(res, spec),
        "balance": balance,
        "friction": _measured_friction(res, spec),
        "channels": {"flywheel_speed": float(max(terms[:2 * m].sum(), 0.0)),
                     "torque_balance": float(max(terms[2 * m:].sum(), 0.0))},
        "trends": trends(res),
        "healthy_gap": {**hg, "firing": [o for o in hg["orders"] if (2 * o) % spec.n_cyl == 0]},
    }


def beyond_null(loc: dict) -> bool:
    """Whether a held-out residual (``localise``'s) holds anything beyond the healthy model's own error: an engine
    order above its model-error floor or a balance residual beyond its own (issue 27: significant = beyond the null).
    The workflow looks for no further step after one without it, and an ambiguity without it is no discrepancy
    (design note 39)."""
    return bool(loc["significant_orders"] or loc["balance"]["significant"])


def beyond_healthy_gap(loc: dict) -> bool:
    """Whether a held-out residual (``localise``'s) holds a speed gap beyond GAP_NULL x the healthy gap at its
    amplitudes (``healthy_gap``) while nothing is beyond the null (``beyond_null``): a discrepancy inside the
    model-error floor, which the model's own error at those orders could be too (said, never named from; design
    note 48)."""
    return bool(not beyond_null(loc) and loc.get("healthy_gap", {}).get("beyond"))


__all__ = ["FLOOR_RMS", "GAP_NULL", "NULL_BALANCE", "NULL_FLOOR", "NULL_KINETIC", "NULL_OWN", "RPM_PER_RAD_S",
           "SIGNIFICANT", "SMALL_ORDER", "FloorRms", "balance_floor_nm", "balance_point_floor_nm", "balance_residual",
           "beyond_healthy_gap", "beyond_null", "coherent_power", "coherent_terms", "cost", "cylinder_windows",
           "feature_floor", "gap", "healthy_gap", "localise", "noise_scale", "order_table", "pattern_sigma_rpm",
           "small_orders", "speed_floor_rpm", "speed_model_error_rpm", "trends"]
