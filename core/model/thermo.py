"""Single-zone cylinder model for the plant simulator (physics.md §13; paper 001 Eq. 1, 3, 12-13).

One call gives one cylinder's absolute pressure over one 720 deg cycle on a uniform local-angle grid

    theta_i = -2 pi + i * step,  i = 0 .. n  (n = 4 pi / step; theta = 0 is this cylinder's firing TDC),

so the first and last points are the gas-exchange TDC either side of firing TDC (p(-2 pi) = p(+2 pi)).

Closed part IVC -> EVO: state (p, m) integrated by fixed-step RK4 in theta with

    dp/dtheta = ((gamma-1)/V)(dQc - dQw) - gamma p/V dV/dtheta + gamma p/m dm/dtheta      (leak as isentropic outflow)

gamma = c_p/c_v of air at T = pV/(m R) from the Sonntag c_p (Seddak Eq. 12); no extra dgamma term (physics.md §13).
Heat release: dual Wiebe (single when beta_p = 0), exponents as given (= m + 1). Wall heat: Woschni with the IVC
reference state and a polytropic motored pressure. Blow-by: an effective orifice area to the crankcase (choked or
subsonic), which lowers compression and peak pressure.

Gas exchange (crude, adequate for a torque source): exponential blowdown from EVO towards p_exh (tau 12 deg),
p_exh through the exhaust stroke, a 30 deg ramp across gas-exchange TDC to p_int (valve overlap), p_int in the
intake stroke, then a linear ramp to p_IVC ending at IVC.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba
import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.jit import BORROWING
from frictionwatch.core.model.kinematics import kinematics

R_AIR = 287.0  # J/(kg K)
P_CRANKCASE = 1.0e5  # Pa
STEP_DEG = 0.25  # default local-angle grid of a trace
BLOWDOWN_TAU_DEG = 12.0
OVERLAP_HALF_DEG = 15.0
WALL_AREA_HEAD_PISTON = 2.3  # head + piston crown (with bowl) in piston areas
WOSCHNI_C1 = 2.28
WOSCHNI_C2 = 3.24e-3  # m/(s K), combustion and expansion only
N_MOTORED = 1.33  # polytropic exponent of the Woschni motored reference pressure
WOSCHNI_SCALE = 0.6  # calibration multiplier on Woschni h: reproduces the CHK prototype points of engines.md §3

# constant parameter layout (``cylinder_model(...).constants``)
(_BORE, _AREA, _VD, _TW, _WA, _EXP_P, _EXP_D, _DUR_P, _DUR_D, _TIVC, _IIVC, _IEVO, _TAU, _STEP, _PCC, _AW0, _VIVC,
 _HT, _NCONST) = range(19)
# per-cycle parameter layout (``cycle_params``)
_Q, _SOC, _BETA, _LEAK, _OMEGA, _PIVC, _PINT, _PEXH, _NCYC = range(9)


@numba.njit(**BORROWING)
def cp_air_kernel(temp):
    """Sonntag c_p of air [J/(kg K)], T clipped to the fit's 300..3500 K range (physics.md §13)."""
    t = min(max(temp, 300.0), 3500.0)
    s = math.sqrt(t)
    return 1e3 * (2.506e-11 * t * t + 1.454e-7 * t * s - 4.246e-7 * t + 3.162e-5 * s + 1.3303
                  - 1.512e4 / (t * s) + 3.063e5 / (t * t) - 2.212e7 / (t * t * t))


@numba.njit(cache=True)
def _cp_air_array(temp, out):
    for i in range(temp.shape[0]):
        out[i] = cp_air_kernel(temp[i])


def cp_air(temp_k: np.ndarray) -> np.ndarray:
    """The simulator's Sonntag c_p of air [J/(kg K)] at each temperature (any shape), for analyses that must use the
    same gas properties (core.monitor.calibration.tdc)."""
    t = np.asarray(temp_k, dtype=np.float64)
    flat = np.ascontiguousarray(t).ravel()
    out = np.empty_like(flat)
    _cp_air_array(flat, out)
    return out.reshape(t.shape)


@numba.njit(**BORROWING)
def _wiebe_rate(u, a, expo, dur):
    """d x_b / d theta of one Wiebe function at u = theta - theta_s >= 0 [1/rad]."""
    r = u / dur
    rm = r ** (expo - 1.0)  # r^expo as rm r: one pow, not two (design note 123)
    return a * expo / dur * rm * math.exp(-a * rm * r)


@numba.njit(**BORROWING)
def _orifice_flow(area, p, temp, p_down, g):
    """Isentropic mass flow [kg/s] through an effective area [m^2] from (p, T) to p_down (choked or subsonic)."""
    pr = p_down / p
    crit = (2.0 / (g + 1.0)) ** (g / (g - 1.0))
    rt = math.sqrt(R_AIR * temp)
    if pr <= crit:
        return area * p / rt * math.sqrt(g) * (2.0 / (g + 1.0)) ** ((g + 1.0) / (2.0 * (g - 1.0)))
    return area * p / rt * math.sqrt(2.0 * g / (g - 1.0) * (pr ** (2.0 / g) - pr ** ((g + 1.0) / g)))


@numba.njit(**BORROWING)
def _angle_terms(theta, vol, c, q):
    """What the closed cylinder's rate depends on through the angle alone: (combustion heat release rate dQc/dtheta
    [J/rad], dual Wiebe; Woschni's motored pressure p_mot [Pa]), both 0 before SOC. The kernel takes them once per
    angle (RK4's two mid-point stages share theta): the same numbers as computed in each stage."""
    dqc = 0.0
    p_mot = 0.0
    u = theta - q[_SOC]
    if u > 0.0 and q[_Q] > 0.0:
        beta = q[_BETA]
        if beta > 0.0:
            dqc += beta * _wiebe_rate(u, c[_WA], c[_EXP_P], c[_DUR_P])
        if beta < 1.0:
            dqc += (1.0 - beta) * _wiebe_rate(u, c[_WA], c[_EXP_D], c[_DUR_D])
        dqc *= q[_Q]
    if u > 0.0:
        p_mot = q[_PIVC] * (c[_VIVC] / vol) ** N_MOTORED
    return dqc, p_mot


@numba.njit(**BORROWING)
def _woschni_constants(c, q):
    """A cycle's Woschni constants: (3.26 B^-0.2 times the scale, C1 cbar [m/s], (C1 cbar)^0.8 (w before SOC),
    C2 Vd T_r/(p_r V_r) [m/(s Pa)])."""
    cbar = c[_VD] / c[_AREA] * q[_OMEGA] / np.pi  # 2 S n = S omega / pi
    w0 = WOSCHNI_C1 * cbar
    return (c[_HT] * 3.26 * c[_BORE] ** -0.2, w0, w0**0.8,
            WOSCHNI_C2 * c[_VD] * c[_TIVC] / (q[_PIVC] * c[_VIVC]))


@numba.njit(**BORROWING)
def _closed_rhs(theta, vol, dvol, p, m, c, q, angle, wo):
    """(dp/dtheta [Pa/rad], dm/dtheta [kg/rad]) of the closed cylinder; c = constants, q = cycle parameters,
    angle = ``_angle_terms`` at theta, wo = ``_woschni_constants``."""
    dqc, p_mot = angle
    h_pre, w0, w0_08, wc2 = wo
    temp = p * vol / (m * R_AIR)
    cp = cp_air_kernel(temp)
    g = cp / (cp - R_AIR)
    # Woschni: h = 3.26 B^-0.2 p[kPa]^0.8 T^-0.55 w^0.8 with w = C1 cbar + C2 Vd T_r/(p_r V_r) (p - p_mot)
    # as h_pre exp(0.8 ln(p[kPa] w) - 0.55 ln T): two logs and an exp, not three pows (design note 123)
    omega = q[_OMEGA]
    if theta - q[_SOC] > 0.0:
        h = h_pre * math.exp(0.8 * math.log(p * 1e-3 * (w0 + wc2 * max(p - p_mot, 0.0))) - 0.55 * math.log(temp))
    else:
        h = h_pre * w0_08 * math.exp(0.8 * math.log(p * 1e-3) - 0.55 * math.log(temp))
    area_w = c[_AW0] + np.pi * c[_BORE] * vol / c[_AREA]
    dqw = h * area_w * (temp - c[_TW]) / omega
    dm = 0.0
    if q[_LEAK] > 0.0 and p > c[_PCC]:
        dm = -_orifice_flow(q[_LEAK], p, temp, c[_PCC], g) / omega
    dp = (g - 1.0) / vol * (dqc - dqw) - g * p / vol * dvol + g * p / m * dm
    return dp, dm


@numba.njit(**BORROWING)
def cycle_pressure_kernel(vol_half, dvol_half, c, q, out):
    """Fill ``out`` (n+1,) with p [Pa] at theta_i = -2 pi + i*step; returns the trapped-mass fraction lost by leak.

    vol_half, dvol_half : (2n+1,) V [m^3] and dV/dtheta [m^3/rad] at the half-step grid -2 pi + j*step/2.
    """
    n = out.shape[0] - 1
    h = c[_STEP]
    i_ivc = int(c[_IIVC])
    i_evo = int(c[_IEVO])
    p_int = q[_PINT]
    p_exh = q[_PEXH]
    p_ivc = q[_PIVC]
    half_overlap = OVERLAP_HALF_DEG * np.pi / 180.0
    ramp_start = min(-np.pi, (i_ivc * h - 2.0 * np.pi) - 20.0 * np.pi / 180.0)
    theta_ivc = i_ivc * h - 2.0 * np.pi
    # intake side: overlap ramp (mid-point at gas-exchange TDC), p_int, linear ramp to p_IVC at IVC
    for i in range(i_ivc + 1):
        th = i * h - 2.0 * np.pi
        if th < ramp_start:
            pi_ = p_int
        else:
            pi_ = p_int + (p_ivc - p_int) * (th - ramp_start) / (theta_ivc - ramp_start)
        x = (th + 2.0 * np.pi) / half_overlap
        if x < 1.0:
            pi_ = pi_ + (p_exh - p_int) * 0.5 * (1.0 - x)
        out[i] = pi_
    # closed part, RK4 in theta on (p, m)
    p = p_ivc
    m = p_ivc * c[_VIVC] / (R_AIR * c[_TIVC])
    m0 = m
    wo = _woschni_constants(c, q)
    a4 = _angle_terms(i_ivc * h - 2.0 * np.pi, vol_half[2 * i_ivc], c, q)
    for i in range(i_ivc, i_evo):
        th = i * h - 2.0 * np.pi
        j = 2 * i
        a1 = a4  # the angle terms at the step's end are the next step's start (design note 123)
        a2 = _angle_terms(th + 0.5 * h, vol_half[j + 1], c, q)
        a4 = _angle_terms(th + h, vol_half[j + 2], c, q)
        k1p, k1m = _closed_rhs(th, vol_half[j], dvol_half[j], p, m, c, q, a1, wo)
        k2p, k2m = _closed_rhs(th + 0.5 * h, vol_half[j + 1], dvol_half[j + 1], p + 0.5 * h * k1p, m + 0.5 * h * k1m,
                               c, q, a2, wo)
        k3p, k3m = _closed_rhs(th + 0.5 * h, vol_half[j + 1], dvol_half[j + 1], p + 0.5 * h * k2p, m + 0.5 * h * k2m,
                               c, q, a2, wo)
        k4p, k4m = _closed_rhs(th + h, vol_half[j + 2], dvol_half[j + 2], p + h * k3p, m + h * k3m, c, q, a4, wo)
        p += h / 6.0 * (k1p + 2.0 * k2p + 2.0 * k3p + k4p)
        m += h / 6.0 * (k1m + 2.0 * k2m + 2.0 * k3m + k4m)
        p = max(p, 1e3)
        out[i + 1] = p
    # exhaust side: blowdown from EVO towards p_exh, then the overlap ramp towards p_int
    p_evo = out[i_evo]
    theta_evo = i_evo * h - 2.0 * np.pi
    for i in range(i_evo + 1, n + 1):
        th = i * h - 2.0 * np.pi
        pe = p_exh + (p_evo - p_exh) * math.exp(-(th - theta_evo) / c[_TAU])
        x = (2.0 * np.pi - th) / half_overlap
        if x < 1.0:
            pe = pe + (p_int - p_exh) * 0.5 * (1.0 - x)
        out[i] = pe
    return 1.0 - m / m0


@dataclass(frozen=True)
class CylinderModel:
    """Engine-fixed inputs of the cylinder kernel: constants ``c`` and the V, dV/dtheta tables.

    theta : (n+1,) local angle grid [rad] of a trace; vol / dvol : V [m^3] and dV/dtheta [m^3/rad] on that grid.
    """

    constants: np.ndarray
    vol_half: np.ndarray
    dvol_half: np.ndarray
    theta: np.ndarray
    vol: np.ndarray
    dvol: np.ndarray

    @property
    def step(self) -> float:
        return float(self.constants[_STEP])


def cylinder_model(spec: EngineSpec, step_deg: float = STEP_DEG, heat_transfer_scale: float = WOSCHNI_SCALE) -> CylinderModel:
    """Precompute the constants and the volume tables of ``spec`` for traces on a ``step_deg`` grid.

    IVC and EVO are snapped to the grid (``spec.combustion.ivc_deg``, ``evo_deg``).
    """
    n = round(720.0 / step_deg)
    if n < 360 or abs(n * step_deg - 720.0) > 1e-9:
        raise ValueError(f"step_deg = {step_deg} must divide 720 deg into at least 360 steps")
    h = 4.0 * np.pi / n
    theta_half = -2.0 * np.pi + 0.5 * h * np.arange(2 * n + 1)
    x, dx, _ = kinematics(theta_half, spec.kinematics_params())
    area = spec.piston_area
    vol_half = spec.clearance_volume + area * x
    dvol_half = area * dx
    cb = spec.combustion
    i_ivc = round((cb.ivc_deg + 360.0) / step_deg)
    i_evo = round((cb.evo_deg + 360.0) / step_deg)
    c = np.zeros(_NCONST)
    c[_BORE] = spec.bore
    c[_AREA] = area
    c[_VD] = spec.displacement_cyl
    c[_TW] = cb.t_wall_k
    c[_WA] = cb.wiebe_a
    c[_EXP_P] = cb.premixed_exponent
    c[_EXP_D] = cb.diffusion_exponent
    c[_DUR_P] = np.radians(cb.premixed_duration_deg)
    c[_DUR_D] = np.radians(cb.diffusion_duration_deg)
    c[_TIVC] = cb.t_ivc_k
    c[_IIVC] = i_ivc
    c[_IEVO] = i_evo
    c[_TAU] = np.radians(BLOWDOWN_TAU_DEG)
    c[_STEP] = h
    c[_PCC] = P_CRANKCASE
    c[_AW0] = WALL_AREA_HEAD_PISTON * area
    c[_VIVC] = vol_half[2 * i_ivc]
    c[_HT] = heat_transfer_scale
    return CylinderModel(c, vol_half, dvol_half, theta_half[::2].copy(), vol_half[::2].copy(), dvol_half[::2].copy())


def charge_pressures(spec: EngineSpec, load: float) -> tuple[float, float, float]:
    """(p_IVC, p_int, p_exh) [Pa] at load fraction ``load``.

    With ``part_load_p_ivc_scaling`` (throttled SI, turbocharged gensets) p_IVC and p_int scale by 0.3 + 0.7 load
    (about 1 bar at no load for the genset, a part-open throttle for the SI engine) and the exhaust back-pressure
    excess over 1.05 bar scales with load; otherwise all three are the full-load values.
    """
    cb = spec.combustion
    if not cb.part_load_p_ivc_scaling:
        return cb.p_ivc_pa, cb.p_intake_pa, cb.p_exhaust_pa
    f = 0.3 + 0.7 * min(max(load, 0.0), 1.2)
    p_exh = cb.p_exhaust_pa if cb.p_exhaust_pa <= 1.05e5 else 1.05e5 + (cb.p_exhaust_pa - 1.05e5) * min(max(load, 0.0), 1.2)
    return cb.p_ivc_pa * f, cb.p_intake_pa * f, p_exh


def cycle_params(spec: EngineSpec, omega: float, fuel_kg: float, load: float = 1.0, soc_deg: float | None = None,
                 premixed_fraction: float | None = None, leak_area_m2: float = 0.0) -> np.ndarray:
    """Per-cycle parameter vector of the kernel (defaults from ``spec.combustion``); omega [rad/s], fuel [kg]."""
    cb = spec.combustion
    q = np.zeros(_NCYC)
    q[_Q] = cb.combustion_efficiency * fuel_kg * cb.lhv_j_per_kg
    q[_SOC] = np.radians(cb.start_deg if soc_deg is None else soc_deg)
    q[_BETA] = cb.premixed_fraction if premixed_fraction is None else premixed_fraction
    q[_LEAK] = leak_area_m2
    q[_OMEGA] = omega
    q[_PIVC], q[_PINT], q[_PEXH] = charge_pressures(spec, load)
    return q


def cylinder_pressure(model: CylinderModel, params: np.ndarray) -> tuple[np.ndarray, float]:
    """One cycle's absolute pressure [Pa] on ``model.theta`` and the fraction of trapped mass lost by blow-by.

    params : ``cycle_params(...)`` vector [Q_in J, SOC rad, beta_p, leak area m^2, omega rad/s, p_IVC, p_int, p_exh Pa].
    """
    q = np.ascontiguousarray(params, dtype=np.float64)
    if q.shape != (_NCYC,):
        raise ValueError(f"params must be cycle_params(...) ({_NCYC} values), got shape {q.shape}")
    if not (q[_OMEGA] > 0 and q[_PIVC] > 0 and q[_Q] >= 0 and q[_LEAK] >= 0 and 0 <= q[_BETA] <= 1):
        raise ValueError("need omega > 0, p_IVC > 0, Q_in >= 0, leak area >= 0 and 0 <= beta_p <= 1")
    out = np.empty(model.theta.shape[0])
    lost = cycle_pressure_kernel(model.vol_half, model.dvol_half, model.constants, q, out)
    return out, float(lost)


def indicated_work(model: CylinderModel, pressure: np.ndarray, p_cc: float = P_CRANKCASE) -> float:
    """Net indicated work of one cycle [J]: the trapezoid of (p - p_cc) dV/dtheta over the 720 deg grid."""
    f = (pressure - p_cc) * model.dvol
    return float(model.step * (f.sum() - 0.5 * (f[0] + f[-1])))


def imep(model: CylinderModel, pressure: np.ndarray) -> float:
    """Net IMEP [Pa] of one trace (whole cycle, pumping included)."""
    return indicated_work(model, pressure) / float(model.constants[_VD])
