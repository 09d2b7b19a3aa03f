"""`frictionwatch trace FILE`: what a real-engine recording the monitor cannot run on does and does not measure.

The monitor needs the crank-wheel timing and the pressure of every cylinder (a replay log, `import-daq`). Bench
exports often hold less; this command reads them, prints the figures they do carry and says in words what they
cannot give, rather than refusing them or inventing the rest:

- ``.csv``  crank-angle pressure table of one cylinder (PoliTo: ``crank_angle_deg, p_cyl1_bar``): IMEP, peak pressure;
- ``.xlsx`` time table with pressure volts, a gapless encoder and a TDC marker (AUTH): the same per cycle, and speed
  (TDC convention: drivers/daq/angle_traces.py);
- ``.mf4``  J1939 bus log (CSS CANedge): engine speed from EEC1 only.

With the bench's brake torque (``--brake-torque-nm``) IMEP - BMEP is printed, labelled as resting on the measured
cylinder standing for all of them. No friction figure comes from the speed: none of these files allows one.
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np
from frictionwatch.core.model.engine import EngineSpec, load_engine
from frictionwatch.core.model.indicated import net_imep, peak_pressure
from frictionwatch.drivers.daq.angle_traces import PressureCycles, read_angle_csv, read_encoder_table
from frictionwatch.drivers.logs.mdf4 import j1939_engine_speed, read_can_frames

FORMATS = {".csv": "angle-csv", ".xlsx": "encoder-xlsx", ".mf4": "j1939-mdf4", ".mdf": "j1939-mdf4"}


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("trace", help="read a bench export the monitor cannot run on (pressure-angle CSV, encoder "
                                     "xlsx, J1939 MDF4) and say what it measures")
    p.add_argument("file", type=Path, help=".csv (crank angle, pressure), .xlsx (time, volts, encoder, TDC marker) "
                                           "or .mf4 (J1939 bus log)")
    p.add_argument("--engine", help="engine preset or TOML file (the geometry behind IMEP); needed for pressure files")
    p.add_argument("--gain-bar-per-v", type=float, help="pressure sensor gain of a volts column [bar/V] (AUTH: 10)")
    p.add_argument("--brake-torque-nm", type=float, help="the bench's brake torque at this point [N m]")
    p.add_argument("--json", action="store_true", help="print one JSON document instead of the text")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    doc = trace_document(args.file, args.engine, args.gain_bar_per_v, args.brake_torque_nm)
    print(json.dumps(doc, indent=1) if args.json else "\n".join(text_lines(doc)))
    return 0


def trace_document(path: Path, engine: str | None, gain_bar_per_v: float | None,
                   brake_torque_nm: float | None) -> dict:
    """The whole report as a JSON-able dict (what ``trace`` prints); ValueError / CorruptLog in one line."""
    if not path.exists():
        raise FileNotFoundError(f"no such file: {path}")
    kind = FORMATS.get(path.suffix.lower())
    if kind is None:
        raise ValueError(f"{path.name}: unknown kind of file; trace reads {', '.join(sorted(FORMATS))} "
                         "(a DAQ voltage table with a crank-wheel signal goes through `frictionwatch import-daq`)")
    if kind == "j1939-mdf4":
        return speed_document(path, kind)
    if not engine:
        raise ValueError(f"{path.name} is a pressure trace: name the engine with --engine (its geometry gives IMEP)")
    spec = load_engine(engine)
    if kind == "encoder-xlsx":
        if gain_bar_per_v is None or not 0 < gain_bar_per_v < math.inf:
            raise ValueError(f"{path.name}: the pressure column is in volts; give the sensor gain with "
                             "--gain-bar-per-v (a finite number > 0)")
        cycles = read_encoder_table(path, spec, gain_bar_per_v * 1e5)
    else:
        cycles = read_angle_csv(path)
    return pressure_document(cycles, spec, kind, brake_torque_nm)


def pressure_document(pc: PressureCycles, spec: EngineSpec, kind: str, brake_torque_nm: float | None) -> dict:
    if pc.cylinder > spec.n_cyl:
        raise ValueError(f"{pc.source} holds cylinder {pc.cylinder}; engine {spec.name} has {spec.n_cyl}")
    theta = np.radians(pc.angle_deg)
    zero = np.zeros(pc.cycles)  # each row is already in its cylinder's own angle
    imep = net_imep(theta, pc.pressure_pa, zero, spec.kinematics_params(), spec.piston_area, spec.displacement_cyl)
    pmax, pmax_angle = peak_pressure(theta, pc.pressure_pa, zero)
    rows = [{"cycle": k, "rpm": None if np.isnan(pc.rpm[k]) else float(pc.rpm[k]), "imep_bar": float(imep[k] / 1e5),
             "pmax_bar": float(pmax[k] / 1e5), "pmax_angle_deg": float(np.degrees(pmax_angle[k]))}
            for k in range(pc.cycles)]
    doc = {"file": pc.source, "format": kind, "engine": spec.name, "cylinder": pc.cylinder, "cycles": rows,
           "imep_bar": float(imep.mean() / 1e5), "pmax_bar": float(pmax.mean() / 1e5), "notes": list(pc.notes)}
    measured = [f"IMEP (net, 720 deg centred on firing TDC) and peak pressure of cylinder {pc.cylinder}, "
                f"{pc.cycles} cycle(s)"]
    if np.isfinite(pc.rpm).any():
        measured.append("mean speed of each cycle from the encoder")
    others = spec.n_cyl - 1
    not_measured = ["friction from the crank-speed balance: it needs the pressure of every cylinder"
                    + (f" (this file has cylinder {pc.cylinder} of {spec.n_cyl})" if others else "")
                    + ("" if np.isfinite(pc.rpm).any() else " and a crank-speed signal (this file has none)")]
    if others:
        not_measured.append(f"IMEP of the other {others} cylinders")
    if brake_torque_nm is None:
        not_measured.append("FMEP as IMEP - BMEP: give the bench's brake torque with --brake-torque-nm")
    else:
        if not 0 <= brake_torque_nm < math.inf:  # inf would print an FMEP of -inf, NaN one of NaN
            raise ValueError(f"--brake-torque-nm {brake_torque_nm:g} must be a finite number >= 0")
        bmep = spec.torque_to_mep(brake_torque_nm)
        doc["brake"] = {"torque_nm": brake_torque_nm, "bmep_bar": bmep / 1e5,
                        "imep_minus_bmep_bar": doc["imep_bar"] - bmep / 1e5,
                        "assumes": f"cylinder {pc.cylinder} stands for all {spec.n_cyl} (not checked: only it was "
                                   "measured); it is mechanical friction plus auxiliaries (net IMEP already "
                                   "counts the pumping loop)"}
        measured.append("BMEP from the stated brake torque")
    doc["measured"], doc["not_measured"] = measured, not_measured
    return doc


def speed_document(path: Path, kind: str) -> dict:
    frames = read_can_frames(path)
    s = j1939_engine_speed(frames)
    doc: dict = {"file": path.name, "format": kind, "can_frames": len(frames), "notes": [
        "engine speed = J1939 EEC1 (PGN 61444) SPN 190, 0.125 rpm/bit" + (f", source address {s.sources[0]}"
                                                                          if len(s.sources) == 1 else ""),
    ]}
    not_measured = ["crank angle, cylinder pressure, IMEP and friction: the log has no tooth timing and no pressure, "
                    "and EEC1 is the ECU's own speed value, one number per message (no angle-resolved speed)"]
    if s.t.size == 0:
        doc["speed"] = None
        doc["measured"] = []
        not_measured.insert(0, f"engine speed: no valid EEC1 frame ({s.invalid} 'not available', {s.short} short)")
    else:
        dt = np.diff(s.t)
        doc["speed"] = {"samples": int(s.t.size), "duration_s": float(s.t[-1] - s.t[0]),
                        "interval_s": float(np.median(dt)) if dt.size else None, "rpm_mean": float(s.rpm.mean()),
                        "rpm_min": float(s.rpm.min()), "rpm_max": float(s.rpm.max()), "rpm_std": float(s.rpm.std()),
                        "invalid_frames": s.invalid, "short_frames": s.short}
        doc["measured"] = ["engine speed over time (J1939 EEC1)"]
        if s.rpm.max() == 0:
            doc["notes"].append(f"engine at rest: EngineSpeed 0 rpm in all {s.t.size} frames")
        not_measured.append("friction from a coast-down of this speed: it would need the rotating inertia and the "
                            "gas torque, neither of which the log holds")
    doc["not_measured"] = not_measured
    return doc


def text_lines(doc: dict) -> list[str]:
    lines = [f"{doc['file']} ({doc['format']})" + (f", engine {doc['engine']}" if doc.get("engine") else "")]
    lines += [f"  {n}" for n in doc.get("notes", [])]
    if "cycles" in doc:
        lines.append(f"{'cycle':>6} {'rpm':>8} {'IMEP bar':>9} {'Pmax bar':>9} {'@ degCA':>8}   cylinder "
                     f"{doc['cylinder']}")
        for c in doc["cycles"]:
            rpm = "n/a" if c["rpm"] is None else f"{c['rpm']:.1f}"
            lines.append(f"{c['cycle']:>6} {rpm:>8} {c['imep_bar']:>9.3f} {c['pmax_bar']:>9.1f} "
                         f"{c['pmax_angle_deg']:>8.1f}")
        lines.append(f"mean IMEP {doc['imep_bar']:.3f} bar over {len(doc['cycles'])} cycle(s)")
        if "brake" in doc:
            b = doc["brake"]
            lines.append(f"brake {b['torque_nm']:g} N m -> BMEP {b['bmep_bar']:.3f} bar; IMEP - BMEP "
                         f"{b['imep_minus_bmep_bar']:.3f} bar if {b['assumes']}")
    if doc.get("speed"):
        sp = doc["speed"]
        lines.append(f"speed {sp['rpm_mean']:.2f} rpm (min {sp['rpm_min']:.2f}, max {sp['rpm_max']:.2f}, "
                     f"sd {sp['rpm_std']:.2f}) from {sp['samples']} samples over {sp['duration_s']:.1f} s")
    lines += ["measured: " + "; ".join(doc["measured"]) if doc["measured"] else "measured: nothing"]
    lines += ["not measurable from this file: " + n for n in doc["not_measured"]]
    return lines
