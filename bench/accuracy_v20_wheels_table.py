"""Issue 29's first check, per cylinder, from a bench.accuracy_v20_wheels run: at its last checkpoint (or
``--cycles``) each cylinder measured or a share, its error, sigma (whole and without the calibration's part), within
5 %, within 2 sigma, and the first checkpoint from which it stayed measured, beside the information analysis's
prediction (bench/results/information_v20.json: cycles for sigma <= 2.5 %, data only and with the sibling prior).

    python -m bench.accuracy_v20_wheels_table bench/results/accuracy_v20_wheels_check.json [--variant joint] [--cycles N]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

INFORMATION = Path(__file__).parent / "results" / "information_v20.json"
PREDICTION = {"joint": "load +-20 %, two wheels", "one_wheel": "load +-20 %, flywheel"}


def measured_since(checkpoints: list[dict], variant: str, cyl: int) -> int | None:
    """The cycles of the first checkpoint from which cylinder ``cyl`` (1-based) stayed measured to the last one."""
    since = None
    for cp in checkpoints:
        if cyl in cp[variant]["measured_cylinders"]:
            since = cp["cycles"] if since is None else since
        else:
            since = None
    return since


def table(doc: dict, variant: str, cycles: int | None) -> str:
    cps = [cp for i, cp in enumerate(doc["checkpoints"]) if variant in cp and (cycles is None or cp["cycles"] <= cycles)
           and (i == 0 or cp["cycles"] != doc["checkpoints"][i - 1]["cycles"])]  # the end repeats a last checkpoint
    last = cps[-1][variant]
    info = json.loads(INFORMATION.read_text())["configurations"][PREDICTION[variant.removesuffix("_bare")]]
    model = "the bare engine file" if variant.endswith("_bare") else doc.get("model", "the bare engine file")
    lines = [f"{variant} at {cps[-1]['cycles']} cycles (seed {doc['seed']}, model {model})",
             "| cyl | predicted N (siblings) | stayed measured from | status | error % | sigma % | sigma w/o cal % "
             "| within 5 % | within 2 sigma w/o cal |", "|" + "---|" * 9]
    n5 = n2 = n_both = n_both_cal = 0
    for k in range(len(last["err_pct"])):
        meas = (k + 1) in last["measured_cylinders"]
        err, sig, sig0 = last["err_pct"][k], last["sigma_pct"][k], last["sigma_without_calibration_pct"][k]
        w5, w2 = abs(err) <= 5.0, abs(err) <= 2.0 * sig0
        n5 += meas and w5
        n2 += meas and w2
        n_both += meas and w5 and w2
        n_both_cal += meas and w5 and abs(err) <= 2.0 * sig
        since = measured_since(cps, variant, k + 1)
        lines.append(f"| {k + 1} | {info['cycles_needed'][k]:,} ({info['cycles_needed_with_siblings'][k]:,}) | "
                     f"{'-' if since is None else f'{since:,}'} | {'measured' if meas else 'share'} | "
                     f"{f'{err:+.1f}' if meas else '-'} | "
                     f"{sig:.1f} | {sig0:.1f} | {'yes' if w5 else 'no'} | {'yes' if w2 else 'NO' if meas else 'no'} |")
    lines.append(f"measured {len(last['measured_cylinders'])}; of them within 5 % {n5}, within 2 sigma without the "
                 f"calibration {n2}, both {n_both} (with the whole sigma: {n_both_cal})")
    lines.append("every checkpoint, measured (within 5 % and 2 sigma without the calibration): " + ", ".join(
        f"{cp['cycles'] // 1000}k{'*' if on_ramp(doc, cp) else ''} {m} ({ok})" for cp in cps
        for m, ok in [counts(cp[variant])]) + " (* the load moved within the truth's window: a ramp)")
    outside = [(cp["cycles"], k + 1, cp[variant]["err_pct"][k], cp[variant]["sigma_without_calibration_pct"][k])
               for cp in cps for k in [c - 1 for c in cp[variant]["measured_cylinders"]]
               if abs(cp[variant]["err_pct"][k]) > 2.0 * cp[variant]["sigma_without_calibration_pct"][k]]
    n_meas = sum(len(cp[variant]["measured_cylinders"]) for cp in cps)
    lines.append(f"measured figures outside 2 sigma without the calibration, every checkpoint: {len(outside)} of "
                 f"{n_meas}" + "".join(f"; cyl {k} at {c:,}: {e:+.1f} on {s:.1f}" for c, k, e, s in outside))
    return "\n".join(lines)


def on_ramp(doc: dict, cp: dict) -> bool:
    """Whether a load step fell within the checkpoint's truth window (its last ``truth_window`` cycles at 80 ms)."""
    t1 = (cp["cycle_index"] + 1) * 120.0 / doc["rpm"]
    t0 = t1 - doc["truth_window"] * 120.0 / doc["rpm"]
    return any(t0 < ts <= t1 for ts, _ in doc["load_steps"])


def counts(r: dict) -> tuple[int, int]:
    """(measured, of them within 5 % and within 2 sigma without the calibration's part) of one checkpoint."""
    ok = [k for k in (c - 1 for c in r["measured_cylinders"])
          if abs(r["err_pct"][k]) <= 5.0 and abs(r["err_pct"][k]) <= 2.0 * r["sigma_without_calibration_pct"][k]]
    return len(r["measured_cylinders"]), len(ok)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("json")
    ap.add_argument("--variant", default="joint")
    ap.add_argument("--cycles", type=int, default=None, help="the last checkpoint at or below this many cycles")
    args = ap.parse_args()
    print(table(json.loads(Path(args.json).read_text()), args.variant, args.cycles))


if __name__ == "__main__":
    main()
