"""Each cylinder's TDC and pegging from its own pressure (issue 25): a thermodynamic fit, no TDC probe.

Why this method. A TDC error delta and a pegging error dp leave characteristic deviations in the apparent rate of heat
release (ROHR) outside combustion (Zvar Baskovic et al., Energies 2017, 10(1), 143): with the volume evaluated at the
wrong angle the ROHR picks up delta * gamma/(gamma-1) p (V'' - V'^2 / V) (to first order on a polytrope: the same
sign before and after TDC, and in a fired cycle larger in the expansion, where p is high), while a pegging error adds
gamma/(gamma-1) dp V' (opposite signs before and after TDC). A compression-only polytropic fit was tried in this
project and dropped (design-notes.md, sensor health): over one window a TDC shift is nearly collinear with the
exponent and the gain. Fitting the compression (after IVC, before the start of combustion) AND the expansion (after
the end of combustion, before EVO) windows with one delta breaks that: the exponent is not free, gamma(T) of air is
the project's own thermodynamics (core.model.thermo), and the two windows see a TDC shift and a pegging error with
different signs.

What remains outside combustion is the wall heat flow, which a naive fit reads as a TDC error (the motored loss angle,
0.4-1.3 deg, SAE 2004-01-1458). It is the project's Woschni model (core.model.thermo: the simulator's, with its
combustion term after the start of combustion), so the loss angle is not read as an offset. Its scale is not fitted:
a free scale was tried and is nearly collinear with the TDC shift (TU/e motored files moved by 3.5 deg). What the
wall heat and losses it lacks (blow-by, crevices) could do to the offset is refitted and put into sigma instead.
Motored cycles use the same fit over the whole closed part (no combustion window to leave out).

The fit is on the mean of the cycles: a per-cycle fit was tried and the noise in p' biased it (maruti +1.5 deg).

Conventions: angle_rad is the cylinder's local angle, 0 = the *assumed* firing TDC; ``offset_rad`` is the correction
to add to the assumed TDC angle (the true TDC lies at angle_rad = offset_rad), i.e. the sign of the simulator's
``tdc_offset`` effect (+ = TDC later than stated). pegging_pa is what to add to the pressure. Pressure gain does not
enter the TDC to first order (the ROHR scales with it, the Woschni flow with its power 0.8).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.kinematics import kinematics
from frictionwatch.core.model.thermo import (
    N_MOTORED,
    R_AIR,
    WALL_AREA_HEAD_PISTON,
    WOSCHNI_C1,
    WOSCHNI_C2,
    WOSCHNI_SCALE,
    cp_air,
)
from frictionwatch.core.monitor.calibration.tdc_kernels import (
    C_AREA,
    C_BORE,
    C_CLEAR,
    C_DISP,
    C_E,
    C_HEAT,
    C_IVC,
    C_OMEGA,
    C_PIVC,
    C_R,
    C_SOC,
    C_TIVC,
    C_TWALL,
    N_CONST,
    gauss_newton_kernel,
)
from frictionwatch.core.monitor.calibration.tdc_smoothing import (
    Smoothing,
    smooth_width,
    smoothed_pressure,
)
from frictionwatch.core.tuned import MONITOR_RECORD, read_tuned
from frictionwatch.core.types import Cycle

METHOD_FIRED = "rohr-compression-expansion"  # Energies 2017, 10(1), 143 with the project's Woschni wall heat
METHOD_MOTORED = "rohr-motored-heat-loss-shaping"  # SAE 2004-01-1458 idea, same fit over the whole closed part

# Window edges [deg]. The compression window starts this far after IVC (the valve's last flow and the pressure wave)
# and ends this far before the start of combustion; the expansion window starts this far after the end of
# combustion and ends this far before EVO. Chosen on k9k-4cyl 1700 rpm / 1.0 and maruti-3cyl 3000 rpm / 0.8,
# seed 1, healthy and tdc_offset +-1.0 deg (bench/tdc_from_pressure.py --tune); tested on the other cases.
_TUNED = read_tuned(MONITOR_RECORD)  # these hand-set numbers with their provenance (core.tuned)
AFTER_IVC_DEG = _TUNED["TDC_AFTER_IVC_DEG"].value
BEFORE_SOC_DEG = _TUNED["TDC_BEFORE_SOC_DEG"].value
AFTER_EOC_DEG = _TUNED["TDC_AFTER_EOC_DEG"].value
BEFORE_EVO_DEG = _TUNED["TDC_BEFORE_EVO_DEG"].value
# Systematic 1-sigma of the method where the wall heat is right (the mass estimate, the combustion edges, the
# smoothing): the rms of the found-minus-true offsets (rigid crank), rounded up; re-tuned apart on the same points
# at seeds 14-15 by bench/calibrate_tdc_sigma.py (0.045 deg over 42 estimates; seed 1 by hand: 0.043 over 21).
SYSTEMATIC_SIGMA_DEG = _TUNED["TDC_SYSTEMATIC_SIGMA_DEG"].value
BURN_FRACTION = 0.05  # of the peak net ROHR: the start and end of combustion (_combustion_edges)
GN_ITERATIONS = 8
MAX_STEP_RAD = math.radians(3.0)  # a Gauss-Newton step larger than this is cut (the windows move with delta)
# Relative 1-sigma of the wall heat on an engine whose heat transfer nobody measured (Woschni's correlation against
# engines it was not fitted on: tens of %). On the simulator the wall heat is exactly the project's Woschni, so there
# this part of sigma is pessimistic; on a real engine it is most of sigma (bench/tdc_from_pressure.py, README).
HEAT_LOSS_REL_SIGMA = 0.3
BLOCKS = 5  # disjoint blocks of cycles whose fits give the statistical sigma
FD_DELTA_RAD = math.radians(0.05)
FD_PEG_PA = 2.0e3
# the kernel's iteration settings: [iterations, FD delta, FD peg, largest step, stop below this step] (rad, Pa)
_GN_STEPS = np.array([GN_ITERATIONS, FD_DELTA_RAD, FD_PEG_PA, MAX_STEP_RAD, math.radians(1e-4)])


@dataclass(frozen=True)
class TdcEstimate:
    """One cylinder's TDC correction and pegging from its pressure.

    offset_rad : add to the assumed TDC angle (true TDC at local angle offset_rad; + = TDC later than assumed)
    sigma_rad  : 1 sigma = sqrt(statistical^2 + systematic^2 + heat_loss^2 + constant_loss^2) (``tdc_from_pressure``;
                 each part in ``evidence`` in deg)
    pegging_pa : pegging correction of the mean cycle (add to the pressure) [Pa]
    n_cycles   : cycles used (rows with finite pressure)
    method     : METHOD_FIRED or METHOD_MOTORED
    evidence   : windows [deg], the parts of sigma [deg], the block fits' offsets [deg], the pegging's parts of
                 sigma [Pa] (sampling, heat loss, constant loss: as the offset's), the wall-heat scale and its
                 relative sigma, the rms residual in the windows relative to the rms wall heat there
    """

    offset_rad: float
    sigma_rad: float
    pegging_pa: float
    n_cycles: int
    method: str
    evidence: dict = field(default_factory=dict)

    @property
    def offset_deg(self) -> float:
        return math.degrees(self.offset_rad)

    @property
    def sigma_deg(self) -> float:
        return math.degrees(self.sigma_rad)


def volume_and_derivative(angle_rad: np.ndarray, spec: EngineSpec) -> tuple[np.ndarray, np.ndarray]:
    """V [m^3] and dV/dtheta [m^3/rad] of one cylinder at its local angles (any shape; core.model.kinematics)."""
    shape = np.shape(angle_rad)
    x, dx, _ = kinematics(angle_rad, spec.kinematics_params())
    area = spec.piston_area
    return (spec.clearance_volume + area * x).reshape(shape), (area * dx).reshape(shape)


def gamma_of_temperature(temp_k: np.ndarray) -> np.ndarray:
    """c_p / c_v of air at T (the Sonntag c_p of core.model.thermo)."""
    cp = cp_air(temp_k)
    return cp / (cp - R_AIR)


def apparent_heat_release_rate(pressure_pa: np.ndarray, dpressure: np.ndarray, volume: np.ndarray,
                               dvolume: np.ndarray, gamma: np.ndarray) -> np.ndarray:
    """First-law apparent (net) ROHR [J/rad]: gamma/(gamma-1) p V' + 1/(gamma-1) V p' (single zone, no mass flow)."""
    return (gamma * pressure_pa * dvolume + volume * dpressure) / (gamma - 1.0)


@dataclass(frozen=True)
class _Setting:
    """What the ROHR model of one cylinder needs besides the pressure: the spec, the mean crank speed [rad/s], the
    pressure at IVC [Pa] (before pegging) and the start of combustion [rad] (the Woschni combustion term)."""

    spec: EngineSpec
    omega: float
    p_ivc: float
    soc_rad: float
    heat_loss_scale: float = 1.0


def _model_terms(p: np.ndarray, dp: np.ndarray, angle: np.ndarray, delta: float | np.ndarray,
                 peg: float | np.ndarray, st: _Setting) -> tuple[np.ndarray, np.ndarray]:
    """(net apparent ROHR, Woschni wall heat flow) [J/rad] of pressure p (m,) at angles angle - delta, p + peg.

    The wall heat is the project's Woschni model (core.model.thermo: WOSCHNI_SCALE, C1, C2, the head/piston area),
    with the trapped mass from the IVC state (p_IVC + peg, the stated T_IVC); outside combustion the net ROHR of a
    right TDC and pegging is minus this flow. delta and peg may be columns (k, 1): k evaluations at once, (k, m)
    each (a Gauss-Newton iteration's three in one call: ``_gauss_newton``), each the same numbers as alone."""
    spec, cb = st.spec, st.spec.combustion
    shifted = angle - delta
    vol, dvol = volume_and_derivative(shifted, spec)
    v_ivc, _ = volume_and_derivative(np.asarray(math.radians(cb.ivc_deg) - delta, dtype=np.float64), spec)
    p_ivc = np.maximum(st.p_ivc + peg, 1e3)
    mass = p_ivc * v_ivc / (R_AIR * cb.t_ivc_k)
    pc = np.maximum(p + peg, 1e3)
    temp = pc * vol / (mass * R_AIR)
    gamma = gamma_of_temperature(temp)
    q = apparent_heat_release_rate(pc, dp, vol, dvol, gamma)
    cbar = spec.displacement_cyl / spec.piston_area * st.omega / math.pi
    w = WOSCHNI_C1 * cbar + np.where(
        shifted > st.soc_rad,
        WOSCHNI_C2 * spec.displacement_cyl * cb.t_ivc_k / (p_ivc * v_ivc)
        * np.maximum(pc - p_ivc * (v_ivc / vol) ** N_MOTORED, 0.0), 0.0)
    h = WOSCHNI_SCALE * 3.26 * spec.bore ** -0.2 * (pc * 1e-3) ** 0.8 * temp ** -0.55 * w ** 0.8
    area_w = WALL_AREA_HEAD_PISTON * spec.piston_area + math.pi * spec.bore * vol / spec.piston_area
    return q, st.heat_loss_scale * h * area_w * (temp - cb.t_wall_k) / st.omega


def _combustion_edges(angle_deg: np.ndarray, q_mean: np.ndarray, last_deg: float) -> tuple[float, float]:
    """Start and end of combustion [deg] of the mean cycle's net ROHR: the last angle before its peak and the first
    after it where it is below BURN_FRACTION of the peak, the peak sought between -60 deg and ``last_deg``. A
    threshold, not the cumulative release, because a TDC error of a degree adds to the ROHR in the expansion a
    deviation a few % of the peak that moves a cumulative maximum by tens of degrees; the burn's slow start and
    tail beyond the threshold are what the margins BEFORE_SOC_DEG and AFTER_EOC_DEG leave out."""
    sel = (angle_deg >= -60.0) & (angle_deg <= last_deg)
    a, q = angle_deg[sel], q_mean[sel]
    k = int(np.argmax(q))
    low = q < BURN_FRACTION * q[k]
    before = np.flatnonzero(low[:k])
    after = np.flatnonzero(low[k:])
    soc = a[before[-1]] if before.size else a[0]
    eoc = a[k + after[0]] if after.size else a[-1]
    return float(soc), float(eoc)


def _windows(angle_deg: np.ndarray, spec: EngineSpec, motored: bool, q_mean: np.ndarray
             ) -> tuple[np.ndarray, list[tuple[float, float]]]:
    ivc, evo = spec.combustion.ivc_deg, spec.combustion.evo_deg
    if motored:
        edges = [(ivc + AFTER_IVC_DEG, evo - BEFORE_EVO_DEG)]
    else:
        soc, eoc = _combustion_edges(angle_deg, q_mean, evo - BEFORE_EVO_DEG - AFTER_EOC_DEG - 10.0)
        edges = [(ivc + AFTER_IVC_DEG, soc - BEFORE_SOC_DEG), (eoc + AFTER_EOC_DEG, evo - BEFORE_EVO_DEG)]
    mask = np.zeros(angle_deg.shape, dtype=bool)
    for lo, hi in edges:
        if not hi - lo >= 10.0:
            raise ValueError(f"window {lo:.0f}..{hi:.0f} deg is shorter than 10 deg: combustion fills the closed part")
        mask |= (angle_deg >= lo) & (angle_deg <= hi)
    return mask, edges


def _gauss_newton(p: np.ndarray, dp: np.ndarray, ang: np.ndarray, st: _Setting, delta: float, peg: float,
                  constant_loss: bool = False) -> tuple[float, float]:
    """``_gauss_newton_reference`` by its kernel (``tdc_kernels.gauss_newton_kernel``, tested equal): a window's
    fits on k9k took 180 us each in numpy, 82 us in the kernel, the same per-sample arithmetic without ~40 numpy
    calls and an SVD per iteration (a kernel of the residual alone was no faster: the loop and lstsq are the cost)."""
    return gauss_newton_kernel(np.ascontiguousarray(p, dtype=np.float64), np.ascontiguousarray(dp, dtype=np.float64),
                               np.ascontiguousarray(ang, dtype=np.float64), _constants(st),
                               np.array([delta, peg, 1.0 if constant_loss else 0.0]), _GN_STEPS)


def _constants(st: _Setting) -> np.ndarray:
    """The constants array of the kernels (``tdc_kernels`` C_* layout) for one setting."""
    spec, cb = st.spec, st.spec.combustion
    c = np.empty(N_CONST)
    c[C_R:C_E + 1] = spec.kinematics_params()
    c[[C_AREA, C_CLEAR, C_DISP, C_BORE, C_IVC, C_TIVC, C_TWALL, C_OMEGA, C_PIVC, C_SOC, C_HEAT]] = (
        spec.piston_area, spec.clearance_volume, spec.displacement_cyl, spec.bore, math.radians(cb.ivc_deg),
        cb.t_ivc_k, cb.t_wall_k, st.omega, st.p_ivc, st.soc_rad, st.heat_loss_scale)
    return c


def _gauss_newton_reference(p: np.ndarray, dp: np.ndarray, ang: np.ndarray, st: _Setting, delta: float, peg: float,
                  constant_loss: bool = False) -> tuple[float, float]:
    """(delta, peg) minimising sum (ROHR + wall heat [+ c])^2 over the window samples of the mean of the rows of p:
    Gauss-Newton, both columns by forward differences; ``constant_loss`` adds a free constant loss power c (a loss
    the Woschni shape does not have: blow-by, crevices), the variant whose effect is a part of sigma."""
    pm, dpm = p.mean(axis=0), dp.mean(axis=0)
    for _ in range(GN_ITERATIONS):
        # the residual at (delta, peg) and at each forward step in one call
        q, w = _model_terms(pm, dpm, ang, np.array([[delta], [delta + FD_DELTA_RAD], [delta]]),
                            np.array([[peg], [peg], [peg + FD_PEG_PA]]), st)
        r, rd, rp = q + w
        cols = [(rd - r) / FD_DELTA_RAD, (rp - r) / FD_PEG_PA]
        jac = np.column_stack(cols + [np.ones_like(r)] if constant_loss else cols)
        sol, *_ = np.linalg.lstsq(jac, -r, rcond=None)
        delta += float(np.clip(sol[0], -MAX_STEP_RAD, MAX_STEP_RAD))
        peg += float(sol[1])
        if abs(sol[0]) < math.radians(1e-4):
            break
    return delta, peg


def tdc_from_pressure(pressure_pa: np.ndarray, angle_rad: np.ndarray, spec: EngineSpec, speed_rad_s: float,
                      motored: bool = False, heat_loss_scale: float = 1.0,
                      heat_loss_rel_sigma: float = HEAT_LOSS_REL_SIGMA, operator: Smoothing | None = None
                      ) -> TdcEstimate:
    """TDC correction and pegging of one cylinder from its cycles (module docstring).

    pressure_pa : (n_cycles, n_angle) absolute pressure [Pa] on the local grid angle_rad
    angle_rad   : (n_angle,) uniform, increasing local crank angle [rad], 0 = assumed firing TDC, covering at least
                  IVC..EVO of ``spec.combustion``
    speed_rad_s : mean crank speed [rad/s] (the Woschni wall heat scales with the piston speed)
    motored     : no combustion (ignition off, motored, coast-down): one window over the whole closed part
    heat_loss_scale : multiplies the project's Woschni wall heat (1 = core.model.thermo as the simulator has it)
    heat_loss_rel_sigma : relative 1-sigma of that wall heat; its effect on the offset (a refit at
        heat_loss_scale * (1 + heat_loss_rel_sigma)) is a systematic part of sigma
    operator    : the smoothing operator of this grid's step (``smoothing``), where a caller fits the grid again

    The fit is made on the mean cycle (noise averages out before the non-linear ROHR). sigma = sqrt(statistical^2
    + SYSTEMATIC_SIGMA_DEG^2 + heat-loss^2 + other-loss^2): statistical from the same fit on BLOCKS disjoint blocks
    of cycles, SYSTEMATIC_SIGMA_DEG the method's rms error where the wall heat is right (the simulator), heat-loss
    as above, other-loss the change when a free constant loss power is fitted beside it (blow-by and crevice flow
    the model lacks: on the TU/e fired files this moves the offset by degrees, on the simulator by < 0.25 deg).
    """
    p = np.atleast_2d(np.asarray(pressure_pa, dtype=np.float64))
    ang = np.asarray(angle_rad, dtype=np.float64).ravel()
    if p.shape[1] != ang.shape[0] or ang.shape[0] < 8:
        raise ValueError(f"pressure must be (n_cycles, {ang.shape[0]}), got {p.shape}")
    step = np.diff(ang)
    if not np.all(step > 0) or np.ptp(step) > 1e-6 * step.mean():
        raise ValueError("angle_rad must be uniform and increasing")
    if not (speed_rad_s > 0 and heat_loss_scale >= 0 and heat_loss_rel_sigma >= 0):
        raise ValueError(f"speed_rad_s {speed_rad_s} must be > 0, heat_loss_scale {heat_loss_scale} and "
                         f"heat_loss_rel_sigma {heat_loss_rel_sigma} >= 0")
    p = p[np.all(np.isfinite(p), axis=1)]
    if p.shape[0] == 0:
        raise ValueError("no cycle with finite pressure")
    deg = np.degrees(ang)
    cb = spec.combustion
    if deg[0] > cb.ivc_deg or deg[-1] < cb.evo_deg:
        raise ValueError(f"the grid {deg[0]:.0f}..{deg[-1]:.0f} deg must cover IVC {cb.ivc_deg:g}..EVO {cb.evo_deg:g}")
    clipped = _clipped(p, float(step.mean()))
    p, dp = smoothed_pressure(p, float(step.mean()), operator)
    i_ivc = int(np.argmin(np.abs(deg - cb.ivc_deg)))
    p_ivc = float(np.mean(p[:, i_ivc]))
    omega = float(speed_rad_s)
    # windows from the mean cycle's ROHR at no correction, then again at the first pass's correction (and once more
    # where the IVC state is extrapolated: it moves with the pegging)
    delta, peg = 0.0, 0.0
    st = _Setting(spec, omega, p_ivc, math.pi if motored else 0.0, heat_loss_scale)
    for _ in range(3 if clipped[i_ivc] else 2):
        if clipped[i_ivc]:
            p_ivc = _ivc_from_polytrope(p.mean(axis=0), ang, clipped, i_ivc, delta, peg, spec)
            st = _Setting(spec, omega, p_ivc, st.soc_rad, heat_loss_scale)
        q0, _ = _model_terms(p.mean(axis=0), dp.mean(axis=0), ang, delta, peg, st)
        mask, edges = _windows(deg, spec, motored, q0)
        mask &= ~clipped
        if np.count_nonzero(mask) < 8:
            raise ValueError("the pressure is clipped at its floor over the fit windows")
        soc = math.pi if motored else math.radians(edges[0][1] + BEFORE_SOC_DEG)
        st = _Setting(spec, omega, p_ivc, soc, heat_loss_scale)
        delta, peg = _gauss_newton(p[:, mask], dp[:, mask], ang[mask], st, delta, peg)
    pw, dpw, aw = p[:, mask], dp[:, mask], ang[mask]
    n = p.shape[0]
    n_blocks = min(BLOCKS, n)
    blocks = np.array([_gauss_newton(pw[i::n_blocks], dpw[i::n_blocks], aw, st, delta, peg) for i in range(n_blocks)])
    block, block_peg = blocks[:, 0], blocks[:, 1]
    # blocks of n / B cycles: the scatter of their fits over sqrt(B) is the sampling error of the whole mean's fit
    stat = float(np.std(block, ddof=1) / math.sqrt(n_blocks)) if n_blocks > 1 else math.radians(0.5)
    stat_peg = float(np.std(block_peg, ddof=1) / math.sqrt(n_blocks)) if n_blocks > 1 else math.nan
    hot = _Setting(spec, omega, p_ivc, soc, heat_loss_scale * (1.0 + heat_loss_rel_sigma))
    hot_fit = _gauss_newton(pw, dpw, aw, hot, delta, peg)
    loss_fit = _gauss_newton(pw, dpw, aw, st, delta, peg, constant_loss=True)
    heat, other_loss = abs(hot_fit[0] - delta), abs(loss_fit[0] - delta)
    sigma = math.sqrt(stat**2 + math.radians(SYSTEMATIC_SIGMA_DEG) ** 2 + heat**2 + other_loss**2)
    q, w = _model_terms(pw.mean(axis=0), dpw.mean(axis=0), aw, delta, peg, st)
    evidence = {
        "windows_deg": [(round(lo, 1), round(hi, 1)) for lo, hi in edges],
        "statistical_deg": math.degrees(stat),
        "systematic_deg": SYSTEMATIC_SIGMA_DEG,
        "heat_loss_deg": math.degrees(heat),
        "constant_loss_deg": math.degrees(other_loss),
        "heat_loss_scale": heat_loss_scale,
        "heat_loss_rel_sigma": heat_loss_rel_sigma,
        "block_offsets_deg": np.degrees(block).tolist(),
        # the pegging's sampling error and what the same two refits move it by, as the offset's parts (NaN: one block)
        "pegging_statistical_pa": stat_peg,
        "pegging_heat_loss_pa": abs(hot_fit[1] - peg),
        "pegging_constant_loss_pa": abs(loss_fit[1] - peg),
        # rms of ROHR + wall heat left in the windows, relative to the rms wall heat there
        "residual_rel": float(np.sqrt(np.mean((q + w) ** 2)) / max(float(np.sqrt(np.mean(w**2))), 1e-12)),
    }
    return TdcEstimate(delta, sigma, peg, n, METHOD_MOTORED if motored else METHOD_FIRED, evidence)


def _clipped(pressure_pa: np.ndarray, step_rad: float) -> np.ndarray:
    """(n_angle,) the angles the fit leaves out: an absolute pressure is never <= 0, so a sample there is the
    converter's floor (a channel whose offset takes its reading below zero is clipped: the simulator's ADC, a real one
    at the bottom of its range; maruti 1500 rpm at half load with -1.5 bar read its TDC 4.6 deg off and its pegging
    0.93 bar for 1.5 with those samples in), in any row, widened by half the smoothing span on each side (the
    smoothed p and p' there mix in the floor)."""
    bad = np.any(pressure_pa <= 0.0, axis=0)
    half = smooth_width(step_rad) // 2
    if not bad.any():
        return bad
    return np.convolve(bad.astype(np.float64), np.ones(2 * half + 1), mode="same") > 0.0


def _ivc_from_polytrope(p_mean: np.ndarray, ang: np.ndarray, clipped: np.ndarray, i_ivc: int, delta: float,
                        peg: float, spec: EngineSpec) -> float:
    """The reading at IVC where it is clipped: the first unclipped sample of the compression, pegged (``peg``),
    taken back along the motored polytrope (thermo.N_MOTORED) to IVC, less the pegging again."""
    after = np.flatnonzero(~clipped[i_ivc:])
    if after.size == 0:
        raise ValueError("the pressure is clipped at its floor over the whole compression")
    j = i_ivc + int(after[0])
    v, _ = volume_and_derivative(np.array([ang[i_ivc], ang[j]]) - delta, spec)
    return float((p_mean[j] + peg) * (v[1] / v[0]) ** N_MOTORED - peg)


def local_cycles(cycles: Sequence[Cycle], row: int, phase_rad: float, half_width_rad: float = math.pi
                 ) -> tuple[np.ndarray, np.ndarray]:
    """(pressure (m, n_local), local angle (n_local,)) of the cylinder in pressure row ``row`` firing at
    ``phase_rad`` on cylinder 1's angle: every pair of consecutive assembled cycles (index, index + 1) gives that
    cylinder's window [-half, +half) about its firing TDC in the second cycle (or, past 4 pi - half, the first)."""
    if len(cycles) < 2:
        return np.zeros((0, 0)), np.zeros(0)
    grid = cycles[0].grid
    n = grid.shape[0]
    step = 4.0 * math.pi / n
    half = int(round(half_width_rad / step))
    centre = int(round((phase_rad % (4.0 * math.pi)) / step)) % n
    if centre + half > n:  # the window runs past the cycle's end: centre it in the first cycle of the pair
        centre -= n
    rows = []
    for prev, cur in zip(cycles[:-1], cycles[1:], strict=True):
        if cur.index != prev.index + 1:
            continue
        joined = np.concatenate([prev.pressure[row], cur.pressure[row]])
        seg = joined[n + centre - half : n + centre + half]
        if np.all(np.isfinite(seg)):
            rows.append(seg)
    local = step * np.arange(-half, half)
    return (np.array(rows) if rows else np.zeros((0, 2 * half))), local


def tdc_of_cycles(cycles: Sequence[Cycle], spec: EngineSpec, motored: bool = False, **options: float
                  ) -> list[TdcEstimate | None]:
    """``tdc_from_pressure`` of every cylinder of an assembled cycle list (None for a cylinder without pressure or
    without two consecutive cycles); cylinder k fires at ``spec.firing_angles[k]`` on cylinder 1's angle; the speed
    is the cycles' mean; ``options`` go to ``tdc_from_pressure``."""
    out: list[TdcEstimate | None] = []
    spans = [(c.tooth_ticks[-1] - c.tooth_ticks[0]) / c.tick_hz for c in cycles]
    spans_angle = [c.tooth_angle[-1] - c.tooth_angle[0] for c in cycles]
    speed = float(np.sum(spans_angle) / np.sum(spans)) if cycles else math.nan
    for k, phase in enumerate(np.asarray(spec.firing_angles, dtype=np.float64)):
        p, ang = local_cycles(cycles, k, float(phase))
        out.append(tdc_from_pressure(p, ang, spec, speed, motored, **options) if p.shape[0] else None)
    return out
