"""J and friction against speed from the TU/e coast-downs (core.monitor.calibration.inertia), per record and pooled,
and the same on simulated coast-downs whose plant J differs from the preset's.

    python -m bench.inertia_from_coastdowns [--realdata ../shared/realdata] [--gain-rel-std 0.0]

Real records are read as `import-daq` reads them (TDC 244.5 deg, 12.4 bar/V). Figures, not pass/fail: the checks
are tests/realdata/test_tue_inertia.py and tests/core/test_inertia_calibration.py.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import load_engine
from frictionwatch.core.model.engine_model import EngineModel, load_model
from frictionwatch.core.monitor.balance.coastdown import fit_inertia_friction
from frictionwatch.core.monitor.calibration.inertia import (
    InertiaCalibration,
    coastdown_record,
    commission_inertia,
    record_inertia,
)
from frictionwatch.core.plant.simulate import simulate
from frictionwatch.drivers.daq.raw import TUE_GAIN_PA_PER_V, TUE_TDC_DEG, daq_to_records
from frictionwatch.service.pipeline import assembled_cycles

FOLDER = "tue-4gb10-si-encoder-pressure"
POOL = [f"group14_ENGINEOFF{i}" for i in range(2, 7)]
RPM = np.pi / 30.0


def _law(cal: InertiaCalibration) -> str:
    c = cal.friction.friction_coeffs
    sd = np.sqrt(np.diag(cal.friction.covariance))[1:1 + c.shape[0]]
    terms = [f"({c[0]:.3f} ± {sd[0]:.3f})"] + [f"({c[k] * (RPM * 1e3) ** k:.3f} ± "
                                                  f"{sd[k] * (RPM * 1e3) ** k:.3f})e-{3 * k}·rpm^{k}"
                                                  for k in range(1, c.shape[0])]
    return " + ".join(terms) + " N m"


def _print_pool(title: str, cal: InertiaCalibration) -> None:
    print(f"\n{title}")
    print(f"{'record':30s} {'rpm':>11s} {'cycles':>6s} {'J [kg m2]':>9s} {'1σ':>8s} {'shaped':>8s} "
          "J per half order 0.5 / 1.5 / 2.5")
    for p in cal.records:
        lo, hi = p.speed_range
        print(f"{p.name:30s} {lo / RPM:5.0f}-{hi / RPM:<5.0f} {p.fit.per_cycle.shape[0]:6d} {p.inertia:9.5f} "
              f"{p.inertia_std:8.5f} {p.shaped:8.5f} " + " / ".join(f"{j:.4f}" for j in p.order_inertia[:3]))
    print(f"pooled ripple J {cal.ripple_inertia:.5f} ± {cal.ripple_std:.5f} (between records {cal.between_std:.5f}, "
          f"speed trend {cal.speed_systematic:.5f}, friction shape {cal.shape_systematic:.6f}, order spread "
          f"{cal.order_systematic:.5f} not in σ)")
    mb = cal.mean_balance
    if mb is not None:
        print(f"mean balance (J free, friction c0 + c1 W): J {mb.inertia:.5f} ± {cal.mean_std:.5f}, "
              f"{100 * cal.mean_weight:.0f} % of the information, {'used' if cal.mean_used else 'not used'}")
    print(f"J = {cal.inertia:.5f} ± {cal.inertia_std:.5f} kg m² (gain systematic {cal.gain_systematic:.5f})")
    print(f"friction = {_law(cal)}; records' spread about it {cal.friction_between_std:.3f} N m; offsets "
          + ", ".join(f"{o:+.3f}" for o in cal.record_offsets))
    speeds = np.array([1200.0, 1800.0, 2400.0])
    f, s = cal.friction_at(speeds * RPM)
    print("  " + ", ".join(f"{r:.0f} rpm {a:.3f} ± {b:.3f}" for r, a, b in zip(speeds, f, s, strict=True)) + " N m")


def real(folder: Path, gain_rel_std: float) -> None:
    model = load_model("tue-4gb10")
    cycles = {}
    for name in POOL + ["group14_ENGINEOFF", "group14_E0FULLOAD4EngineOff", "group14_E5FULLOAD4EngineOff"]:
        info, recs = daq_to_records(folder / f"{name}.txt.gz", tdc_deg=TUE_TDC_DEG, gain_pa_per_v=TUE_GAIN_PA_PER_V)
        cycles[name], _ = assembled_cycles(model, info, recs)
    records = {n: coastdown_record(n, c, model) for n, c in cycles.items()}
    print(f"TU/e 4GB10, TDC {TUE_TDC_DEG} deg, gain {TUE_GAIN_PA_PER_V / 1e5} bar/V; preset J "
          f"{model.spec.total_inertia} kg m²")
    _print_pool("ENGINEOFF2-6 pooled", commission_inertia([records[n] for n in POOL], gain_rel_std=gain_rel_std))
    stepped = coastdown_record("group14_E0FULLOAD4EngineOff", cycles["group14_E0FULLOAD4EngineOff"], model,
                               motored_only=False, load_group=0)
    _print_pool("ENGINEOFF2-6 + E0FULLOAD4EngineOff (ignition-off torque step, generator on: its own d0 + d1 W)",
                commission_inertia([records[n] for n in POOL] + [stepped], gain_rel_std=gain_rel_std))
    one = records["group14_ENGINEOFF"]
    p = record_inertia(one)
    print(f"\nENGINEOFF (1): {len(cycles['group14_ENGINEOFF'])} cycles, {len(one.rows)} motored, "
          f"{len(one.balance)} mean-balance row(s); ripple J {p.inertia:.5f} ± {p.inertia_std:.5f}")
    e5 = records["group14_E5FULLOAD4EngineOff"]
    p = record_inertia(e5)
    print(f"E5FULLOAD4EngineOff (generator on, ignition off): ripple J {p.inertia:.5f} ± {p.inertia_std:.5f} "
          f"({len(e5.rows)} cycles; its resisting torque is friction + generator load)")
    step = coastdown_record("E0FULLOAD4EngineOff", cycles["group14_E0FULLOAD4EngineOff"], model, motored_only=False)
    a = np.array([b.acceleration(model.spec.total_inertia) for b in step.balance])
    w, y = (np.array([getattr(b, k) for b in step.balance]) for k in ("omega", "gas_mean"))
    fit = fit_inertia_friction(a, w, y)
    print(f"E0FULLOAD4EngineOff torque step (mean balance, {a.shape[0]} rows, friction + load c0 + c1 W): "
          f"J {fit.inertia:.5f} ± {fit.inertia_std:.5f}")


def simulated() -> None:
    print("\nsimulated, load 0.6, coast_down (tue-4gb10 3000 rpm 24 cycles cut at 0.4 s, deutz-1cyl 2400 rpm 30 cycles "
          "cut at 0.3 s); the estimate never sees the plant's J")
    print(f"{'engine':>10s} {'plant J':>8s} {'seed':>4s} {'J':>8s} {'1σ':>8s} {'error':>7s} {'error/σ':>7s}  "
          "friction law")
    for engine, scale, seed in (("tue-4gb10", 1.0, 3), ("tue-4gb10", 1.12, 3), ("tue-4gb10", 0.9, 4),
                                ("tue-4gb10", 1.25, 5), ("deutz-1cyl", 1.1, 3)):
        spec = load_engine(engine)
        rpm, cycles_n, cut = (3000.0, 24, 0.4) if engine == "tue-4gb10" else (2400.0, 30, 0.3)
        plant = dataclasses.replace(spec, node_inertia=spec.node_inertia * scale)
        sim = simulate(plant, rpm, load=0.6, cycles=cycles_n, seed=seed, effects={"coast_down": {"time_s": cut}})
        cycles, _ = assembled_cycles(spec, sim.info, sim.records)
        cal = commission_inertia([coastdown_record("sim", cycles, EngineModel.from_spec(spec))])
        j = plant.total_inertia
        print(f"{engine:>10s} {j:8.5f} {seed:4d} {cal.inertia:8.5f} {cal.inertia_std:8.5f} {100 * (cal.inertia / j - 1):+6.2f}% "
              f"{(cal.inertia - j) / cal.inertia_std:+7.2f}  {_law(cal)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--realdata", type=Path, default=Path(__file__).resolve().parents[1].parent / "shared" / "realdata")
    ap.add_argument("--gain-rel-std", type=float, default=0.0, help="the pressure gain's relative 1σ, into J's σ")
    args = ap.parse_args()
    if (args.realdata / FOLDER).is_dir():
        real(args.realdata / FOLDER, args.gain_rel_std)
    else:
        print(f"{args.realdata / FOLDER} absent: real records skipped")
    simulated()


if __name__ == "__main__":
    main()
