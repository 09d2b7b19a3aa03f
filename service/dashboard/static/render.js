// Turns the API's JSON into what a person reads: the per-cylinder bars and table, the traces, sensor health and
// the alerts. Pure rendering: no fetching, no state beyond the DOM.

import { describeValue, fmt, fmtAuto, isNum, unitOf } from "./format.js";
import { barPlot, emptyPlot, linePlot } from "./plot.js";

const $ = (id) => document.getElementById(id);

function cell(row, text, cls = "") {
  const td = document.createElement("td");
  td.textContent = text;
  if (cls) td.className = cls;
  row.appendChild(td);
  return td;
}

export function showError(id, message) {
  const p = $(id);
  p.hidden = !message;
  p.textContent = message || "";
}

/** losses: the /losses body; summary: the latest CycleSummary (its IMEP and pmax per cylinder) or null. */
export function renderLosses(losses, summary) {
  const cyls = losses.cylinders || [];
  barPlot($("losses-plot"), {
    bars: cyls.map((c) => ({ cylinder: c.cylinder, value: c.fmep_bar, sigma: c.fmep_sigma_bar, status: c.status })),
    yLabel: "FMEP (bar)", unit: "bar",
  });
  const w = losses.window;
  // a window: the cycles behind the figures; the smoothed estimate: its effective number of cycles
  const span = w && isNum(w.first_cycle) ? `cycles ${w.first_cycle}–${w.last_cycle}` : `up to cycle ${losses.cycle_index}`;
  $("losses-window").textContent = !w || !isNum(w.cycles) ? `as of cycle ${losses.cycle_index}`
    : isNum(w.forgetting) ? `smoothed over ${span}: about ${fmt(w.cycles, 0)} effective cycles (forgetting factor ${w.forgetting})`
      : `${span} (${fmt(w.cycles, 0)} cycles)`;
  const body = $("losses-table").tBodies[0];
  body.replaceChildren();
  const notes = new Map();  // reason (its data weight left out: the table has a column for it) -> cylinders
  for (const c of cyls) {
    const row = body.insertRow();
    row.dataset.cylinder = c.cylinder;
    cell(row, String(c.cylinder));
    cell(row, fmt(c.fmep_bar), "fmep");
    cell(row, fmt(c.fmep_sigma_bar));
    cell(row, c.status, `text status status-${c.status}`);
    cell(row, fmt(c.data_weight, 2));
    cell(row, isNum(c.friction_torque_mean_nm)
      ? `${fmt(c.friction_torque_mean_nm, 2)} ± ${fmt(c.friction_torque_sigma_nm, 2)}` : "—");
    const k = c.cylinder - 1;
    cell(row, summary && summary.imep_bar ? fmt(summary.imep_bar[k], 2) : "—");
    cell(row, summary && summary.pmax_bar ? fmt(summary.pmax_bar[k], 1) : "—");
    cell(row, (c.flags || []).join(", ") || "none", "text");
    cell(row, c.reason ? `note ${noteOf(notes, c)}` : "", "text");
  }
  renderNotes(notes);
  const e = losses.engine || {};
  const cal = e.calibration === "uncalibrated" ? ", uncalibrated" : "";
  $("engine-fmep").textContent = isNum(e.fmep_bar)
    ? `${fmt(e.fmep_bar)} ± ${fmt(e.fmep_sigma_bar)} bar${e.status ? ` (${e.status}${cal})` : ""}`
    : `—${e.status ? ` (${e.status})` : ""}`;
  $("losses-calibration").textContent = calibrationWords(e);
}

/** What the ±1σ rests on: the installation's calibration (core/model/calibration.py), in words. */
function calibrationWords(e) {
  if (!e.calibration) return "";
  const part = isNum(e.calibration_sigma_nm) ? ` ${fmt(e.calibration_sigma_nm, 2)} N·m of the engine's ±1σ is the calibration's.` : "";
  return e.calibration === "commissioned"
    ? `Calibration: commissioned (TDC, pressure gain and J measured on this engine).${part}`
    : "Calibration: uncalibrated. Every ±1σ includes a typical installation's TDC (±0.5°), pressure gain "
      + "(±3 % per channel, ±1 % common) and "
      + `inertia (±5 %), not measured on this engine: run frictionwatch commission to measure them.${part}`;
}

/** The note number of a cylinder's reason: cylinders whose reasons differ only in the data weight share one. */
function noteOf(notes, c) {
  const key = c.reason.replace(/\s*\(data weight [^)]*\)/, "");
  if (!notes.has(key)) notes.set(key, { status: c.status, cylinders: [] });
  notes.get(key).cylinders.push(c.cylinder);
  return [...notes.keys()].indexOf(key) + 1;
}

function renderNotes(notes) {
  const list = $("losses-notes");
  list.replaceChildren();
  [...notes.entries()].forEach(([reason, n], i) => {
    const li = document.createElement("li");
    const cyls = n.cylinders.length > 1 ? `cylinders ${n.cylinders.join(", ")}` : `cylinder ${n.cylinders[0]}`;
    li.textContent = `note ${i + 1}, ${n.status} (${cyls}): ${reason}`;
    list.appendChild(li);
  });
}

/** showTotal false: the cylinders alone, on a scale of their own (the total is z times larger). */
export function renderTorque(ft, highlight, showTotal) {
  const x = ft.crank_angle_deg || [];
  const perCyl = ft.friction_torque_cyl_nm || [];
  const series = perCyl.map((y, k) => ({ x, y, cls: k + 1 === highlight ? "series-highlight" : "series-cyl",
    label: `cylinder ${k + 1}` }));
  const hl = series.findIndex((s) => s.cls === "series-highlight");
  if (hl >= 0) series.push(series.splice(hl, 1)[0]);  // drawn on top
  if (showTotal) series.push({ x, y: ft.friction_torque_nm || [], cls: "series-total", label: "total" });
  const legend = showTotal ? [{ cls: "series-total", label: "total" }] : [];
  if (perCyl.length) legend.push({ cls: "series-cyl", label: `each cylinder (${perCyl.length})` });
  if (hl >= 0) legend.push({ cls: "series-highlight", label: `cylinder ${highlight}` });
  linePlot($("torque-plot"), { series, legend, xLabel: "crank angle (°CA)", yLabel: "friction torque (N·m)" });
  $("torque-cycle").textContent = `cycle ${ft.cycle_index}`;
}

export function renderSpeed(sp) {
  const x = sp.crank_angle_deg || [];
  linePlot($("speed-plot"), { series: [
    { x, y: sp.speed_measured_rpm || [], cls: "series-measured", label: "measured" },
    { x, y: sp.speed_model_rpm || [], cls: "series-model", label: "model" },
  ], legend: [{ cls: "series-measured", label: "measured" }, { cls: "series-model", label: "model" }],
  xLabel: "crank angle (°CA)", yLabel: "flywheel speed (rpm)" });
  $("speed-cycle").textContent = `cycle ${sp.cycle_index}`;
  const h = sp.history || {};
  if ((h.cycle_index || []).length < 2) {
    emptyPlot($("history-plot"), "fewer than two cycles so far");
  } else {
    linePlot($("history-plot"), { series: [{ x: h.cycle_index, y: h.rpm_mean, cls: "series-history",
      label: "mean speed per cycle" }], xLabel: "cycle index", yLabel: "mean speed (rpm)" });
  }
}

export function renderHealth(health) {
  const box = $("health");
  box.replaceChildren();
  const p = document.createElement("p");
  box.appendChild(p);
  if (!health.enabled) {
    p.textContent = "Off: the sensor-health stage is opt-in, so TDC offset, pressure gain and pegging are not "
      + "checked on this engine.";
    return;
  }
  const flags = health.flags || [];
  p.textContent = flags.length ? `Flagged: ${flags.join(", ")} (the figures these touch are withheld)`
    : "No sensor flagged.";
  const rows = health.cylinders || [];
  if (!rows.length || typeof rows[0] !== "object") return;
  const keys = Object.keys(rows[0]).filter((k) => k !== "cylinder");
  const table = document.createElement("table");
  const head = table.createTHead().insertRow();
  for (const k of ["cylinder", ...keys]) {
    const th = document.createElement("th");
    const [name, unit] = unitOf(k);
    th.textContent = unit ? `${name} (${unit})` : name;
    th.scope = "col";
    head.appendChild(th);
  }
  const body = table.createTBody();
  rows.forEach((r, i) => {
    const row = body.insertRow();
    cell(row, String(r.cylinder ?? i + 1));
    for (const k of keys) cell(row, isNum(r[k]) ? fmtAuto(r[k]) : describeValue(k, r[k]));  // unit in the header
  });
  box.appendChild(table);
}

const STATE_ORDER = { active: 0, acknowledged: 1, cleared: 2 };
const SEVERITY_ORDER = { alarm: 0, warning: 1, info: 2 };

export function sortAlerts(alerts) {
  return [...alerts].sort((a, b) => (STATE_ORDER[a.state] ?? 3) - (STATE_ORDER[b.state] ?? 3)
    || (SEVERITY_ORDER[a.severity] ?? 3) - (SEVERITY_ORDER[b.severity] ?? 3)
    || (b.raised_cycle ?? 0) - (a.raised_cycle ?? 0));
}

function addPair(dl, term, value) {
  const dt = document.createElement("dt");
  dt.textContent = term;
  const dd = document.createElement("dd");
  dd.textContent = value;
  dl.append(dt, dd);
}

/** alerts: [Alert]; onAck(alert): called by an alert's Acknowledge button. */
export function renderAlerts(alerts, onAck) {
  const list = $("alerts");
  list.replaceChildren();
  const active = alerts.filter((a) => a.state === "active").length;
  const acked = alerts.filter((a) => a.state === "acknowledged").length;
  $("active-alerts").textContent = `${active} active, ${acked} acknowledged`;
  if (!alerts.length) {
    const li = document.createElement("li");
    li.className = "no-alerts";
    li.textContent = "No alerts.";
    list.appendChild(li);
    return;
  }
  for (const a of sortAlerts(alerts)) {
    const li = document.createElement("li");
    li.className = `alert sev-${a.severity} state-${a.state}`;
    li.dataset.alertId = a.alert_id;
    const h = document.createElement("h3");
    const where = a.cylinder === null || a.cylinder === undefined ? "engine" : `cylinder ${a.cylinder}`;
    h.innerHTML = '<span class="sev"></span> <span class="what"></span> <span class="state muted"></span>';
    h.querySelector(".sev").textContent = a.severity;
    h.querySelector(".what").textContent = `${a.kind.replaceAll("_", " ")} — ${where}`;
    h.querySelector(".state").textContent = `(${a.state}, alert ${a.alert_id})`;
    const msg = document.createElement("p");
    msg.textContent = a.message;
    const dl = document.createElement("dl");
    addPair(dl, "raised", `cycle ${a.raised_cycle}` + (isNum(a.raised_at_s) ? `, t = ${fmt(a.raised_at_s, 1)} s` : ""));
    if (a.cleared_cycle !== null && a.cleared_cycle !== undefined) addPair(dl, "cleared", `cycle ${a.cleared_cycle}`);
    if (a.acknowledged_by) addPair(dl, "acknowledged by", a.acknowledged_by);
    for (const [k, v] of Object.entries(a.evidence || {})) addPair(dl, unitOf(k)[0], describeValue(k, v));
    li.append(h, msg, dl);
    if (a.state === "active") {
      const btn = document.createElement("button");
      btn.type = "button";
      btn.textContent = "Acknowledge";
      btn.setAttribute("aria-label", `Acknowledge alert ${a.alert_id}: ${a.kind} on ${where}`);
      btn.addEventListener("click", () => onAck(a, btn));
      li.appendChild(btn);
    }
    list.appendChild(li);
  }
}
