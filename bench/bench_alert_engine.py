"""The alert engine's CPU per cycle (issue 28 item 7, design notes 72, 73): ``AlertEngine.update`` replayed on kept
runs (``bench.ring_condition --save``) or on synthetic cycles, as the branch has it and as a commit had it
(service/alert*.py and the core module the rules call most, core/monitor/checks/ring_condition.py, read from git; the
rest of the tree as it is now), alternating in one process, and whether the two give the same alerts and pressure
statistics.

    python -m bench.bench_alert_engine /tmp/v20_s7_h.pkl [more.pkl ...] --base 7f2dc33 --repeat 5
    python -m bench.bench_alert_engine synthetic --engine genset-v20 --base 7f2dc33
    python -m bench.bench_alert_engine /tmp/v20_s7_h.pkl --profile

Each pass makes a fresh engine (the run's baseline) and folds every cycle; CPU is ``time.process_time`` per cycle,
the figure per variant the smallest over ``--repeat`` alternating passes (the box is shared: the ratio of the two
minima is the figure, docs/quiet-bench.md). "same": every event (kind, alert id, cylinder, kind, severity, state,
cycle, message, evidence) equal, and every cycle's pressure statistics (z_leak, effect, z_ratio, the EWMA, var,
var_ratio, the long-run factors) and ring-condition figure equal within rtol 1e-12 (NaN where NaN).
"""

from __future__ import annotations

import argparse
import atexit
import importlib.util
import json
import os
import pickle
import shutil
import subprocess
import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np
from frictionwatch.service.alerts import AlertConfig, AlertEngine

ROOT = Path(__file__).resolve().parent.parent
MODULES = ("alert_config", "alert_baseline", "alert_interface", "alert_rules", "alert_ring_rule", "alerts")
# core modules taken from the commit too (dotted name under frictionwatch.): the rules' friction excess and ring figure
CORE_MODULES = ("core.monitor.checks.ring_condition",)


def _git_show(commit: str, path: str) -> str:
    return subprocess.run(["git", "show", f"{commit}:{path}"], cwd=ROOT, check=True, capture_output=True,
                          text=True).stdout


def base_engine_class(commit: str) -> type:
    """``AlertEngine`` as at ``commit``: every service/alert*.py module and each of ``CORE_MODULES`` read from git
    under its own name (the core ones from a file in a temporary folder: their numba kernels cache beside a file)."""
    prefix = f"_base_{commit[:10]}_"
    folder = Path(tempfile.mkdtemp(prefix=f"bench_alert_engine_{commit[:10]}_"))
    atexit.register(shutil.rmtree, folder, True)
    renames = {}
    for dotted in CORE_MODULES:
        name = prefix + dotted.replace(".", "_")
        path = folder / f"{name}.py"
        path.write_text(_git_show(commit, dotted.replace(".", "/") + ".py"))
        spec = importlib.util.spec_from_file_location(name, path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[name] = mod
        spec.loader.exec_module(mod)
        renames[f"frictionwatch.{dotted}"] = name
    for other in MODULES:
        renames[f"frictionwatch.service.{other}"] = prefix + other
    for name in MODULES:
        src = _git_show(commit, f"service/{name}.py")
        for old, new in renames.items():
            src = src.replace(f"{old} ", f"{new} ").replace(f"{old}\n", f"{new}\n")
        mod = types.ModuleType(prefix + name)
        mod.__dict__["__file__"] = str(ROOT / "service" / f"{name}.py")  # alert_config reads its json beside it
        sys.modules[prefix + name] = mod
        exec(compile(src, f"{commit}:service/{name}.py", "exec"), mod.__dict__)  # noqa: S102 - our own history
    return sys.modules[prefix + "alerts"].AlertEngine


def synthetic_run(engine: str, n: int, seed: int, friction: bool = False) -> dict:
    """A run of synthetic cycles (tests.service.test_alert_long_run's: AR(1) indicators about healthy offsets, no
    friction figure) with a leak ramping into cylinder 2 from cycle n/2 and a load step at 3n/4; no baseline.
    ``friction``: every cylinder's friction measured from cycle 100 on (5 N m, 1 % scatter, sigma 0.05 N m), and
    cylinder 4's rising by 10 % from cycle n/3 over 200 cycles (a worn ring)."""
    from frictionwatch.core.model.engine import load_engine

    from tests.service.test_alert_long_run import _ar1, _cycle

    spec = load_engine(engine)
    z = spec.n_cyl
    rng = np.random.default_rng(seed)
    sd = np.array([0.0012, 0.0013, 0.0022, 0.0012])
    offset = rng.standard_normal((4, z)) * 0.001
    x = offset + _ar1(rng, 0.5, n, (4, z)) * np.sqrt(1.0 - 0.25) * sd[:, None]
    ramp = np.clip((np.arange(n) - n // 2) / 200.0, 0.0, 1.0)
    x[:, 1, 1] -= 0.006 * ramp
    x[:, 2, 1] += 0.006 * ramp
    results = []
    for i in range(n):
        c = _cycle(i, x[i], z)
        if i >= 3 * n // 4:
            c.imep = np.full(z, 6e5)
        if friction and i >= 100:
            t = 5.0 * (1.0 + 0.01 * rng.standard_normal(z))
            t[3] *= 1.0 + 0.1 * min(max((i - n // 3) / 200.0, 0.0), 1.0)
            c.smoothed = c.cycle = types.SimpleNamespace(**{**vars(c.cycle), "resolved": np.ones(z, bool),
                                                            "friction_torque_mean": t,
                                                            "friction_torque_mean_sigma": np.full(z, 0.05)})
        results.append(c)
    return {"spec": spec, "baseline": None, "results": results, "effects": [f"synthetic seed {seed}"]}


def fold(cls: type, run: dict, trace: bool) -> tuple[float, list, list]:
    """CPU seconds for one pass, its events and (``trace``) each cycle's pressure statistics and ring figure."""
    config = AlertConfig(skip_cycles=0) if run["baseline"] is None else AlertConfig()
    engine = cls(run["spec"], config, run["baseline"])
    stats: list = []
    if trace:
        original = engine._pressure
        ring = next(r for stage in engine.rules for r in stage if r.name == "ring_condition")

        def seen(result, flags):
            p = original(result, flags)
            stats.append(None if p is None or p.stats is None else
                         np.concatenate([p.stats.z_leak, p.stats.effect, p.stats.z_ratio, p.ewma.ravel(),
                                         [p.var, p.var_ratio, *p.long_run]]))
            return p

        engine._pressure = seen
    events = []
    t0 = time.process_time()
    for res in run["results"]:
        for e in engine.update(res):
            a = e.alert
            events.append((e.kind, a.alert_id, a.cylinder, a.kind, a.severity, a.state, a.raised_cycle,
                           a.cleared_cycle, a.message, json.dumps(a.evidence, sort_keys=True, default=float)))
        if trace and ring.last is not None:
            rc = ring.last
            stats.append(np.concatenate([rc.figure, rc.sigma, rc.since, rc.since_sigma, rc.siblings,
                                         rc.siblings_sigma]))
    return time.process_time() - t0, events, stats


def same(a: tuple, b: tuple) -> bool:
    """Whether two traced passes agree: the events exactly, every figure within rtol 1e-12 (NaN where NaN)."""
    if a[1] != b[1] or len(a[2]) != len(b[2]):
        return False
    for x, y in zip(a[2], b[2], strict=True):
        if (x is None) != (y is None):
            return False
        if x is not None and not np.allclose(x, y, rtol=1e-12, atol=0.0, equal_nan=True):
            return False
    return True


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.bench_alert_engine", description=__doc__.split("\n\n")[0])
    ap.add_argument("runs", nargs="+", help="kept runs (.pkl), 'synthetic' or 'synthetic-friction'")
    ap.add_argument("--base", help="a commit: its service/alert*.py is the 'before'")
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--engine", default="genset-v20", help="synthetic runs' engine")
    ap.add_argument("--cycles", type=int, default=1600, help="synthetic runs' cycles")
    ap.add_argument("--profile", action="store_true", help="cProfile one pass of the branch instead")
    args = ap.parse_args(argv)
    variants = {"branch": AlertEngine}
    if args.base:
        variants = {"base": base_engine_class(args.base), **variants}
    out = {"uptime": os.getloadavg(), "base": args.base, "runs": {}}
    for path in args.runs:
        if path in ("synthetic", "synthetic-friction"):
            run = synthetic_run(args.engine, args.cycles, 72, path == "synthetic-friction")
        else:
            with open(path, "rb") as fh:
                run = pickle.load(fh)
        if args.profile:
            import cProfile
            import pstats

            fold(AlertEngine, run, False)
            pr = cProfile.Profile()
            pr.enable()
            fold(AlertEngine, run, False)
            pr.disable()
            pstats.Stats(pr).sort_stats("tottime").print_stats(40)
            continue
        traced = {name: fold(cls, run, True) for name, cls in variants.items()}  # also the numba warm-up
        cpu: dict[str, list[float]] = {name: [] for name in variants}
        for _ in range(args.repeat):
            for name, cls in variants.items():
                cpu[name].append(fold(cls, run, False)[0] / len(run["results"]) * 1e6)
        row = {"cycles": len(run["results"]), "n_cyl": run["spec"].n_cyl, "events": len(traced["branch"][1]),
               "us_per_cycle_min": {k: round(min(v), 1) for k, v in cpu.items()},
               "us_per_cycle_all": {k: [round(x) for x in v] for k, v in cpu.items()}}
        if args.base:
            row["ratio_branch_over_base"] = round(min(cpu["branch"]) / min(cpu["base"]), 3)
            row["same"] = same(traced["base"], traced["branch"])
        out["runs"][path] = row
    out["uptime_end"] = os.getloadavg()
    print(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
