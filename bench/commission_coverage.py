"""Issue 25 checks for `commission`: a hidden sensor error (wheel TDC, one channel's gain or pegging) on a simulated
log; the log is commissioned and analysed with the model it wrote. Per case: the wheel TDC found against the truth,
the engine friction against the truth and its sigma, before (bare preset) and after.

    python -m bench.commission_coverage [--cycles 150] [--engines k9k-4cyl,genset-v20] [--gain-sigma 0.005]

Not a test: minutes of CPU.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

from frictionwatch.core.model.engine_model import load_model
from frictionwatch.service.cli import main as cli
from frictionwatch.service.pipeline import analyze_log

POINTS = {"k9k-4cyl": (2000.0, 0.8), "maruti-3cyl": (2500.0, 0.6), "deutz-1cyl": (1400.0, 0.6),
          "genset-v20": (1500.0, 0.6)}
EFFECTS = [(f"tdc_offset:deg={d},cylinder=0", d) for d in (0.6, -0.6, 1.5, -1.5)] + [
    ("pressure_gain:cylinder=2,gain=1.06", 0.0), ("pressure_offset:cylinder=2,pa=50000", 0.0)]


def run_case(engine: str, effect: str, wheel_deg: float, cycles: int, seed: int, gain_sigma: float | None,
             tmp: Path) -> dict:
    rpm, load = POINTS[engine]
    if load_model(engine).spec.n_cyl == 1:  # a channel error on the only cylinder
        effect = effect.replace("cylinder=2", "cylinder=1")
    log, model = tmp / "log.mcap", tmp / "model.toml"
    if cli(["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load), "--cycles", str(cycles), "--seed",
            str(seed), "--effect", effect, "-o", str(log)]) != 0:
        raise RuntimeError("simulate failed")
    args = ["commission", str(log), "-o", str(model), "--json"]
    if gain_sigma is not None:
        args += ["--gain-sigma", str(gain_sigma)]
    if cli(args) != 0:
        raise RuntimeError("commission failed")
    truth = json.loads((tmp / "log.truth.json").read_text())["friction_torque_mean_nm"]
    found = [e for e in load_model(str(model)).effects if e.name == "tdc_offset" and e.values["cylinder"] == 0][0]
    bare = analyze_log(log).results[-1].smoothed
    done = analyze_log(log, engine=str(model)).results[-1].smoothed
    return {"engine": engine, "effect": effect, "wheel_true_deg": wheel_deg, "wheel_found_deg": found.values["deg"],
            "wheel_sigma_deg": found.sigma["deg"], "truth_nm": truth,
            "bare_err_pct": 100 * (bare.total_friction_torque / truth - 1),
            "bare_z": (bare.total_friction_torque - truth) / bare.total_friction_torque_sigma,
            "err_pct": 100 * (done.total_friction_torque / truth - 1),
            "sigma_pct": 100 * done.total_friction_torque_sigma / truth,
            "z": (done.total_friction_torque - truth) / done.total_friction_torque_sigma}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cycles", type=int, default=150)
    ap.add_argument("--seed", type=int, default=9)
    ap.add_argument("--engines", default=",".join(POINTS))
    ap.add_argument("--gain-sigma", type=float, default=None)
    a = ap.parse_args(argv)
    print(f"{'engine':<12} {'effect':<38} {'wheel true':>10} {'found':>7} {'±1σ':>6} {'bare err%':>9} {'z':>6} "
          f"{'comm. err%':>10} {'σ %':>6} {'z':>6}")
    for engine in a.engines.split(","):
        for effect, wheel in EFFECTS:
            t0 = time.perf_counter()
            with tempfile.TemporaryDirectory() as tmp:
                r = run_case(engine, effect, wheel, a.cycles, a.seed, a.gain_sigma, Path(tmp))
            print(f"{engine:<12} {effect:<38} {wheel:+10.2f} {r['wheel_found_deg']:+7.3f} {r['wheel_sigma_deg']:6.3f} "
                  f"{r['bare_err_pct']:+9.1f} {r['bare_z']:+6.2f} {r['err_pct']:+10.1f} {r['sigma_pct']:6.1f} "
                  f"{r['z']:+6.2f}  ({time.perf_counter() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
