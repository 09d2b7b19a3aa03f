"""Is commissioning's stated sigma honest, what limits it, and does a motored stretch help (issue 29's calibration
floor, issue 25's commissioning; design note 163).

    python -m bench.commission_sigma z [--engines k9k-4cyl,genset-v20] [--seeds 201-212] [--cycles 200]
    python -m bench.commission_sigma cycles [--engines ...] [--seeds 221] [--counts 200,600,2000]
    python -m bench.commission_sigma motored [--engines ...] [--seeds 231,232]
    python -m bench.commission_sigma z --coast --seeds 241-250 --section z_coast

Every case simulates a log with hidden sensor errors drawn from the seed (the wheel's TDC, one cylinder's own TDC, each
uniform in +-0.5 deg; one channel's gain uniform in 0.97..1.03), runs the product's `commission` on it
(service.cmd_commission.commission, the pipeline and the commissioning as the CLI runs them) and compares what the
commissioned model corrects with the truth, in units of the sigma it states:

- wheel: (wheel found - wheel true) / the wheel's sigma;
- each cylinder's own TDC: (its correction beyond the wheel - its true own offset, less the wheel's error) over the
  calibration's per-cylinder sigma (``tdc_cylinder_sigma_deg``, what every friction sigma carries) and over the
  cylinder's own stated sigma (the effect's sigma where applied, the reading and its statistical sigma where kept);
- each channel's gain: (true gain / corrected gain - 1) over the calibration's per-channel ``gain_sigma`` and over the
  channel's own sigma in the report. The gain common to every channel is a stated input (none here; the simulator has
  no common gain error), not tested.

``cycles``: the same engine and point, no hidden error, commissioned on its first 200, 600, 2000 cycles: the sigma's
parts (tdc.py: statistical, systematic, heat loss, constant loss; the gains' standard error and sibling spread).
``motored``: a log that coasts down (the ``coast_down`` effect) after fired cycles, with hidden TDC errors: the fired
and the motored TDCs each against the truth, with their sigma parts.

Seeds: 71 and 83 are note 159's and used nowhere here; 201-212 the z table, 221-222 the cycles, 231-232 the motored
runs; nothing is tuned on any of them. Writes bench/results/commission_sigma.json (one section per mode, merged).
Not a test: minutes of CPU.
"""

from __future__ import annotations

import os

for _v in ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_v, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
from frictionwatch.core.model.engine_model import load_model  # noqa: E402
from frictionwatch.service.cli import main as cli  # noqa: E402
from frictionwatch.service.cmd_commission import commission  # noqa: E402

OUT = Path(__file__).parent / "results" / "commission_sigma.json"
POINTS = {"k9k-4cyl": (2000.0, 0.8), "genset-v20": (1500.0, 0.75)}
TDC_RANGE_DEG = 0.5
GAIN_RANGE = 0.03
# (fired cycles before the coast-down, motored cycles after it): k9k loses ~36 rpm a cycle coasting (2000 -> ~1000
# rpm over 30), genset-v20 ~3 (1500 -> ~1150 over 120)
COAST = {"k9k-4cyl": (60, 30), "genset-v20": (100, 120)}


def hidden_errors(engine: str, seed: int) -> dict:
    """The hidden sensor errors of a case, drawn from its seed (wheel and one cylinder's own TDC, one channel's gain)."""
    z = load_model(engine).spec.n_cyl
    rng = np.random.default_rng([163, seed])
    return {"wheel_deg": round(float(rng.uniform(-TDC_RANGE_DEG, TDC_RANGE_DEG)), 3),
            "tdc_cylinder": int(rng.integers(1, z + 1)),
            "tdc_cylinder_deg": round(float(rng.uniform(-TDC_RANGE_DEG, TDC_RANGE_DEG)), 3),
            "gain_cylinder": int(rng.integers(1, z + 1)),
            "gain": round(float(rng.uniform(1.0 - GAIN_RANGE, 1.0 + GAIN_RANGE)), 4)}


def simulate(engine: str, seed: int, cycles: int, hidden: dict | None, log: Path, coast_s: float | None = None) -> None:
    rpm, load = POINTS[engine]
    args = ["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load), "--cycles", str(cycles),
            "--seed", str(seed), "-o", str(log)]
    if hidden:
        args += ["--effect", f"tdc_offset:cylinder=0,deg={hidden['wheel_deg']}",
                 "--effect", f"tdc_offset:cylinder={hidden['tdc_cylinder']},deg={hidden['tdc_cylinder_deg']}",
                 "--effect", f"pressure_gain:cylinder={hidden['gain_cylinder']},gain={hidden['gain']}"]
    if coast_s is not None:
        args += ["--effect", f"coast_down:time_s={coast_s}"]
    if cli(args) != 0:
        raise RuntimeError("simulate failed")


def truth_arrays(z: int, hidden: dict | None) -> tuple[float, np.ndarray, np.ndarray]:
    """(wheel deg, each cylinder's own TDC offset deg (z,), each channel's gain (z,))."""
    own, gain = np.zeros(z), np.ones(z)
    if hidden:
        own[hidden["tdc_cylinder"] - 1] = hidden["tdc_cylinder_deg"]
        gain[hidden["gain_cylinder"] - 1] = hidden["gain"]
    return (hidden or {}).get("wheel_deg", 0.0), own, gain


def judged(report: dict, model_path: Path, hidden: dict | None) -> dict:
    """What the commissioned model corrects against the truth, in its stated sigmas (module doc)."""
    model = load_model(str(model_path))
    z = model.spec.n_cyl
    wheel_true, own_true, gain_true = truth_arrays(z, hidden)
    cal = model.calibration
    own_applied, own_sigma, gain_applied = np.zeros(z), np.full(z, np.nan), np.ones(z)
    wheel = wheel_sigma = 0.0
    for e in model.effects:
        k = int(e.values.get("cylinder", 0))
        if e.name == "tdc_offset" and k == 0:
            wheel, wheel_sigma = e.values["deg"], e.sigma["deg"]
        elif e.name == "tdc_offset":
            own_applied[k - 1], own_sigma[k - 1] = e.values["deg"], e.sigma["deg"]
        elif e.name == "pressure_gain":
            gain_applied[k - 1] = e.values["gain"]
    # a cylinder whose reading was left (no effect) has no sigma of its own in the model: the calibration's
    # per-cylinder sigma is what carries it (its own z stays NaN)
    wheel_err = wheel - wheel_true
    own_err = own_applied - own_true  # the cylinder's correction beyond the wheel's, against its truth
    gain_res = gain_true / gain_applied - 1.0
    rows = report["cylinders"]
    gain_own_sigma = np.array([r.get("gain_sigma", cal.gain_sigma) for r in rows])
    # what every friction sigma carries: each cylinder's own calibration sigma (design note 170), and the one rms
    # over the cylinders it carried before (the calibration's summary scalars)
    own_cal_deg, gain_cal = np.sqrt(cal.own_variances(z))
    own_cal_deg = np.degrees(own_cal_deg)
    fired = [r["tdc_fired"] for r in rows]
    parts = {k: [f["sigma_parts_deg"][k] for f in fired if f] for k in ("statistical_deg", "systematic_deg",
                                                                        "heat_loss_deg", "constant_loss_deg")}
    return {
        "hidden": hidden, "cycles_fired": report["cycles_fired"], "cycles_motored": report["cycles_motored"],
        "wheel_found_deg": wheel, "wheel_sigma_deg": wheel_sigma, "wheel_err_deg": round(wheel_err, 4),
        "z_wheel": round(wheel_err / wheel_sigma, 3),
        "tdc_cylinder_sigma_deg": cal.tdc_cylinder_sigma_deg, "tdc_cylinder_sigmas_deg": own_cal_deg.round(4).tolist(),
        "own_applied_deg": own_applied.round(4).tolist(), "own_err_deg": own_err.round(4).tolist(),
        "own_sigma_deg": own_sigma.round(4).tolist(),
        "z_own_calibration": (own_err / own_cal_deg).round(3).tolist(),
        "z_own_rms": (own_err / cal.tdc_cylinder_sigma_deg).round(3).tolist(),
        "z_own_stated": (own_err / own_sigma).round(3).tolist(),
        "z_tdc_total": ((own_err + wheel_err) / np.hypot(wheel_sigma, own_cal_deg)).round(3).tolist(),
        "gain_sigma": cal.gain_sigma, "gain_common_sigma": cal.gain_common_sigma,
        "gain_applied": gain_applied.round(5).tolist(), "gain_residual": gain_res.round(5).tolist(),
        "gain_own_sigma": gain_own_sigma.round(5).tolist(),
        "z_gain_calibration": (gain_res / gain_cal).round(3).tolist(),
        "z_gain_rms": (gain_res / cal.gain_sigma).round(3).tolist(),
        "z_gain_stated": (gain_res / gain_own_sigma).round(3).tolist(),
        "sibling_gain_spread": report.get("sibling_gain_spread"),
        "tdc_sigma_parts_median_deg": {k: round(float(np.median(v)), 4) for k, v in parts.items() if v},
    }


def run_case(engine: str, seed: int, cycles: int, hidden: dict | None, max_cycles: int | None = None,
             coast_s: float | None = None) -> tuple[dict, dict]:
    with tempfile.TemporaryDirectory() as tmp:
        log, model = Path(tmp) / "log.mcap", Path(tmp) / "model.toml"
        t0 = time.perf_counter()
        simulate(engine, seed, cycles, hidden, log, coast_s)
        t1 = time.perf_counter()
        result, report = commission([log], None, None, max_cycles or cycles)
        model.write_text(result.model.to_toml(), encoding="utf-8")
        out = judged(report, model, hidden)
        out.update({"engine": engine, "seed": seed, "cycles": cycles, "simulate_s": round(t1 - t0, 1),
                    "commission_s": round(time.perf_counter() - t1, 1)})
        return out, report


def share_within(values: list[float], limit: float = 2.0) -> str:
    a = np.abs(np.asarray(values, dtype=np.float64))
    a = a[np.isfinite(a)]
    return f"{int(np.sum(a <= limit))}/{a.size}"


def restated(rows: list[dict]) -> list[dict]:
    """The rows with ``z_own_stated`` NaN where no own offset was applied (rows written before the bench left a
    kept cylinder's own z out: it had divided by the reading and its statistical sigma, which the model does not
    state)."""
    out = []
    for r in rows:
        applied = np.asarray(r["own_applied_deg"]) != 0.0
        z = np.where(applied, np.asarray(r["own_err_deg"]) / np.asarray(r["own_sigma_deg"], dtype=np.float64), np.nan)
        out.append({**r, "z_own_stated": z.tolist()})
    return out


def summary(rows: list[dict]) -> dict:
    """Per parameter: |z| <= 2 counts, the rms z, the largest |z| (the hidden cylinder and channel apart)."""
    out = {}
    for engine in sorted({r["engine"] for r in rows}):
        rs = [r for r in rows if r["engine"] == engine]
        cols = {"wheel": [r["z_wheel"] for r in rs]}
        for label, key, hidden in (("own TDC", "z_own", "tdc_cylinder"), ("gain", "z_gain", "gain_cylinder")):
            hid = [(r, r["hidden"][hidden] - 1) for r in rs]
            item = "cylinder" if label == "own TDC" else "channel"
            for which, suffix in (("calibration sigma", "_calibration"), ("own stated sigma", "_stated"),
                                  ("calibration's rms sigma", "_rms")):
                if not all(key + suffix in r for r in rs):  # rows written before note 170 have no rms column
                    continue
                cols[f"{label}, hidden {item} ({which})"] = [r[key + suffix][k] for r, k in hid]
                cols[f"{label}, other {item}s ({which})"] = [z for r, k in hid for i, z in enumerate(r[key + suffix])
                                                            if i != k]
            if label == "own TDC":
                cols["TDC total per cylinder"] = [z for r in rs for z in r["z_tdc_total"]]
        cols = {name: np.asarray(v, dtype=np.float64)[np.isfinite(np.asarray(v, dtype=np.float64))]
                for name, v in cols.items()}
        out[engine] = {name: {"within_2": share_within(v),
                              "rms_z": round(float(np.sqrt(np.mean(np.square(v)))), 3) if v.size else None,
                              "max_abs_z": round(float(np.max(np.abs(v))), 3) if v.size else None}
                       for name, v in cols.items()}
        out[engine]["stated"] = {
            "wheel_sigma_deg_median": float(np.median([r["wheel_sigma_deg"] for r in rs])),
            "tdc_cylinder_sigma_deg_median": float(np.median([r["tdc_cylinder_sigma_deg"] for r in rs])),
            "gain_sigma_median": float(np.median([r["gain_sigma"] for r in rs])),
            "wheel_err_deg_rms": round(float(np.sqrt(np.mean([r["wheel_err_deg"] ** 2 for r in rs]))), 4),
            "own_err_deg_rms_all": round(float(np.sqrt(np.mean([e ** 2 for r in rs for e in r["own_err_deg"]]))), 4),
            "gain_residual_rms_all": round(float(np.sqrt(np.mean([g ** 2 for r in rs for g in r["gain_residual"]]))),
                                           5)}
    return out


def motored_part(report: dict, hidden: dict | None, z: int) -> dict:
    """The fired and the motored TDCs of a coast-down log against the truth (the wheel's and each cylinder's)."""
    wheel_true, own_true, _ = truth_arrays(z, hidden)
    out = {}
    for kind in ("tdc_fired", "tdc_motored"):
        est = [r[kind] for r in report["cylinders"]]
        if not all(est):
            out[kind] = None
            continue
        off = np.array([e["offset_deg"] for e in est])
        sig = np.array([e["sigma_deg"] for e in est])
        err = off - (wheel_true + own_true)
        wheel = float(np.median(off))
        parts = {k: round(float(np.median([e["sigma_parts_deg"][k] for e in est])), 4)
                 for k in ("statistical_deg", "systematic_deg", "heat_loss_deg", "constant_loss_deg")}
        out[kind] = {"cycles": est[0]["cycles"], "wheel_deg": round(wheel, 4), "wheel_err_deg": round(wheel - wheel_true, 4),
                     "wheel_sigma_deg": round(float(np.median(sig)), 4), "err_deg": err.round(4).tolist(),
                     "err_rms_deg": round(float(np.sqrt(np.mean(err ** 2))), 4),
                     "own_err_rms_deg": round(float(np.sqrt(np.mean((err - np.median(err)) ** 2))), 4),
                     "sigma_parts_median_deg": parts}
    return out


def seeds_of(text: str) -> list[int]:
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def save(section: str, value) -> None:
    doc = json.loads(OUT.read_text()) if OUT.exists() else {}
    doc[section] = value
    OUT.write_text(json.dumps(doc, indent=1) + "\n")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("mode", choices=("z", "cycles", "motored", "table"))
    ap.add_argument("--engines", default=",".join(POINTS))
    ap.add_argument("--seeds", default=None)
    ap.add_argument("--cycles", type=int, default=200)
    ap.add_argument("--counts", default="200,600,2000")
    ap.add_argument("--section", default=None, help="the JSON section to write (default: the mode)")
    ap.add_argument("--coast", action="store_true", help="z: each log coasts down after its fired cycles (COAST)")
    a = ap.parse_args(argv)
    engines = a.engines.split(",")
    rows = []
    if a.mode == "table":  # the z tables of every z section written, from the cases (summary recomputed)
        doc = json.loads(OUT.read_text())
        for section in [k for k in doc if k.startswith("z")]:
            doc[section]["summary"] = summary(restated(doc[section]["cases"]))
            doc[section]["cases"] = restated(doc[section]["cases"])
            for engine, cols in doc[section]["summary"].items():
                print(f"[{section}] {engine}: " + "; ".join(
                    f"{name} {c['within_2']} (rms {c['rms_z']}, max {c['max_abs_z']})" for name, c in cols.items()
                    if name != "stated") + f"; stated {cols['stated']}")
        OUT.write_text(json.dumps(doc, indent=1) + "\n")
        return 0
    if a.mode == "z":
        for engine in engines:
            fired, coasting = COAST[engine] if a.coast else (a.cycles, 0)
            for seed in seeds_of(a.seeds or "201-212"):
                r, _ = run_case(engine, seed, fired + coasting, hidden_errors(engine, seed),
                                coast_s=fired * 120.0 / POINTS[engine][0] if a.coast else None)
                rows.append(r)
                h = r["hidden"]
                k, j = h["tdc_cylinder"] - 1, h["gain_cylinder"] - 1
                print(f"{engine} s{seed}: wheel {h['wheel_deg']:+.3f} found {r['wheel_found_deg']:+.3f}±"
                      f"{r['wheel_sigma_deg']:.3f} z {r['z_wheel']:+.2f} | cyl {k + 1} {h['tdc_cylinder_deg']:+.3f} "
                      f"applied {r['own_applied_deg'][k]:+.3f} z {r['z_own_calibration'][k]:+.2f}/"
                      f"{r['z_own_stated'][k]:+.2f} | gain ch {j + 1} {h['gain']:.4f} applied "
                      f"{r['gain_applied'][j]:.4f} z {r['z_gain_calibration'][j]:+.2f}/{r['z_gain_stated'][j]:+.2f} "
                      f"| others own |z|max {np.max(np.abs(np.delete(r['z_own_calibration'], k))):.2f} gain |z|max "
                      f"{np.max(np.abs(np.delete(r['z_gain_calibration'], j))):.2f} ({r['simulate_s']}+"
                      f"{r['commission_s']} s)", flush=True)
        doc = {"cases": rows, "summary": summary(rows)}
        print(json.dumps(doc["summary"], indent=1))
    elif a.mode == "cycles":
        counts = [int(c) for c in a.counts.split(",")]
        for engine in engines:
            for seed in seeds_of(a.seeds or "221"):
                for n in counts:
                    r, _ = run_case(engine, seed, n, None)
                    rows.append(r)
                    print(f"{engine} s{seed} {n} cycles: wheel {r['wheel_found_deg']:+.3f}±{r['wheel_sigma_deg']:.3f}"
                          f" cyl sigma {r['tdc_cylinder_sigma_deg']:.3f} gain sigma {r['gain_sigma']:.4f} spread "
                          f"{r['sibling_gain_spread']:.4f} parts {r['tdc_sigma_parts_median_deg']} "
                          f"({r['simulate_s']}+{r['commission_s']} s)", flush=True)
        doc = {"cases": rows}
    else:
        for engine in engines:
            rpm = POINTS[engine][0]
            fired, coasting = COAST[engine]
            coast_s = fired * 120.0 / rpm
            for seed in seeds_of(a.seeds or "231,232"):
                hidden = hidden_errors(engine, seed)
                r, report = run_case(engine, seed, fired + coasting, hidden, coast_s=coast_s)
                r["motored"] = motored_part(report, hidden, len(report["cylinders"]))
                rows.append(r)
                for kind, m in r["motored"].items():
                    if m:
                        print(f"{engine} s{seed} {kind} ({m['cycles']} cycles): wheel err {m['wheel_err_deg']:+.3f} "
                              f"sigma {m['wheel_sigma_deg']:.3f}, rms err {m['err_rms_deg']:.3f}, own rms "
                              f"{m['own_err_rms_deg']:.3f}, parts {m['sigma_parts_median_deg']}", flush=True)
        doc = {"cases": rows, "coast": COAST}
    save(a.section or a.mode, doc)
    print(f"wrote {OUT} [{a.section or a.mode}]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
