"""The offline HTML report of `frictionwatch discrepancy --report DIR`: one self-contained file, the plots inline as
SVG (matplotlib, Agg), nothing fetched from the network. Wiring and units only; the figures come from core.discrepancy.

Sections: the verdict and the gap before and after; each found effect with its parameters, sigma and evidence; the
held-out residual against crank angle (baseline and after each step) and against engine order (before and after each
step, half orders marked: they point at the cam); where along the cycle (cylinder windows) and per channel.
"""

from __future__ import annotations

import html
import io
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from frictionwatch.core.discrepancy import Discovery  # noqa: E402
from frictionwatch.core.discrepancy.sensor_faults import said_fault, said_stood_in, separation  # noqa: E402
from frictionwatch.core.discrepancy.words import inside_floor  # noqa: E402
from frictionwatch.service.output_files import atomic_path  # noqa: E402

RPM_PER_RAD_S = 30.0 / np.pi


def _svg(fig) -> str:
    buf = io.StringIO()
    fig.savefig(buf, format="svg", bbox_inches="tight")
    plt.close(fig)
    text = buf.getvalue()
    return text[text.index("<svg"):]  # drop the XML prolog and doctype: inline in HTML


def angle_plot(found: Discovery) -> str:
    fig, ax = plt.subplots(figsize=(9, 3.6))
    for label, angles, mean in found.curves:
        ax.plot(np.degrees(angles), mean * RPM_PER_RAD_S, lw=1.2, label=label)
    ax.axhline(0.0, color="0.6", lw=0.6)
    ax.set(xlabel="crank angle [°CA, 0 = cyl 1 firing TDC]", ylabel="measured − model speed [rpm]",
           title="held-out residual, mean over cycles")
    ax.legend(fontsize=8)
    return _svg(fig)


def order_plot(before: dict, after: dict, title: str) -> str:
    fig, ax = plt.subplots(figsize=(9, 3.2))
    orders = np.array([o["order"] for o in before["orders"]])
    width = 0.2
    for shift, loc, label in ((-width / 2, before, "before"), (width / 2, after, "after")):
        amp = np.array([o["amplitude_rpm"] for o in loc["orders"]])
        sig = np.array([o["sigma_rpm"] for o in loc["orders"]])
        ax.bar(orders + shift, amp, width, yerr=sig, label=label, capsize=1.5)
    for o in orders[::2]:
        ax.axvspan(o - 0.25, o + 0.25, color="0.93", zorder=-1)
    ax.set(xlabel="engine order (shaded: half orders, the cam)", ylabel="coherent residual [rpm]", title=title)
    ax.legend(fontsize=8)
    return _svg(fig)


def _table(rows: list[list[str]], head: list[str]) -> str:
    th = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r) + "</tr>" for r in rows)
    return f"<table><tr>{th}</tr>{body}</table>"


def _fmt(v: object) -> str:
    return f"{v:.4g}" if isinstance(v, float) else str(v)


def _fmep_change(evidence: dict) -> str:
    """The engine FMEP the mean balance measures, without and with the found effect (what analyze would read)."""
    a, b = evidence.get("measured_friction_before"), evidence.get("measured_friction_after")
    if not a or not b:
        return "–"
    return f"{a['fmep_bar']:.3f} → {b['fmep_bar']:.3f} ± {b['fmep_sigma_bar']:.2g}"


def render(doc: dict, found: Discovery) -> str:
    parts = [f"<h1>Discrepancy: {html.escape(doc.get('engine', ''))}</h1>",
             f"<p><b>{html.escape(doc['verdict'])}</b> Baseline {html.escape(str(doc.get('baseline', '')))}, "
             f"{doc.get('cycles', '?')} cycles. Gap on held-out cycles {doc['gap_before']:.3g} → "
             f"{doc['gap_after']:.3g}.</p>", f"<p class=small>Gap: {html.escape(doc['metric'])}.</p>"]
    rows = [[f["effect"], _fmt(f["cylinder"]) if f["cylinder"] is not None else "–",
             ", ".join(f"{k} = {_fmt(v)}" for k, v in f["parameters"].items()),
             ", ".join(f"{k} ± {_fmt(v)}" for k, v in f["sigma"].items()) or "–",
             f"{f['evidence']['gap_before']:.3g} → {f['evidence']['gap_after']:.3g}"
             + (f" (named from the pressure: {f['evidence']['pressure_reading']})"
                if f["evidence"].get("channel") == "pressure" else ""),
             f"{f['evidence']['delta_chi2_heldout']:.1f}", _fmep_change(f["evidence"]),
             str(f["evidence"]["runner_up"] or "–")]
            for f in doc["found"]]
    if rows:
        parts.append(_table(rows, ["effect", "cylinder", "parameters", "sigma", "gap", "held-out Δχ²",
                                   "measured FMEP [bar]", "runner-up"]))
    rest = doc.get("remainder")
    if rest:
        parts.append("<p>What remains unexplained on the held-out cycles: engine orders "
                     f"{html.escape(', '.join(_fmt(o) for o in rest['engine_orders']) or 'none')}"
                     f" (half-order share {rest['half_order_share']:.2f}), peak at {rest['peak_deg']:.0f}° crank angle,"
                     f" largest in the windows of cylinder(s) {', '.join(str(c) for c in rest['cylinder_windows'])}"
                     + (f", torque balance {rest['balance_nm']:+.3g} N·m" if rest["balance_nm"] is not None else "")
                     + ".</p>")
    for part in (rest, doc.get("ambiguous")):  # a speed gap far beyond a healthy log's, inside the floor (note 48)
        if part and part.get("inside_floor"):
            parts.append(f"<p>Inside the model-error floor: {html.escape(inside_floor(part['inside_floor']))}.</p>")
    amb = doc.get("ambiguous")
    faults = doc.get("sensor_faults") or []
    if faults:  # a pressure sensor the monitor flags with a fault no candidate describes (sensor_faults.py)
        parts.append("<p>Sensor: the monitor doubts " + html.escape(" and ".join(said_fault(f) for f in faults))
                     + "; every figure here rests on its reading. " + html.escape(separation(faults))
                     + " would tell the sensor from the engine.</p>")
    if doc.get("stood_in_channels"):  # channels the monitor replaced by the siblings' pressure
        parts.append("<p>Sensor: " + html.escape(said_stood_in(doc["stood_in_channels"])) + ".</p>")
    if amb and amb.get("sensor_faults"):
        parts.append(f"<p>Ambiguous: the fits found {html.escape(' and '.join(amb['fits']))}, but on the reading of "
                     "the sensor above; nothing was added.</p>")
    elif amb and amb.get("inside_floor"):
        parts.append(f"<p>Ambiguous: {html.escape(', '.join(amb['candidates']))} or the model's own error there "
                     "explain the held-out cycles equally well; none was added. " + html.escape(
                         "; or ".join(amb["separated_by"]) + " would tell them apart." if amb["separated_by"] else "")
                     + "</p>")
    elif amb and len(amb["candidates"]) == 1:  # one effect the speed cannot place in a cylinder
        parts.append(f"<p>Ambiguous: {html.escape(amb['candidates'][0])} explains the held-out cycles, but the speed "
                     "cannot tell which cylinder; it was not added. " + html.escape(
                         "; or ".join(amb["separated_by"]) + " would tell." if amb["separated_by"] else "")
                     + "</p>")
    elif amb:
        parts.append(f"<p>Ambiguous: {html.escape(' and '.join(amb['candidates']))} explain the held-out cycles "
                     "equally well; neither was added. " + html.escape(
                         "; or ".join(amb["separated_by"]) + " would tell them apart." if amb["separated_by"] else "")
                     + "</p>")
    if doc.get("within_null_fits"):  # fits of the model's own error: said, never named (core.discrepancy.workflow)
        parts.append(f"<p>Within the model's own error: {html.escape(' and '.join(doc['within_null_fits']))} fit the "
                     "held-out cycles as well as each other; that names neither, and nothing was added.</p>")
    for r in doc.get("refused", []):
        parts.append(f"<p>Refused: {html.escape(r['candidate'])}: {html.escape(r['reason'])} (held-out gap "
                     f"{r['gap_before']:.3g} → {r['gap_after']:.3g}); the model was left as it was.</p>")
    parts += ["<h2>Residual against crank angle</h2>", angle_plot(found), "<h2>Residual against engine order</h2>"]
    prev = found.localisation
    for s in found.steps:
        parts.append(order_plot(s.before, s.after, f"before and after + {s.label}"))
        prev = s.after
    if not found.steps:
        parts.append(order_plot(prev, found.final, "baseline (nothing added)"))
    loc = found.localisation
    parts.append("<h2>Where (baseline, held-out cycles)</h2>")
    parts.append(_table([[str(c["cylinder"]), f"{c['rms_rpm']:.4g}", f"{c['relative']:.2f}"] for c in loc["cylinders"]],
                        ["cylinder window (TDC..+180°)", "residual rms [rpm]", "of the cycle's"]))
    bal = loc["balance"]
    if bal.get("points"):  # a log at several operating points: each judged on its own (core.discrepancy.features)
        parts.append(f"<p>The held-out cycles ran at {len(bal['points'])} operating points, each judged against its "
                     f"own noise ({loc.get('cycles_between_points', 0)} cycles of the log, in its load steps, were "
                     "left out). Torque balance residual by point: " + "; ".join(
                         f"{p['rpm']:.0f} rpm, {p['load_nm']:.4g} N·m load: {p['mean_nm']:+.3g} N·m"
                         for p in bal["points"]) + ".</p>")
    parts.append(f"<p>Torque balance residual (measured − model friction): {bal['mean_nm']:.3g} ± "
                 f"{bal['sigma_nm']:.2g} N·m. Channels, coherent χ² per cycle: flywheel speed "
                 f"{loc['channels']['flywheel_speed']:.3g}, torque balance {loc['channels']['torque_balance']:.3g}."
                 f" Significant orders: {', '.join(_fmt(o) for o in loc['significant_orders']) or 'none'}.</p>")
    if doc.get("not_significant"):
        parts.append("<p>Tried and not significant (held-out gap): " + html.escape(", ".join(
            f"{k} {v:.3g}" for k, v in doc["not_significant"].items())) + "</p>")
    if doc.get("not_physical"):
        parts.append("<p>Fits dropped as not their effect's physics: " + html.escape("; ".join(
            f"{k}: {v}" for k, v in doc["not_physical"].items())) + "</p>")
    style = ("body{font-family:sans-serif;max-width:960px;margin:2em auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #bbb;padding:2px 8px}.small{font-size:85%;color:#444}")
    return (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>frictionwatch discrepancy</title>"
            f"<style>{style}</style></head><body>{''.join(parts)}</body></html>\n")


def write_report(out_dir: Path, doc: dict, found: Discovery) -> Path:
    """Write ``out_dir/discrepancy.html`` whole or not at all; returns its path."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "discrepancy.html"
    text = render(doc, found)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return path


__all__ = ["angle_plot", "order_plot", "render", "write_report"]
