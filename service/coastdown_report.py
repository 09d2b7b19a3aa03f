"""`analyze` on a run whose speed changes: inertia J and friction against speed (core.monitor.balance.mean_balance), and a word
on friction figures the monitor withheld. Wiring and units only; the numbers come from core."""

from __future__ import annotations

import numpy as np
from frictionwatch.core.monitor.balance.mean_balance import LOAD_STEP_FRACTION, mid_cycle_inertia, transient_friction
from frictionwatch.core.monitor.calibration.inertia import INERTIA_UNCALIBRATED_REL
from frictionwatch.service.pipeline import LogAnalysis

RPM_PER_RAD_S = 30.0 / np.pi
SPEED_POINTS = 4  # friction reported at this many speeds across the range the run covered


def transient_section(analysis: LogAnalysis) -> dict | None:
    """The "transient" block of ``analyze --json``: None when the run's speed hardly changed (or too few
    consecutive cycles)."""
    res = analysis.results
    if len(res) < 2:
        return None
    spec = analysis.spec

    def col(name: str) -> np.ndarray:
        return np.array([getattr(r, name) for r in res], dtype=np.float64)

    j_spec = mid_cycle_inertia(spec)
    tf = transient_friction(np.array([r.index for r in res]), col("omega_mean"), col("acceleration"),
                            col("indicated_window"), col("load_torque"), col("coupling_loss"),
                            j_spec, LOAD_STEP_FRACTION * spec.rated_torque_nm,
                            inertia_prior_std=INERTIA_UNCALIBRATED_REL * j_spec)
    if tf is None:
        return None
    lo, hi = float(tf.speed.min()), float(tf.speed.max())
    # a constant (3 cycles) stands for the mean speed only
    speeds = np.linspace(lo, hi, SPEED_POINTS) if tf.fit.friction_coeffs.shape[0] > 1 else np.array([tf.speed.mean()])
    fric, sig = tf.friction_at(speeds)
    c0, c1 = (float(v) for v in np.append(tf.fit.friction_coeffs, 0.0)[:2])  # a constant from 3 rows: c1 = 0
    # without a load reading the resisting torque is friction plus whatever load there was: the data cannot tell
    # (TU/e: the ENGINEOFF coast-downs read the friction, E5FULLOAD4EngineOff twice that with its generator on)
    label = "friction" if tf.load_measured else "friction + any load (no load measured)"
    centred = [r for r in res if "no_previous_cycle" not in r.flags]
    low = min(spec.speed_range_rpm[0] / RPM_PER_RAD_S, lo)  # the engine's lowest speed, or the run's if lower
    negative = tf.negative_friction(low)
    checks = [] if negative is None else [{
        "check": "negative_friction",
        "reason": (f"the law gives {negative[1]:.2f} ± {negative[2]:.2f} N m at {negative[0] * RPM_PER_RAD_S:.0f} rpm"
                   + (f" (negative below {-c0 / c1 * RPM_PER_RAD_S:.0f} rpm)" if c0 < 0 < c1 else "")
                   + ": friction cannot be negative; the rows hold a torque the balance does not (a load connected "
                   "without a reading, a wrong J), so this is not the engine's friction"),
    }]
    return {
        "cycles": int(tf.speed.shape[0]),
        "rows": "motored cycles" if tf.motored else "all consecutive cycles",
        "inertia_kgm2": tf.inertia,
        # the spec's J is uncalibrated: its assumed sigma is in every friction sigma below (friction = T_i - J a)
        "inertia_sigma_kgm2": tf.inertia_std,
        "inertia_source": "identified (torque step)" if tf.inertia_identified else "engine spec (not resolved by the "
                          f"run: no torque step at one speed; uncalibrated, ±{100 * INERTIA_UNCALIBRATED_REL:.0f} % "
                          "assumed)",
        "inertia_spec_kgm2": j_spec,
        "inertia_mismatch": bool(tf.inertia_identified and abs(tf.inertia - j_spec) > 2.0 * tf.inertia_std),
        "friction_label": label,
        "speed_range_rpm": [lo * RPM_PER_RAD_S, hi * RPM_PER_RAD_S],
        "friction_c0_nm": c0,
        "friction_c1_nm_per_rpm": c1 / RPM_PER_RAD_S if tf.fit.friction_coeffs.shape[0] > 1 else None,
        "friction_vs_speed": [{"rpm": float(w * RPM_PER_RAD_S), "friction_nm": float(f), "sigma_nm": float(s)}
                              for w, f, s in zip(speeds, fric, sig, strict=True)],
        "residual_rms_nm": tf.fit.residual_rms,
        "checks": checks,
        "imep_bar_centred": (float(np.mean([r.imep.mean() for r in centred])) / 1e5) if centred else None,
    }


def add_to(doc: dict, analysis: LogAnalysis) -> None:
    """Adds the "transient" block (or None) to ``analyze``'s JSON document."""
    doc["transient"] = transient_section(analysis)


def print_lines(doc: dict) -> None:
    """Printed under ``analyze``'s table: the transient block (why a figure is not measured is the table's own
    status line, core.monitor.report.figure_status)."""
    t = doc.get("transient")
    if not t:
        return
    print(f"speed transient ({t['cycles']} {t['rows']}, {t['speed_range_rpm'][0]:.0f}-{t['speed_range_rpm'][1]:.0f}"
          f" rpm): J = {t['inertia_kgm2']:.4f} ± {t['inertia_sigma_kgm2']:.4f} kg m², {t['inertia_source']}")
    if t["inertia_mismatch"]:
        print(f"  the engine spec's J = {t['inertia_spec_kgm2']:.4f} kg m² is off the identified one: the monitor's "
              "per-cycle balance in this run is biased by the difference times dw/dt")
    slope = t["friction_c1_nm_per_rpm"]
    law = f"{t['friction_c0_nm']:.3f}" + (f" + {slope * 1e3:.4f}e-3·rpm" if slope is not None else " (constant: 3 cycles)")
    bad = t.get("checks") or []
    print(("NOT PHYSICAL: " if bad else "") + f"{t['friction_label']} = {law} N m:")
    for c in bad:
        print(f"  {c['check']}: {c['reason']}")
    print("  " + ", ".join(f"{p['rpm']:.0f} rpm {p['friction_nm']:.3f} ± {p['sigma_nm']:.3f}"
                           for p in t["friction_vs_speed"]) + " N m")
