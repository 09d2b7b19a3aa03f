"""Sensor health every cycle, per cylinder (issue 16 item 1): TDC offset of each cylinder and of the whole wheel,
pressure pegging offset and pressure gain error, each as this cycle's estimate, a smoothed estimate with its 1-sigma
and a flag; the identifiable part is corrected before the harmonic balance and IMEP.

Two sources, each used where it carries information:

1. TDC from the speed data. A cylinder whose true TDC is Delta_k later than stated has its piston Delta_k late on
   the pressure's time base: the monitor's gas and mass torques are off by dT_k/dDelta_k, which through the chain's
   transfer functions is a speed-harmonic column s_k (M,). The speed residual (measured - model at the current
   friction estimate) is solved for Delta jointly with the friction and tooth-error columns under their prior (the
   Schur complement eliminates them: a friction estimate that absorbed part of a TDC error must not hide it), the
   normal equations accumulated with forgetting, each cycle's referred to the correction it ran with. The wheel is
   the median of the joint estimates on a small engine (one cylinder's offset stays its own), and estimated alone
   (all cylinders shifted alike) on a large one, where the common mode is well determined and each cylinder's own
   is not; a cylinder's own offset is its joint estimate beyond the wheel (three or more cylinders).
   The compression stroke alone cannot do this: over a window before combustion a TDC shift is nearly collinear
   with a cylinder's own polytropic exponent and gain (simulated healthy K9K / V20 cylinders read +-0.4 deg).
2. Gain and pegging from a sibling comparison of the compression stroke. Over a window after inlet-valve closing
   and before start of combustion each cylinder's trace, at its piston's position (the model's static twist and the
   TDC correction in use taken out), is compared with the median of its siblings: p_k = g_k pbar V^-b_k + o_k,
   linearised and solved twice (Gauss-Newton). b_k takes a cylinder's own heat loss. Cylinders share the intake
   manifold, so their trapped charge is the same on average; what is common to all (a common gain) is not seen.

Gain and offset are smoothed by an EWMA, their sigma the EWMA scatter over the effective number of cycles; the TDC's
sigma is the larger of that scatter and the accumulated information's; every sigma has a floor for what the method
cannot resolve. A flag needs the smoothed estimate beyond a physical threshold, beyond ``flag_sigmas`` of its sigma
and (for a sibling comparison) beyond the siblings' own robust spread; the correction in use is the smoothed
estimate of every flagged quantity. What stays uncertain in TDC and gain is propagated into the friction sigma
through dT_iM/dDelta and T_iM (``inflate``): on a large genset 0.1 deg is several % of FMEP, so the figure says how
little it knows instead of a confident number.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.monitor.balance.harmonic_balance import OperatingPoint
from frictionwatch.core.monitor.checks.check import CheckInput, CheckStep
from frictionwatch.core.monitor.checks.sensor_evidence import sibling_compare, speed_sensitivity, tdc_information
from frictionwatch.core.monitor.report.results import FrictionEstimate, SensorHealth


@dataclass(frozen=True)
class SensorHealthConfig:
    """memory: EWMA factor of the per-cycle estimates; min_cycles before any flag; flag_sigmas: a flag needs the
    smoothed estimate beyond this many sigmas and beyond the thresholds tdc_deg (a cylinder against its siblings),
    wheel_deg, gain (relative), offset_pa, and a sibling quantity beyond spread_sigmas of the siblings' own robust
    spread (1.4826 MAD across the cylinders: healthy cylinders differ by a few % in compression);
    floors: 1-sigma the methods cannot resolve whatever the cycle count (model and sibling spread);
    prior_wheel_deg, prior_tdc_deg: 1-sigma prior of the wheel's TDC offset and of a cylinder's own offset from it
    (the wheel's also goes into the friction sigma until min_cycles are in);
    window_deg: compression window before firing TDC (its end moves before the start of combustion)."""

    memory: float = 1.0 - 1.0 / 30.0
    min_cycles: int = 8
    flag_sigmas: float = 4.0
    tdc_deg: float = 0.3
    wheel_deg: float = 0.8  # healthy K9K part-load logs: the speed's wheel estimate wandered to 0.68 deg
    gain: float = 0.02
    offset_pa: float = 0.2e5
    floor_tdc_deg: float = 0.03
    floor_wheel_deg: float = 0.05
    floor_gain: float = 0.003
    floor_offset_pa: float = 0.02e5
    window_deg: tuple[float, float] = (-100.0, -25.0)
    spread_sigmas: float = 3.0
    prior_wheel_deg: float = 1.0  # what is known of the wheel's TDC before the speed data
    prior_tdc_deg: float = 0.5  # ... and of a cylinder's own offset from the wheel
    joint_max_cyl: int = 6  # up to this many cylinders the wheel is the median of the joint per-cylinder estimates
    prior_gain: float = 0.05  # of a pressure channel's gain error, where the speed separates it from TDC
    scale_error: float = 0.5  # relative error of the speed's TDC (K9K at full load read 0.48 deg for 1.0: bench/sensor_faults)
    # correct_wheel False: a flagged wheel offset is carried in the sigma and withholds the figures (figure_status)
    # but is not applied. Applied (the default) it corrects simulated offsets (bench/sensor_faults.py); the speed's
    # common-mode TDC is unreliable where the model is not the engine (K9K +1.0 deg read +0.05 deg): why the whole
    # stage is opt-in (core.monitor.state.MonitorConfig)
    correct_wheel: bool = True


@dataclass(frozen=True)
class SensorHealthState:
    """EWMA mean and variance of the per-cycle estimates q = [a cylinder's own TDC offset (z) rad, gain - 1 (z),
    offset (z) Pa, wheel TDC offset rad] and the count; ``applied`` the corrections in use, in the same layout;
    tdc_info (z, z), tdc_rhs (z,) the accumulated normal equations of each cylinder's absolute TDC offset from the
    speed, wheel_info, wheel_rhs those of the wheel's alone (all cylinders shifted alike)."""

    count: int
    mean: np.ndarray
    var: np.ndarray
    applied: np.ndarray
    tdc_info: np.ndarray
    tdc_rhs: np.ndarray
    wheel_info: float
    wheel_rhs: float

    @staticmethod
    def empty(n_cyl: int) -> SensorHealthState:
        zero = np.zeros(3 * n_cyl + 1)
        return SensorHealthState(0, zero, zero, zero, np.zeros((n_cyl, n_cyl)), np.zeros(n_cyl), 0.0, 0.0)


def corrected_inputs(state: SensorHealthState, pressure: np.ndarray,
                     op: OperatingPoint) -> tuple[np.ndarray, OperatingPoint]:
    """The pressure re-pegged and rescaled by the corrections in use, and ``op`` with every cylinder's kinematic
    phase moved by its TDC correction (the pressure stays on its time base: a late TDC is a late piston, exactly
    what the plant does); both the inputs themselves when nothing is corrected."""
    z = pressure.shape[0]
    a = state.applied
    tdc, gain, offset = a[:z] + a[-1], 1.0 + a[z:2 * z], a[2 * z:3 * z]
    if np.any(gain != 1.0) or np.any(offset != 0.0):
        pressure = (pressure - offset[:, None]) / gain[:, None]
    if np.any(tdc != 0.0):
        cyl = op.cylinders
        phase = np.ascontiguousarray(cyl.phase + tdc)
        op = replace(op, cylinders=cyl._replace(phase=phase, cos_phase=np.cos(phase), sin_phase=np.sin(phase)))
    return pressure, op


@dataclass(frozen=True)
class SpeedEvidence:
    """The speed side of one cycle: theta_fly, omega, alpha (n_t,) the harmonic balance's time samples [rad, rad/s,
    rad/s^2]; residual (M,) complex measured - model speed harmonics at the current friction estimate, sigma (M,)
    its 1-sigma per real component; design (M, P) complex and prior_info (P, P) the friction and tooth-nuisance
    columns and their prior (whitened units) that the TDC columns are made independent of."""

    theta_fly: np.ndarray
    omega: np.ndarray
    alpha: np.ndarray
    residual: np.ndarray
    sigma: np.ndarray
    design: np.ndarray
    prior_info: np.ndarray


def assess(cfg: SensorHealthConfig, spec: EngineSpec, state: SensorHealthState, grid: np.ndarray,
           raw_pressure: np.ndarray, pressure: np.ndarray, op: OperatingPoint, speed: SpeedEvidence,
           indicated: np.ndarray, twist: np.ndarray | None) -> tuple[SensorHealthState, SensorHealth]:
    """This cycle's estimates folded into the state, the result, and the corrections for the next cycle.

    raw_pressure / pressure (z, n) Pa before and after this cycle's corrections; op the operating point the balance
    ran with (corrected phases); indicated (z,) N m the corrected work-mean indicated torques; twist (z,) rad each
    cylinder's throw-minus-flywheel static twist (None: rigid)."""
    z = spec.n_cyl
    a = state.applied
    in_use = a[:z] + a[-1]
    # the pistons' positions with the TDC correction in use or, not yet flagged, the speed's estimate where it is
    # beyond the threshold: a TDC error read as gain would be "corrected" into a wrong pressure (below the threshold
    # the speed's estimate is too noisy to steer the comparison)
    m_tdc, m_wheel = state.mean[:z], state.mean[-1]
    suspect = np.where(np.abs(m_tdc) > math.radians(cfg.tdc_deg), m_tdc, 0.0) + (
        m_wheel if abs(m_wheel) > math.radians(cfg.wheel_deg) else 0.0)
    lead_tdc = np.where(in_use != 0.0, in_use, suspect)
    sib = sibling_compare(spec, grid, raw_pressure, cfg.window_deg, (np.zeros(z) if twist is None else twist)
                          - lead_tdc)
    sens, d_indicated, gain_cols = speed_sensitivity(op, grid, pressure, speed.theta_fly, speed.omega, speed.alpha)
    # TDC: normal equations accumulated with forgetting, each cycle's referred to the correction it ran with
    j_c, h_c = tdc_information(sens, speed.residual, speed.sigma, speed.design, speed.prior_info, gain_cols,
                               cfg.prior_gain)
    # a TDC offset is zero until the speed says not: the wheel (common to all) and each cylinder's own offset
    prior = np.linalg.inv(math.radians(cfg.prior_wheel_deg) ** 2 + np.eye(z) * math.radians(cfg.prior_tdc_deg) ** 2)
    j_acc = cfg.memory * state.tdc_info + j_c
    h_acc = cfg.memory * state.tdc_rhs + h_c + j_c @ in_use
    cov = np.linalg.inv(j_acc + prior)
    tdc_s = cov @ h_acc
    tdc = in_use + np.linalg.solve(j_c + prior, h_c)  # this cycle's own
    # the wheel alone (every cylinder shifted alike, the sum of the columns): on a large engine the common mode is
    # well determined where the cylinders' own offsets are not, and a joint solve would let them trade off
    # (the gains are not eliminated here: their sum, a common gain, looks much like the wheel and is not measured)
    one = np.ones(z)
    j_w, h_w = tdc_information(sens, speed.residual, speed.sigma, speed.design, speed.prior_info, gain_cols[:, :0],
                               cfg.prior_gain)
    jw_c, hw_c = float(one @ j_w @ one), float(one @ h_w)
    prior_w = 1.0 / math.radians(cfg.prior_wheel_deg) ** 2
    jw = cfg.memory * state.wheel_info + jw_c
    hw = cfg.memory * state.wheel_rhs + hw_c + jw_c * float(np.mean(in_use))
    wheel = float(np.mean(in_use)) + hw_c / (jw_c + prior_w)
    # a few cylinders resolve their own columns: the wheel is the median of the joint estimates (one cylinder's
    # offset then stays its own instead of moving the wheel)
    few = 3 <= z <= cfg.joint_max_cyl
    if few:
        wheel = float(np.median(tdc))
    rel = tdc - wheel if z >= 3 else np.full(z, np.nan)  # a cylinder's own: its joint estimate beyond the wheel
    q = np.concatenate([rel, sib.ravel(), [wheel]])
    n = state.count + 1
    g = max(1.0 - cfg.memory, 1.0 / n)
    ok = np.isfinite(q)
    d = np.where(ok, q - state.mean, 0.0)
    mean = state.mean + g * d
    var = (1.0 - g) * (state.var + g * d * d)
    n_eff = min(float(n), (2.0 - g) / g)
    floor = np.concatenate([np.full(z, math.radians(cfg.floor_tdc_deg)), np.full(z, cfg.floor_gain),
                            np.full(z, cfg.floor_offset_pa), [math.radians(cfg.floor_wheel_deg)]])
    spread = var / n_eff  # the scatter of the per-cycle values, or for the TDC the information if it says more
    mean[-1] = float(np.median(tdc_s)) if few else hw / (jw + prior_w)
    spread[-1] = max(spread[-1], float(np.mean(np.diag(cov))) * math.pi / (2.0 * z) if few else 1.0 / (jw + prior_w))
    if z >= 3:
        mean[:z] = tdc_s - mean[-1]
        spread[:z] = np.maximum(spread[:z], np.diag(cov))
    noise = np.where(ok, np.sqrt(spread + floor**2), np.nan)  # what decides a flag: is it more than noise?
    scale = np.zeros_like(mean)
    scale[:z], scale[-1] = cfg.scale_error * mean[:z], cfg.scale_error * mean[-1]
    sigma = np.hypot(noise, scale)  # what is reported and carried into the friction sigma
    thr = np.concatenate([np.full(z, math.radians(cfg.tdc_deg)), np.full(z, cfg.gain), np.full(z, cfg.offset_pa),
                          [math.radians(cfg.wheel_deg)]])
    if z >= 3:  # beyond the healthy spread of the siblings themselves (robust: one faulty cylinder does not move it)
        block = mean[:3 * z].reshape(3, z)
        spread = 1.4826 * np.median(np.abs(block - np.median(block, axis=1, keepdims=True)), axis=1)
        thr[:3 * z] = np.maximum(thr[:3 * z], np.repeat(cfg.spread_sigmas * spread, z))
    flagged = ok & (n >= cfg.min_cycles) & (np.abs(mean) > thr) & (np.abs(mean) > cfg.flag_sigmas * noise)
    keep = ok & (a != 0.0) & (np.abs(mean) > 2.0 * noise)  # a correction in use stays while it is significant
    applied = np.where(flagged | keep, mean, 0.0)
    if not cfg.correct_wheel:  # flagged and carried in the sigma, never applied (see SensorHealthConfig)
        applied[-1] = 0.0
    # what stays uncertain after this cycle's corrections, into the friction sigma (dT_iM/dDelta, dT_iM/dgain;
    # a constant pressure offset does no work over the cycle)
    unsure = np.where(a != 0.0, sigma, np.hypot(mean, sigma))
    u_tdc, u_gain, u_wheel = unsure[:z], unsure[z:2 * z], unsure[-1]
    u_tdc = np.where(np.isfinite(u_tdc), u_tdc, 0.0)
    u_gain = np.where(np.isfinite(u_gain), u_gain, 0.0)
    if not math.isfinite(u_wheel) or n < cfg.min_cycles:
        u_wheel = max(u_wheel if math.isfinite(u_wheel) else 0.0, math.radians(cfg.prior_wheel_deg))
    per_cyl = np.sqrt((d_indicated * u_tdc) ** 2 + (indicated * u_gain) ** 2 + (d_indicated * u_wheel) ** 2)
    total = math.sqrt(float(np.sum((d_indicated * u_tdc) ** 2 + (indicated * u_gain) ** 2))
                      + (float(np.sum(d_indicated)) * u_wheel) ** 2)
    names = ([f"sensor_tdc_offset_cyl{k + 1}" for k in range(z)] + [f"sensor_pressure_gain_cyl{k + 1}" for k in range(z)]
             + [f"sensor_pressure_offset_cyl{k + 1}" for k in range(z)] + ["sensor_tdc_offset"])
    sib_nan = np.zeros(z) if z >= 3 else np.full(z, np.nan)
    health = SensorHealth(
        tdc_offset=mean[-1] + np.nan_to_num(mean[:z]), tdc_offset_sigma=np.hypot(sigma[-1], np.nan_to_num(sigma[:z])),
        tdc_offset_cycle=q[-1] + np.nan_to_num(q[:z]), tdc_offset_siblings=mean[:z] + sib_nan,
        wheel_tdc_offset=float(mean[-1]), wheel_tdc_offset_sigma=float(sigma[-1]), wheel_tdc_offset_cycle=float(q[-1]),
        pressure_gain=1.0 + mean[z:2 * z], pressure_gain_sigma=sigma[z:2 * z], pressure_gain_cycle=1.0 + q[z:2 * z],
        pressure_offset=mean[2 * z:3 * z], pressure_offset_sigma=sigma[2 * z:3 * z],
        pressure_offset_cycle=q[2 * z:3 * z],
        applied_tdc=a[:z] + a[-1], applied_gain=1.0 + a[z:2 * z], applied_offset=a[2 * z:3 * z],
        friction_sigma_cyl=per_cyl, friction_sigma=total,
        flags=tuple(nm for nm, f in zip(names, flagged, strict=True) if f))
    return SensorHealthState(n, mean, var, applied, j_acc, h_acc, jw, hw), health


def inflate(spec: EngineSpec, est: FrictionEstimate, health: SensorHealth) -> FrictionEstimate:
    """``est`` with the sensors' remaining uncertainty added (in quadrature) to its friction and FMEP sigmas: the
    figure is the same, what it claims to know is honest about the TDC and gain it rests on."""
    t = health.friction_sigma
    if t == 0.0:
        return est
    per = health.friction_sigma_cyl
    return replace(
        est, total_friction_torque_sigma=math.hypot(est.total_friction_torque_sigma, t),
        total_fmep_sigma=math.hypot(est.total_fmep_sigma, spec.torque_to_mep(t)),
        friction_torque_mean_sigma=np.hypot(est.friction_torque_mean_sigma, per),
        fmep_sigma=np.hypot(est.fmep_sigma, spec.torque_to_mep(1.0, 1) * per))


def check_cycle(cfg: SensorHealthConfig, spec: EngineSpec, state: SensorHealthState, grid: np.ndarray,
                raw_pressure: np.ndarray, pressure: np.ndarray, op: OperatingPoint, balance, params: np.ndarray,
                stats, prior_info: np.ndarray, model_rel_error: float) -> tuple[SensorHealthState, SensorHealth]:
    """``assess`` from the monitor's stages: the harmonic balance's result (core.monitor.balance.harmonic_balance:
    excitation, rows, static twist), the friction estimate ``params`` the residual is taken at, and the noise model
    (core.monitor.identify.noise_model.ResidualStats plus the repeatable model error, as in core.monitor.identify.noise_model)."""
    exc, rows, static = balance.excitation, balance.rows, balance.static
    omega = exc.omega_fly if exc.omega_fly is not None else np.full(exc.tau.shape, float(np.mean(exc.omega_node)))
    alpha = exc.alpha_fly if exc.alpha_fly is not None else np.zeros(exc.tau.shape)
    p = rows.design.shape[1]
    resid = rows.target - rows.design @ params[:p]
    sigma = np.sqrt(np.maximum(stats.var, 0.0) + (model_rel_error * np.abs(rows.target)) ** 2)
    sigma = np.where(sigma > 0, sigma, max(float(np.max(sigma)), 1e-12))
    twist = static[op.cylinders.node] if static is not None and static.shape[0] == op.cylinders.n_nodes else None
    speed = SpeedEvidence(exc.theta_fly, omega, alpha, resid, sigma, rows.design, prior_info)
    return assess(cfg, spec, state, grid, raw_pressure, pressure, op, speed, exc.indicated_mean, twist)


class SensorHealthCheck:
    """Sensor health as one of the monitor's checks (core.monitor.checks.check): ``check_cycle`` with the monitor's
    ``config.sensor_health`` (None: off, the state passed on as it came, no flags, ``sensor_health`` None), the
    friction estimates' sigmas inflated by what the sensors leave uncertain (``inflate``). Its state is the one the
    corrections before the balance were taken from (``corrected_inputs``).

    >>> from types import SimpleNamespace
    >>> off = SimpleNamespace(config=SimpleNamespace(sensor_health=None), ident="the identification",
    ...                       spec=SimpleNamespace(n_cyl=2))
    >>> step = SensorHealthCheck().update(None, off)
    >>> (step.flags, step.ident, step.report, step.state.count)
    ((), 'the identification', {'sensor_health': None}, 0)
    """

    name = "sensor"

    def update(self, state: SensorHealthState | None, inp: CheckInput) -> CheckStep:
        cfg = inp.config
        state = state if state is not None else SensorHealthState.empty(inp.spec.n_cyl)  # kept even when off
        if cfg.sensor_health is None:
            return CheckStep(state, (), inp.ident, {"sensor_health": None})
        ident = inp.ident
        state, health = check_cycle(cfg.sensor_health, inp.spec, state, inp.grid, inp.raw_pressure, inp.pressure,
                                    inp.op, inp.balance, inp.params, ident.stats, inp.prior_info,
                                    cfg.model_rel_error)
        ident = replace(ident, smoothed_estimate=inflate(inp.spec, ident.smoothed_estimate, health),
                        cycle_estimate=inflate(inp.spec, ident.cycle_estimate, health))
        return CheckStep(state, tuple(health.flags), ident, {"sensor_health": health})
