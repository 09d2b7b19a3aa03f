"""How far the alerts' standard errors are from the truth on a healthy engine (issue 29 item 3, design note 71): an
accuracy run, not a test; the figures go into the work's report.

    python -m bench.ring_condition healthy --engine k9k-4cyl --seed 11 --step-every 500 --save /tmp/k9k_s11.pkl
    python -m bench.alert_autocorrelation factors /tmp/k9k_s11.pkl [more.pkl ...]
    python -m bench.alert_autocorrelation replay /tmp/k9k_s11.pkl --cylinder 0

The runs are the cycle results ``bench.ring_condition --save`` kept (the monitor's output and the baseline the run
started from); the alerts are replayed on them alone, so one simulated run serves every variant of the alert engine.

factors: the per-cycle series the pressure alerts fold (service.alerts.AlertEngine: each used cycle's indicators
less its load band's mean), each cylinder's less the median over the cylinders (the sibling reference, three or
more cylinders), as the three figures the rules read: the leak signature (LeakRule, standardised by the band's
covariance), the compression ratio (GainRule) and the leak effect (RingConditionRule's "since" change); and the ring
condition's sibling-window input (each cylinder's leak effect less its siblings' median, less its own run mean: a
healthy offset is the allowance's, not noise). Per series the long-run-variance factor: the variance of a window's
mean (or of the alerts' EWMA) over what independent cycles would give -- from the autocorrelation (the pooled lags
summed with the EWMA's weights) and from non-overlapping batch means of contiguous cycles. Each cylinder's figure is
centred on its mean over its load band (the band mean's own error is not the cycles'); a lag product or a batch
spans only contiguous used cycles (none across a hold: a settle, a learning band, an unusable cycle).

replay: the alerts on the kept results as they are now (the healthy cylinders' largest z per statistic: leak,
compression ratio, ring condition since / against siblings; ring alerts; the first alert on ``--cylinder``), or as at
the commit ``--base`` (service/alerts.py and alert_interface.py from git) for the same-run comparison.
"""

from __future__ import annotations

import argparse
import json
import pickle
import sys

import numpy as np
from frictionwatch.service.alerts import RING_KINDS, AlertEngine

LAGS = 400


def load(path: str) -> dict:
    with open(path, "rb") as fh:
        return pickle.load(fh)


def pressure_series(run: dict, args_contiguous: bool = False) -> dict:
    """Replays the alert engine on a kept run: per used cycle (the pressure statistics had a value) its cycle index,
    the indicators' change from the band's mean u (4, z), the band's sd (4, z) and cov (z, 4, 4), and a segment id
    (a new one at every hold, band change or gap); and per cycle the ring rule's leak effect (z,) and whether the
    sibling window took it. ``args_contiguous``: a segment runs on through holds (the used cycles in the order the
    alerts' EWMA folds them) and ends only at a band change."""
    engine = AlertEngine(run["spec"], baseline=run["baseline"])
    rows: dict = {"cycle": [], "u": [], "sd": [], "cov": [], "segment": [], "band": [], "effect": [], "effect_used": []}
    seg, last_key = 0, None
    original = engine._pressure

    def recording(result, cyl_flags):  # the engine's own statistics, seen from outside
        nonlocal seg, last_key
        p = original(result, cyl_flags)
        if p is None or p.held is not None or p.band is None:
            if not args_contiguous:
                last_key = None
            return p
        key = (p.band.first_cycle, p.band.last_cycle)
        if key != last_key:
            seg += 1
            last_key = key
        rows["cycle"].append(int(result.index))
        rows["u"].append(result.ring.compared() - p.band.mean)
        rows["sd"].append(p.band.sd)
        rows["cov"].append(p.band.cov)
        rows["segment"].append(seg)
        rows["band"].append(p.band.first_cycle)
        return p

    engine._pressure = recording
    for res in run["results"]:
        engine.update(res)
        ring = res.ring
        if ring is not None:
            rows["effect"].append(0.5 * (np.asarray(ring.n_expansion_dev) - np.asarray(ring.n_compression_dev)))
            rows["effect_used"].append("operating_point_changed" not in res.flags
                                       and not any(f.startswith("misfire") for f in res.flags))
    return {k: np.array(v) for k, v in rows.items()}


def figures(s: dict) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The per-cycle figures (T, z) with their segment and band ids (T,) (the leak signature and the compression
    ratio standardised by the band's spread, as the rules read them)."""
    u = s["u"]
    z = u.shape[2]
    d = u - np.median(u, axis=2, keepdims=True) if z >= 3 else u
    sd = s["sd"]
    w1, w2 = -1.0 / sd[:, 1], 1.0 / sd[:, 2]
    leak_sig = (w1 * d[:, 1] + w2 * d[:, 2]) / np.sqrt(2.0)
    seg, band = s["segment"], s["band"]
    out = {"leak_signature": (leak_sig, seg, band),
           "compression_ratio": (d[:, 0] / np.maximum(sd[:, 0], 1e-12), seg, band),
           "leak_effect_change": (0.5 * (d[:, 2] - d[:, 1]), seg, band)}
    e = s["effect"][s["effect_used"]]
    if e.shape[1] >= 3:
        others = np.stack([np.median(np.delete(e, k, axis=1), axis=1) for k in range(e.shape[1])], axis=1)
        sib = e - others
        zero = np.zeros(len(sib), dtype=int)
        out["sibling_window_input"] = (sib - sib.mean(axis=0), zero, zero)
    return out


def _centred(x: np.ndarray, band: np.ndarray) -> np.ndarray:
    """Each cylinder's figure less its mean over its band's cycles (the band mean's own error is not the cycles')."""
    out = np.empty_like(x)
    for b in np.unique(band):
        out[band == b] = x[band == b] - x[band == b].mean(axis=0)
    return out


def acf(x: np.ndarray, segment: np.ndarray, band: np.ndarray, lags: int) -> np.ndarray:
    """(lags + 1,) autocorrelation pooled over the cylinders and the segments (each cylinder centred on its band's
    mean; lag products only within a segment of contiguous used cycles)."""
    x = _centred(x, band)
    num, den = np.zeros(lags + 1), np.zeros(lags + 1)
    for sg in np.unique(segment):
        xs = x[segment == sg]
        for k in range(min(lags, len(xs) - 1) + 1):
            num[k] += np.sum(xs[k:] * xs[:len(xs) - k])
            den[k] += xs[k:].size
    gamma = np.where(den > 0, num / np.maximum(den, 1), np.nan)
    return gamma / gamma[0]


def ewma_factor(rho: np.ndarray, window: float) -> float:
    """The variance of a fixed-factor EWMA (g = 1 / window) over the independent cycles' g / (2 - g), from the
    autocorrelation: 1 + 2 sum_k rho_k (1 - g)^k (lags without data count 0)."""
    g = 1.0 / window
    k = np.arange(1, len(rho))
    r = np.nan_to_num(rho[1:])
    return float(1.0 + 2.0 * np.sum(r * (1.0 - g) ** k))


def batch_factor(x: np.ndarray, segment: np.ndarray, band: np.ndarray, b: int) -> float:
    """Non-overlapping batch means of ``b`` contiguous cycles: their mean square times b over the per-cycle one
    (each cylinder centred on its band's mean)."""
    x = _centred(x, band)
    means = [xs[:len(xs) // b * b].reshape(len(xs) // b, b, -1).mean(axis=1)
             for xs in (x[segment == sg] for sg in np.unique(segment)) if len(xs) >= b]
    if not means:
        return float("nan")
    return float(b * np.mean(np.concatenate(means) ** 2) / np.mean(x ** 2))


def factors(args: argparse.Namespace) -> dict:
    out = {}
    for path in args.runs:
        run = load(path)
        s = pressure_series(run, args.through_holds)
        res = {"through_holds": args.through_holds, "cycles": len(run["results"]), "used": int(len(s["cycle"])),
               "segments": int(len(np.unique(s["segment"]))), "effects": run["effects"]}
        for name, (x, seg, band) in figures(s).items():
            rho = acf(x, seg, band, args.lags)
            res[name] = {"rho_1_2_5_10_20_50": [round(float(rho[k]), 3) for k in (1, 2, 5, 10, 20, 50)
                                               if k < len(rho)],
                         "ewma50": round(ewma_factor(rho[:args.lags + 1], 50.0), 2),
                         "ewma200": round(ewma_factor(rho[:args.lags + 1], 200.0), 2),
                         "batch30": round(batch_factor(x, seg, band, 30), 2),
                         "batch50": round(batch_factor(x, seg, band, 50), 2),
                         "batch100": round(batch_factor(x, seg, band, 100), 2),
                         "segment_cycles_median": int(np.median(np.unique(seg, return_counts=True)[1]))}
        out[path] = res
    return out


def base_engine_class(commit: str) -> type:
    """``AlertEngine`` as it was at ``commit`` (service/alerts.py and service/alert_interface.py read from git, the
    rest of the tree as it is now): the same-run "before" of a replay."""
    import subprocess
    import types
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    mods = {}
    for name in ("alert_interface", "alerts"):
        src = subprocess.run(["git", "show", f"{commit}:service/{name}.py"], cwd=root, check=True,
                             capture_output=True, text=True).stdout
        src = src.replace("frictionwatch.service.alert_interface", "_base_alert_interface")
        mod = types.ModuleType(f"_base_{name}")
        mod.__dict__["__name__"] = f"_base_{name}"
        sys.modules[f"_base_{name}"] = mod
        exec(compile(src, f"{commit}:service/{name}.py", "exec"), mod.__dict__)  # noqa: S102 - our own history
        mods[name] = mod
    return mods["alerts"].AlertEngine


def replay(args: argparse.Namespace) -> dict:
    """The alerts replayed on a kept run: now, or as at ``--base`` (a commit)."""
    run = load(args.runs[0])
    cls = base_engine_class(args.base) if args.base else AlertEngine
    engine = cls(run["spec"], baseline=run["baseline"])
    z = run["spec"].n_cyl
    top = {"leak": np.full(z, -np.inf), "ratio": np.full(z, -np.inf), "ring_since": np.full(z, -np.inf),
           "ring_siblings": np.full(z, -np.inf)}
    raised, factor = [], []
    rule = next(r for stage in engine.rules for r in stage if r.name == "ring_condition")
    original = engine._pressure

    def seen(result, flags):
        p = original(result, flags)
        if p is not None and p.stats is not None:
            top["leak"] = np.fmax(top["leak"], p.stats.z_leak)
            top["ratio"] = np.fmax(top["ratio"], np.abs(p.stats.z_ratio))
            factor.append(getattr(p, "long_run", (1.0, 1.0)))
        return p

    engine._pressure = seen
    onset = next((int(e.split("from_cycle=")[1].split(",")[0]) for e in run["effects"] if "from_cycle=" in e), None)
    for res in run["results"]:
        raised += [{"cycle": int(res.index), "kind": e.alert.kind, "cylinder": e.alert.cylinder, "rule": e.alert.rule}
                   for e in engine.update(res) if e.kind == "raised"]
        rc = rule.last
        if rc is not None and (onset is None or args.cylinder == 0):
            with np.errstate(invalid="ignore", divide="ignore"):
                top["ring_since"] = np.fmax(top["ring_since"], rc.since / rc.since_sigma)
                top["ring_siblings"] = np.fmax(top["ring_siblings"], rc.siblings / rc.siblings_sigma)
        elif rc is not None:  # a faulty run: the healthy cylinders' figures only
            with np.errstate(invalid="ignore", divide="ignore"):
                healthy = np.arange(z) != args.cylinder - 1
                top["ring_since"] = np.where(healthy, np.fmax(top["ring_since"], rc.since / rc.since_sigma), np.nan)
                top["ring_siblings"] = np.where(healthy, np.fmax(top["ring_siblings"], rc.siblings / rc.siblings_sigma),
                                                np.nan)
    first = next((r for r in raised if r["kind"] in RING_KINDS and r["cylinder"] == args.cylinder), None)
    fac = np.array(factor) if factor else np.full((1, 2), np.nan)
    healthy = [k for k in range(z) if k != args.cylinder - 1]
    return {"run": args.runs[0], "base": args.base, "effects": run["effects"], "cycles": len(run["results"]),
            "ring_alerts": [r for r in raised if r["kind"] in RING_KINDS][:10],
            "other_alerts": [r for r in raised if r["kind"] not in RING_KINDS][:6],
            "first_on_cylinder": first, "delay": None if first is None or onset is None else first["cycle"] - onset,
            "wrong_cylinder": [r for r in raised if r["kind"] in RING_KINDS and r["cylinder"] != args.cylinder][:6],
            "long_run_end": [round(float(v), 2) for v in fac[-1]],
            "long_run_max": [round(float(v), 2) for v in np.max(fac, axis=0)],
            "largest_healthy_z": {k: round(float(np.nanmax(v[healthy])), 2) if np.any(np.isfinite(v[healthy]))
                                  else None for k, v in top.items()}}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="bench.alert_autocorrelation", description=__doc__.split("\n\n")[0])
    sub = ap.add_subparsers(dest="mode", required=True)
    p = sub.add_parser("factors")
    p.add_argument("runs", nargs="+")
    p.add_argument("--lags", type=int, default=LAGS)
    p.add_argument("--through-holds", action="store_true", help="lag products across holds within a band (the "
                   "used cycles as the EWMA folds them); default: only across contiguous cycles")
    p = sub.add_parser("replay")
    p.add_argument("runs", nargs=1)
    p.add_argument("--cylinder", type=int, default=0, help="the faulty cylinder (1-based; 0: a healthy run)")
    p.add_argument("--base", default="", help="a commit: the alert engine as it was there (the same-run before)")
    args = ap.parse_args(argv)
    out = factors(args) if args.mode == "factors" else replay(args)
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
