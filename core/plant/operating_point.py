"""Quasi-static operating-point estimates for the plant simulator (thermo trace + friction at constant speed).

They only *start* the simulation near its equilibrium; the time-domain plant then finds the real one.

Load fraction L (0 = zero brake torque, "idle-synchronised"; 1 = full load): fuel per cylinder per cycle
    m_f(L) = m_0 + L (m_full - m_0),
with m_0 the fuel at which indicated torque equals friction at this speed (charge pressures at L = 0) and m_full the
preset's ``fuel_mass_kg``; p_IVC, p_int, p_exh follow ``thermo.charge_pressures``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from frictionwatch.core.model.engine import EngineSpec
from frictionwatch.core.model.terms import TermLibrary, cylinder_samples, rezeka_henein
from frictionwatch.core.model.thermo import P_CRANKCASE, CylinderModel, cycle_params, cylinder_pressure, indicated_work

FOUR_PI = 4.0 * np.pi


@dataclass(frozen=True)
class CylinderMeans:
    """Cycle means of one cylinder at constant speed: indicated torque, friction torque and basis means [N m, -]."""

    indicated_nm: float
    friction_nm: float
    basis_mean: np.ndarray  # (L,) angle mean of the loss terms F_l over the cycle
    pmax_pa: float


def cylinder_means(spec: EngineSpec, model: CylinderModel, omega: float, fuel_kg: float, load: float,
                   coef: np.ndarray, leak_m2: float = 0.0, misfire_probability: float = 0.0,
                   library: TermLibrary | None = None) -> CylinderMeans:
    """Expected cycle means of one cylinder (a misfiring cycle is a motored one, weighted by its probability);
    coef (L,) the coefficients of ``library``'s terms (default the six Rezeka-Henein terms)."""
    lib = rezeka_henein() if library is None else library
    consts = spec.friction_params()
    out = []
    for fuel, weight in ((fuel_kg, 1.0 - misfire_probability), (0.0, misfire_probability)):
        if weight <= 0.0:
            continue
        p, _ = cylinder_pressure(model, cycle_params(spec, omega, fuel, load, leak_area_m2=leak_m2))
        basis = lib.evaluate(cylinder_samples(model.theta, omega, p - P_CRANKCASE, consts), consts)
        fmean = basis[:, :-1].mean(axis=1)  # uniform grid, last point = first point of the next cycle
        out.append((weight, indicated_work(model, p) / FOUR_PI, float(coef @ fmean), fmean, p.max()))
    w = sum(o[0] for o in out)
    return CylinderMeans(
        indicated_nm=sum(o[0] * o[1] for o in out) / w,
        friction_nm=sum(o[0] * o[2] for o in out) / w,
        basis_mean=sum(o[0] * o[3] for o in out) / w,
        pmax_pa=max(o[4] for o in out),
    )


def engine_brake_torque(spec: EngineSpec, model: CylinderModel, omega: float, fuel: np.ndarray, load: float,
                        coef: np.ndarray, leak: np.ndarray, misfire: np.ndarray, extra_nm: np.ndarray,
                        library: TermLibrary | None = None) -> tuple[float, list[CylinderMeans]]:
    """Sum over cylinders of (indicated - friction - extra) [N m] and the per-cylinder means.

    fuel (z,) kg per cycle (spread included); coef (z, L) of ``library``'s terms; leak (z,) m^2; misfire (z,) probability; extra (z,) N m.
    """
    cache: dict[tuple, CylinderMeans] = {}
    means = []
    for k in range(spec.n_cyl):
        key = (round(float(fuel[k]), 15), tuple(coef[k]), float(leak[k]), float(misfire[k]))
        if key not in cache:
            cache[key] = cylinder_means(spec, model, omega, float(fuel[k]), load, coef[k], float(leak[k]),
                                        float(misfire[k]), library)
        means.append(cache[key])
    total = sum(m.indicated_nm - m.friction_nm for m in means) - float(np.sum(extra_nm))
    return total, means


def idle_fuel(spec: EngineSpec, model: CylinderModel, omega: float, spread: np.ndarray, coef: np.ndarray,
              leak: np.ndarray, misfire: np.ndarray, extra_nm: np.ndarray, library: TermLibrary | None = None) -> float:
    """Nominal fuel m_0 [kg] at which the brake torque is zero at load 0 (secant on the near-linear IMEP(m_f));
    coef (z, L) of ``library``'s terms (default the six Rezeka-Henein terms)."""
    def brake(m: float) -> float:
        return engine_brake_torque(spec, model, omega, m * spread, 0.0, coef, leak, misfire, extra_nm, library)[0]

    m1 = spec.combustion.fuel_mass_kg
    b0, b1 = brake(0.0), brake(m1)
    if b1 <= b0:
        raise ValueError(f"{spec.name}: fuel does not raise the indicated torque at {omega * 30 / np.pi:.0f} rpm")
    m0 = max(0.0, -b0 * m1 / (b1 - b0))
    for _ in range(2):
        bm = brake(m0)
        if abs(bm) < 1e-3 * abs(b1 - b0) or m0 == 0.0:
            break
        m0 = max(0.0, m0 - bm * m1 / (b1 - b0))
    return m0


def fuel_for_load(m0: float, spec: EngineSpec, load: float) -> float:
    """m_f(L) = m_0 + L (m_full - m_0) [kg per cylinder per cycle]."""
    return m0 + load * (spec.combustion.fuel_mass_kg - m0)


def leak_area_for_loss(spec: EngineSpec, model: CylinderModel, omega: float, fuel_kg: float, load: float,
                       mass_loss: float) -> float:
    """Effective blow-by orifice area [m^2] that loses ``mass_loss`` of the trapped mass between IVC and EVO."""
    if mass_loss <= 0.0:
        return 0.0
    area = 1e-6 * (spec.bore / 0.08) ** 2
    for _ in range(8):
        _, lost = cylinder_pressure(model, cycle_params(spec, omega, fuel_kg, load, leak_area_m2=area))
        if lost <= 0.0:
            area *= 10.0
            continue
        ratio = mass_loss / lost
        area *= ratio ** 1.1 if ratio > 1 else ratio
        if abs(ratio - 1.0) < 1e-4:
            break
    return area


def variability_sensitivity(spec: EngineSpec, model: CylinderModel, omega: float, fuel_kg: float, load: float
                            ) -> tuple[float, float, float]:
    """(IMEP [Pa], dIMEP/dln(Q) [Pa], dIMEP/dSOC [Pa/deg]) of a nominal cylinder, by central differences."""
    def imep_of(fuel: float, soc: float) -> float:
        p, _ = cylinder_pressure(model, cycle_params(spec, omega, fuel, load, soc_deg=soc))
        return indicated_work(model, p) / spec.displacement_cyl

    soc0 = spec.combustion.start_deg
    base = imep_of(fuel_kg, soc0)
    d_q = (imep_of(fuel_kg * 1.05, soc0) - imep_of(fuel_kg * 0.95, soc0)) / 0.1
    d_soc = (imep_of(fuel_kg, soc0 + 1.0) - imep_of(fuel_kg, soc0 - 1.0)) / 2.0
    return base, d_q, d_soc


def sized_transfers(spec: EngineSpec, model: CylinderModel, omega: float, fuel: np.ndarray, load: float,
                    coef: np.ndarray, transfers: tuple[tuple[str, str, float], ...], library: TermLibrary
                    ) -> np.ndarray:
    """Coefficients (z, L) with each (base, new, fraction) of ``transfers`` applied: ``fraction`` of the base term's
    mean friction at this operating point moved into the new term's shape, same mean there (per cylinder)."""
    out = np.array(coef, dtype=np.float64)
    if not transfers:
        return out
    z = spec.n_cyl
    _, means = engine_brake_torque(spec, model, omega, fuel, load, out, np.zeros(z), np.zeros(z), np.zeros(z),
                                   library)
    for base, new, fraction in transfers:
        i, j = library.index(base), library.index(new)
        for k in range(z):
            moved = fraction * out[k, i] * means[k].basis_mean[i]
            if moved > 0.0 and means[k].basis_mean[j] > 0.0:
                out[k, j] += moved / means[k].basis_mean[j]
                out[k, i] *= 1.0 - fraction
    return out
