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

/** A cylinder's figure as drawn: the API keeps a measurement in fmep_bar and the like, a share's number under
 *  share_* (never in a measurement field); either is shown with its status word, a share hatched. */
function shownFigure(c) {
  const p = c.status === "share" ? "share_" : "";
  return { fmep: c[`${p}fmep_bar`], sigma: c[`${p}fmep_sigma_bar`], torque: c[`${p}friction_torque_mean_nm`],
    torqueSigma: c[`${p}friction_torque_sigma_nm`] };
}

/** losses: the /losses body; summary: the latest CycleSummary (its IMEP and pmax per cylinder) or null. */
export function renderLosses(losses, summary) {
  const cyls = losses.cylinders || [];
  barPlot($("losses-plot"), {
    bars: cyls.map((c) => {
      const f = shownFigure(c);
      return { cylinder: c.cylinder, value: f.fmep, sigma: f.sigma, status: c.status };
    }),
    yLabel: "FMEP (bar)", unit: "bar",
  });
  const w = losses.window;
  // a window: the cycles behind the figures; the smoothed estimate: its effective number of cycles
  const span = w && isNum(w.first_cycle) ? `cycles ${w.first_cycle}–${w.last_cycle}` : `up to cycle ${losses.cycle_index}`;
  $("losses-window").textContent = !w || !isNum(w.cycles) ? `as of cycle ${losses.cycle_index}`
    : isNum(w.forgetting) ? `smoothed over ${span}: about ${fmt(w.cycles, 0)} effective cycles (forgetting factor ${Number(w.forgetting.toPrecision(6))})`
      : `${span} (${fmt(w.cycles, 0)} cycles${w.left_out ? `; ${w.left_out}` : ""}${w.missing ? `; ${w.missing}` : ""})`;
  const body = $("losses-table").tBodies[0];
  body.replaceChildren();
  const notes = new Map();  // reason (its data weight left out: the table has a column for it) -> cylinders
  for (const c of cyls) {
    const row = body.insertRow();
    const f = shownFigure(c);
    row.dataset.cylinder = c.cylinder;
    cell(row, String(c.cylinder));
    cell(row, fmt(f.fmep), "fmep");
    cell(row, fmt(f.sigma));
    cell(row, c.status, `text status status-${c.status}`);
    cell(row, fmt(c.data_weight, 2));
    cell(row, isNum(f.torque) ? `${fmt(f.torque, 2)} ± ${fmt(f.torqueSigma, 2)}` : "—");
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
      + "(±3 % per channel, ±1 % common), inertia (±5 %) and load reading (±0.5 % as shaft torque, ±3 % as "
      + "electrical power), not measured on this engine: run frictionwatch commission to measure TDC, gain and J "
      + `(the load's is the installation's to state: see Sensors and calibration).${part}`;
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

const SENSOR_FLAG_WORDS = {
  sensor_tdc_offset: "the whole wheel's TDC is off by more than the calibration allows (or every pressure sensor "
    + "reads the expansion low, as a flame-heated sensor's thermal shock does: the TDC is found from the pressure): "
    + "every friction figure is withheld until it is corrected",
  sensor_tdc_offset_cyl: "this cylinder's TDC differs from the other cylinders' by more than the calibration allows: "
    + "its friction figures are withheld",
  sensor_pressure_gain_cyl: "this cylinder's pressure sensor reads high or low against its siblings: its figures are "
    + "withheld",
  sensor_pressure_offset_cyl: "this cylinder's pressure is offset (pegging) against its siblings: its figures are "
    + "withheld",
  sensor_thermal_shock_cyl: "this cylinder's pressure sensor reads low after combustion (thermal shock of a "
    + "flame-heated sensor) against its siblings: its figures are withheld",
};

/** One sensor flag in words: "sensor_tdc_offset_cyl3" -> "cylinder 3: this cylinder's TDC differs ...". */
export function sensorFlagWords(flag) {
  const m = /^(.*_cyl)(\d+)$/.exec(flag);
  const words = SENSOR_FLAG_WORDS[m ? m[1] : flag];
  if (!words) return `${flag} (the figures it touches are withheld)`;
  return m ? `cylinder ${m[2]}: ${words} (${flag})` : `${words} (${flag})`;
}

function addBlock(box, title, ...lines) {
  const h = document.createElement("h3");
  h.textContent = title;
  box.appendChild(h);
  return lines.filter(Boolean).map((text) => {
    const p = document.createElement("p");
    setWithCode(p, text);
    box.appendChild(p);
    return p;
  });
}

/** Text whose `quoted` parts (a command to type) are shown as code; no HTML is parsed. */
function setWithCode(el, text) {
  el.replaceChildren(...text.split("`").map((part, i) => {
    if (i % 2 === 0) return document.createTextNode(part);
    const code = document.createElement("code");
    code.textContent = part;
    return code;
  }));
}

function addFlagList(box, flags, testId) {
  if (!flags.length) return;
  const ul = document.createElement("ul");
  ul.className = "sensor-flags";
  ul.dataset.testid = testId;
  for (const f of flags) {
    const li = document.createElement("li");
    li.textContent = sensorFlagWords(f);
    ul.appendChild(li);
  }
  box.appendChild(ul);
}

const signed = (v, digits = 2) => (isNum(v) ? `${v >= 0 ? "+" : "−"}${Math.abs(v).toFixed(digits)}` : "—");
const METHOD_WORDS = { "rohr-compression-expansion": "fired cycles (heat release before and after combustion)",
  "rohr-motored-heat-loss-shaping": "motored cycles (heat loss over the closed cycle)" };

/** Where one cylinder's own calibration sigma stands out of the typical one (commissioning writes one per cylinder:
 *  a channel whose gain it corrected holds that correction), that cylinder's, in words; else nothing. */
function widest(perCylinder, typical, unit, digits) {
  if (!Array.isArray(perCylinder) || !perCylinder.length || !isNum(typical)) return "";
  let k = 0;
  perCylinder.forEach((v, i) => { if (v > perCylinder[k]) k = i; });
  return perCylinder[k] > 1.2 * typical
    ? ` (rms; cylinder ${k + 1} ±${fmt(perCylinder[k], digits)}${unit}, the widest, carried in its own figures)` : "";
}

/** The installation's calibration (the model's [model.calibration]) in words. */
function calibrationText(cal) {
  const sig = `TDC ±${fmt(cal.tdc_wheel_sigma_deg, 2)}° for the whole wheel and ±${fmt(cal.tdc_cylinder_sigma_deg, 2)}° `
    + `per cylinder${widest(cal.tdc_cylinder_sigmas_deg, cal.tdc_cylinder_sigma_deg, "°", 2)}, pressure gain `
    + `±${fmt(cal.gain_sigma_pct, 1)} % per channel${widest(cal.gain_sigmas_pct, cal.gain_sigma_pct, " %", 1)} and `
    + `±${fmt(cal.gain_common_sigma_pct, 1)} % `
    + `common to all, flywheel inertia J ±${fmt(cal.inertia_sigma_pct, 1)} %`
    + (isNum(cal.load_torque_sigma_pct) ? `, the load ±${fmt(cal.load_torque_sigma_pct, 1)} % read as shaft torque or `
      + `±${fmt(cal.load_power_sigma_pct, 1)} % read as electrical power (${cal.generator_efficiency < 1
        ? `generator efficiency ${fmt(100 * cal.generator_efficiency, 1)} %`
        : "generator efficiency not stated: its losses are inside that ±"})` : "");
  if (cal.status === "commissioned") {
    return [`Commissioned: TDC, pressure gains and J were measured on this engine (${cal.source}). What is still `
      + `unknown, and is in every ±1σ: ${sig}.`];
  }
  return [`Uncalibrated: nobody has measured this installation's TDC, pressure-sensor gains or flywheel inertia. `
    + `Every friction ±1σ therefore assumes a typical installation's errors: ${sig}.`,
  "To measure them, run `frictionwatch commission` on a recording of this engine: it finds each cylinder's TDC, "
    + "the gains and J and writes a commissioned engine model to run with."];
}

/** The TDC watch: each cylinder's TDC found again from its own pressure every window_cycles cycles. */
function renderTdcWatch(box, w) {
  const every = `Every ${w.window_cycles} cycles each cylinder's TDC is found again from its own pressure and `
    + "compared with where the engine model puts it. If the wheel is found further off than the calibration "
    + "allows, it is flagged and every friction figure is withheld; if one cylinder's TDC has moved against the "
    + "others, that cylinder's figures are withheld. `frictionwatch commission` measures TDC again.";
  if (!isNum(w.window_last_cycle)) {
    addBlock(box, "TDC from the cylinder pressure (always on)", every,
      `First check after ${w.window_cycles} cycles: ${w.cycles_gathered} of ${w.window_cycles} gathered so far.`)[1]
      .dataset.testid = "tdc-watch-status";
    return;
  }
  const cyls_missing = (x) => (x.cylinders || []).some((c) => !isNum(c.offset_deg));
  const verdict = w.flags.length ? "Flagged:" : "No flag: the pressure agrees with the model's TDC within what the "
    + "calibration allows.";
  const ps = addBlock(box, "TDC from the cylinder pressure (always on)", every,
    `Newest check at cycle ${w.window_last_cycle} (the ${w.window_cycles} cycles before it): the wheel's TDC is `
    + `${signed(w.wheel_offset_deg)} ± ${fmt(w.wheel_sigma_deg, 2)}° from the model's (+ means the true TDC is later). `
    + `${verdict} Next check in ${w.window_cycles - w.cycles_gathered} cycles.`
    + (cyls_missing(w) ? " A large engine's cylinders are checked four at a time in turn: — until a cylinder's first "
      + "check." : ""));
  ps[1].dataset.testid = "tdc-watch-status";
  addFlagList(box, w.flags, "tdc-watch-flags");
  const cyls = w.cylinders || [];
  if (!cyls.length) return;
  const table = document.createElement("table");
  table.className = "across";
  table.dataset.testid = "tdc-watch-table";
  const methods = [...new Set(cyls.map((c) => c.method).filter(Boolean))];
  const cap = table.createCaption();
  cap.textContent = `TDC found from each cylinder's pressure, in ° crank angle from the model's, ±1σ; from `
    + (methods.map((m) => METHOD_WORDS[m] || m).join(" and ") || "no cycle");
  const head = table.createTHead().insertRow();
  const th0 = document.createElement("th");
  th0.textContent = "cylinder";
  th0.scope = "row";
  head.appendChild(th0);
  for (const c of cyls) {
    const th = document.createElement("th");
    th.textContent = String(c.cylinder);
    th.scope = "col";
    head.appendChild(th);
  }
  const body = table.createTBody();
  const flagged = new Set(w.flags.map((f) => (/_cyl(\d+)$/.exec(f) || [])[1]).filter(Boolean).map(Number));
  for (const [label, value] of [["TDC found (°)", (c) => signed(c.offset_deg)],
    ["±1σ (°)", (c) => fmt(c.sigma_deg, 2)],
    ["flag", (c) => (flagged.has(c.cylinder) ? "flagged" : "—")]]) {
    const row = body.insertRow();
    const th = document.createElement("th");
    th.textContent = label;
    th.scope = "row";
    row.appendChild(th);
    for (const c of cyls) cell(row, value(c), flagged.has(c.cylinder) && label === "flag" ? "flagged" : "");
  }
  box.appendChild(table);
}

/** The speed-based sensor-health stage (opt-in): its per-cylinder estimates, or why it is off. */
function renderSpeedStage(box, health) {
  const title = "Speed-based check of TDC, gain and pegging (opt-in)";
  if (!health.enabled) {
    addBlock(box, title, "Off. It estimates each cylinder's TDC, pressure gain and pegging from the flywheel speed "
      + "and corrects them, but where the engine model differs from the real engine its TDC reading is not "
      + "reliable, so it is off by default. `frictionwatch serve --sensor-health` switches it on.");
    return;
  }
  const flags = health.speed_based_flags || [];
  addBlock(box, title, `On. ${flags.length ? "Flagged:" : "No sensor flagged by it."}`
    + (isNum(health.wheel_tdc_offset_deg) ? ` Its wheel TDC: ${signed(health.wheel_tdc_offset_deg)} ± `
      + `${fmt(health.wheel_tdc_offset_sigma_deg, 2)}°.` : ""));
  addFlagList(box, flags, "speed-flags");
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

export function renderHealth(health) {
  const box = $("health");
  box.replaceChildren();
  const flags = health.flags || [];
  const top = document.createElement("p");
  top.dataset.testid = "health-summary";
  top.className = flags.length ? "health-flagged" : "";
  top.textContent = flags.length
    ? `Sensor flags on cycle ${health.cycle_index}: ${flags.length}. A flagged sensor withholds the figures it `
      + "touches (no number is shown for them) until it is corrected."
    : `No sensor flagged on cycle ${health.cycle_index}.`;
  box.appendChild(top);
  if (health.calibration) {
    addBlock(box, "Calibration", ...calibrationText(health.calibration))[0].dataset.testid = "health-calibration";
  }
  if (health.tdc_watch) renderTdcWatch(box, health.tdc_watch);
  renderSpeedStage(box, health);
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

/** The fleet table (GET api/v1/fleet): one row per engine of the store; ``served`` the ids this service runs (the
 *  others are another process's, or none's: "no live writer"). A share or unresolved figure shows no number. */
export function renderFleet(rows, served) {
  const body = $("fleet-table").querySelector("tbody");
  body.replaceChildren();
  for (const e of rows) {
    const tr = document.createElement("tr");
    tr.dataset.engine = e.engine_id;
    cell(tr, e.engine_id + (served.has(e.engine_id) ? " (here)" : ""), "text");
    cell(tr, e.writer ? (e.writer_live ? e.writer.split(":").slice(0, 2).join(":") : "no live writer") : "none",
      "text");
    cell(tr, isNum(e.last_cycle) ? `#${e.last_cycle}` : "—");
    cell(tr, isNum(e.last_cycle_age_s) ? fmt(e.last_cycle_age_s, 0) : "—");
    const f = e.engine || {};
    const measured = f.status === "measured";
    cell(tr, measured ? fmt(f.fmep_bar, 3) : "—");
    cell(tr, measured ? fmt(f.fmep_sigma_bar, 3) : "—");
    cell(tr, f.status || "—", "text");
    cell(tr, `${e.active_alerts}` + (e.acknowledged_alerts ? ` (+${e.acknowledged_alerts} acknowledged)` : ""));
    body.appendChild(tr);
  }
}
