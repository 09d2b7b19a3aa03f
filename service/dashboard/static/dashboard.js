// frictionwatch dashboard: picks an engine, follows its cycles over Server-Sent Events and re-fetches the plots
// at most twice a second. The numbers of the "Now" panel come straight from each SSE cycle event; the plots
// and tables from the API (throttled). Without events (stream down) everything is polled every few seconds.

import { ENGINE_ID, enginePath, getJSON, postWithToken, throttle } from "./api.js";
import { backlogWords, fmt, isNum } from "./format.js";
import { emptyPlot } from "./plot.js";
import { renderAlerts, renderFleet, renderHealth, renderLosses, renderSpeed, renderTorque, showError } from "./render.js";

const FIGURES_INTERVAL_MS = 500;  // counters, per-cylinder bars and table: at most twice a second, whatever the cycle rate
const TRACES_INTERVAL_MS = 1000;  // the traces (z+1 curves of a few hundred points each): once a second
const POLL_MS = 5000;           // without cycle events: poll this often
const STALE_S = 10;             // "live" but no cycle for this long: say so
const STARTUP_POLL_MS = 2000;   // before the engine's first cycle: how often to ask what the service is doing
const TOKEN_KEY = "frictionwatch.token";
const BY_KEY = "frictionwatch.acknowledged-by";

const $ = (id) => document.getElementById(id);
// startup: what the service does before the engine's first cycle (GET api/v1/startup), in words; null once running
const state = { engines: [], engineId: null, summary: null, es: null, lastCycleAt: 0, connected: false, cycleEvents: 0,
  startup: null, startupTimer: null };

function setLive(mode) {
  if (mode === "live" && state.startup) mode = "starting";  // connected, but nothing to show yet: not green
  const p = $("live");
  p.className = `live ${mode === "live" ? "live-on" : mode}`;
  p.dataset.state = mode;
  const age = (Date.now() - state.lastCycleAt) / 1000;
  $("live-text").textContent = mode === "live"
    ? (state.lastCycleAt && age > STALE_S ? `live — no cycle for ${age.toFixed(0)} s` : "live")
    : mode === "reconnecting" ? "reconnecting…" : mode === "starting" ? "starting…" : "connecting…";
}

/** The selected engine's start-up (compiling the kernels on a fresh install, or waiting for its first cycle): shown
 *  in the banner and in place of the panels, whose routes answer 503 until the first cycle. Asked again every
 *  STARTUP_POLL_MS until the engine runs. An older service without the route (404): no start-up state. */
async function checkStartup() {
  clearTimeout(state.startupTimer);  // one chain of checks, whoever asked (a cycle event, an engine change)
  const r = await getJSON("api/v1/startup");
  const mine = r.ok ? (r.data.engines || []).find((e) => e.engine_id === state.engineId) : null;
  const running = !r.ok || !mine || mine.state === "running";
  const was = state.startup;
  state.startup = running ? null
    : `${mine.state === "compiling" ? r.data.message || "compiling the numerical kernels (first run only)"
      : r.data.message || "waiting for the first cycle"} — ${Math.round(r.data.elapsed_s)} s`
      + (r.data.kernels_compiled ? `, ${r.data.kernels_compiled} kernels compiled so far` : "");
  const banner = $("startup");
  banner.hidden = !state.startup;
  banner.textContent = state.startup || "";
  banner.dataset.state = running ? "running" : mine.state;
  setLive(state.connected ? "live" : $("live").dataset.state || "connecting");
  if (state.startup) {
    startupPanels();
    clearTimeout(state.startupTimer);
    state.startupTimer = setTimeout(checkStartup, STARTUP_POLL_MS);
  } else if (was) { refreshLatest(); plots(); alerts(); }
}

/** Each panel says what the service is doing, not the HTTP status of a route that has nothing yet. */
function startupPanels() {
  for (const id of ["losses-error", "torque-error", "speed-error", "health-error"]) showError(id, "");
  for (const id of ["losses-plot", "torque-plot", "speed-plot", "history-plot"]) emptyPlot($(id), state.startup);
}

/** A panel's request that failed: while the engine starts (503: no cycle yet) the start-up words, else the error. */
function panelError(id, what, r) {
  if (r.ok || (r.status === 503 && state.startup)) showError(id, "");
  else showError(id, `${what} not available: ${r.message}`);
  return r.ok;
}

function showSummary(s) {
  state.summary = s;
  $("cycle-index").textContent = `#${s.cycle_index}` + (isNum(s.t_start_s) ? ` (t = ${fmt(s.t_start_s, 1)} s)` : "");
  $("rpm").textContent = `${fmt(s.rpm_mean, 1)} rpm`;
  $("load").textContent = `${fmt(s.load_torque_nm, 0)} N·m, ${fmt(s.load_power_kw, 1)} kW`;
  $("friction-balance").textContent = `${fmt(s.friction_balance_nm, 1)} N·m`;
  $("cycle-flags").textContent = (s.flags || []).join(", ") || "none";
}

function showEngine(e) {
  if (!e) return;
  $("cycles-processed").textContent = String(e.cycles_ok);
  const skipped = Object.entries(e.skipped || {});
  const total = skipped.reduce((n, [, v]) => n + v, 0);
  const restarts = Object.entries(e.restarts || {}).map(([k, v]) => `${k.replaceAll("_", " ")}s: ${v}`);
  $("cycles-skipped").textContent = (total
    ? `${total} (${skipped.map(([k, v]) => `${k.replaceAll("_", " ")}: ${v}`).join(", ")})` : "0")
    + (restarts.length ? ` · ${restarts.join(", ")} (no cycle lost)` : "");
  showBacklog(e.backlog);
}

/** The monitor's backlog in words (format.js backlogWords), marked when /health would call the engine degraded. */
function showBacklog(b) {
  const box = $("backlog");
  const said = backlogWords(b);
  box.textContent = said.text;
  box.className = said.degraded ? "backlog-behind" : "";
  box.dataset.behind = b && b.behind ? "1" : "0";
}

function selectedEngine() {
  return state.engines.find((e) => e.engine_id === state.engineId);
}

async function refreshFigures() {
  const id = state.engineId;
  if (!id) return;
  const win = $("window-select").value;
  const [engines, losses] = await Promise.all([
    getJSON("api/v1/engines"),
    getJSON(enginePath(id, win ? `losses?window_cycles=${win}` : "losses")),
  ]);
  if (id !== state.engineId) return;  // the engine was changed while these were in flight
  if (engines.ok) { state.engines = engines.data; showEngine(selectedEngine()); }
  if (panelError("losses-error", "Per-cylinder figures", losses)) renderLosses(losses.data, state.summary);
}

async function refreshTraces() {
  const id = state.engineId;
  if (!id) return;
  const [torque, speed, health] = await Promise.all([
    getJSON(enginePath(id, "friction-torque")),
    getJSON(enginePath(id, "speed")),
    getJSON(enginePath(id, "sensor-health")),
  ]);
  if (id !== state.engineId) return;
  if (panelError("torque-error", "Friction torque", torque)) {
    renderTorque(torque.data, Number($("highlight-select").value) || null, $("show-total").checked);
  }
  if (panelError("speed-error", "Speed", speed)) renderSpeed(speed.data);
  if (panelError("health-error", "Sensor health", health)) renderHealth(health.data);
}

async function refreshLatest() {
  const r = await getJSON(enginePath(state.engineId, "cycles/latest"));
  if (r.ok && r.data.engine_id === state.engineId) showSummary(r.data);
}

async function refreshAlerts() {
  const id = state.engineId;
  if (!id) return;
  const r = await getJSON(enginePath(id, "alerts?state=all"));
  if (id !== state.engineId) return;
  if (r.ok) renderAlerts(r.data, acknowledge);
  else $("alerts-message").textContent = `Alerts not available: ${r.message}`;
}

const figures = throttle(refreshFigures, FIGURES_INTERVAL_MS);
const traces = throttle(refreshTraces, TRACES_INTERVAL_MS);
const plots = () => { figures(); traces(); };
const alerts = throttle(refreshAlerts, FIGURES_INTERVAL_MS);

async function acknowledge(alert, button) {
  const token = $("token").value.trim();  // sent as it is: the service alone decides (401 without a good one)
  button.disabled = true;
  const by = $("ack-by").value.trim();
  const r = await postWithToken(enginePath(state.engineId, `alerts/${alert.alert_id}/acknowledge`), token,
    by ? { by } : {});
  const what = `alert ${alert.alert_id} (${alert.kind.replaceAll("_", " ")})`;
  if (r.ok) $("alerts-message").textContent = `Acknowledged ${what}.`;
  else if (r.status === 401 || r.status === 403) {
    $("alerts-message").textContent = `Not acknowledged ${what}: `
      + (token ? `the service refused the token (HTTP ${r.status}).` : `the service needs its token (HTTP ${r.status}).`)
      + " Enter the token from the service's --token-file above.";
    $("token").focus();
  } else $("alerts-message").textContent = `Not acknowledged ${what}: ${r.message}`;
  button.disabled = false;
  alerts();
}

function connectStream() {
  if (state.es) state.es.close();
  const id = state.engineId;
  const es = new EventSource(`api/v1/stream?engine_id=${id}`);
  state.es = es;
  setLive("connecting");
  es.onopen = () => { state.connected = true; setLive("live"); };
  es.onerror = () => {
    state.connected = false;
    setLive("reconnecting");
    // the browser retries by itself unless the server refused the stream (CLOSED): then retry here
    if (es.readyState === EventSource.CLOSED && state.es === es) setTimeout(() => state.es === es && connectStream(), 3000);
  };
  es.addEventListener("cycle", (ev) => {
    let s;
    try { s = JSON.parse(ev.data); } catch { return; }  // a malformed event: the next one will do
    if (s.engine_id !== id) return;
    state.lastCycleAt = Date.now();
    state.cycleEvents += 1;
    if (state.startup) checkStartup();  // the first cycle: the start is over
    $("live").dataset.cycleEvents = state.cycleEvents;  // read by the browser test: the numbers came by the stream
    showSummary(s);
    setLive("live");
    plots();
  });
  es.addEventListener("alert", () => alerts());
}

function fillPickers() {
  const sel = $("engine-select");
  sel.replaceChildren(...state.engines.map((e) => new Option(`${e.engine_name} (${e.engine_id})`, e.engine_id)));
  sel.value = state.engineId;
  sel.hidden = state.engines.length < 2;
  const e = selectedEngine();
  $("engine-name").textContent = e.engine_name;
  $("engine-meta").textContent = `${e.engine_id} · ${e.n_cylinders} cylinders · ${(e.sources || []).join(", ")}`;
  document.title = `frictionwatch — ${e.engine_name}`;
  const hl = $("highlight-select");
  hl.replaceChildren(new Option("none", ""),
    ...Array.from({ length: e.n_cylinders }, (_, k) => new Option(`cylinder ${k + 1}`, String(k + 1))));
}

/** Nothing of the engine shown before stays on the page under another engine's name. */
function clearEngine() {
  for (const id of ["cycle-index", "cycles-processed", "cycles-skipped", "rpm", "load", "friction-balance",
    "engine-fmep", "active-alerts", "cycle-flags", "losses-window", "torque-cycle", "speed-cycle"]) {
    $(id).textContent = "—";
  }
  for (const id of ["losses-plot", "torque-plot", "speed-plot", "history-plot"]) emptyPlot($(id), "loading…");
  for (const id of ["losses-table", "alerts", "losses-notes", "health"]) {
    const box = $(id).tBodies ? $(id).tBodies[0] : $(id);
    box.replaceChildren();
  }
  $("alerts-message").textContent = "";
}

function chooseEngine(id) {
  state.engineId = id;
  state.summary = null;
  state.lastCycleAt = 0;
  state.startup = null;
  clearEngine();
  history.replaceState(null, "", `#engine=${id}`);
  fillPickers();
  showEngine(selectedEngine());
  connectStream();
  checkStartup();
  refreshLatest();
  plots();
  alerts();
}

/** The fleet panel: shown where the service keeps a store (health says ``fleet``); without one the fleet route
 *  answers 404, which is not asked (the browser would log it as an error). */
async function refreshFleet() {
  const panel = $("fleet-panel");
  const health = await getJSON("api/v1/health");
  if (!health.ok || !health.data.fleet) { panel.hidden = true; return; }
  const r = await getJSON("api/v1/fleet");
  panel.hidden = false;
  if (!r.ok) { showError("fleet-error", `Fleet not available: ${r.message}`); return; }
  showError("fleet-error", "");
  renderFleet(r.data, new Set(state.engines.map((e) => e.engine_id)));
}

async function start() {
  const r = await getJSON("api/v1/engines");
  if (!r.ok || !Array.isArray(r.data) || !r.data.length) {
    showError("load-error", r.ok ? "The service runs no engine." : `Engines not available: ${r.message}; retrying.`);
    setTimeout(start, 3000);
    return;
  }
  showError("load-error", "");
  state.engines = r.data;
  const wanted = new URLSearchParams(location.hash.slice(1)).get("engine");
  const ok = wanted && ENGINE_ID.test(wanted) && state.engines.some((e) => e.engine_id === wanted);
  chooseEngine(ok ? wanted : state.engines[0].engine_id);
}

function setup() {
  for (const [id, key] of [["token", TOKEN_KEY], ["ack-by", BY_KEY]]) {
    const input = $(id);
    input.value = sessionStorage.getItem(key) || "";
    input.addEventListener("input", () => sessionStorage.setItem(key, input.value));
  }
  $("engine-select").addEventListener("change", (ev) => chooseEngine(ev.target.value));
  $("window-select").addEventListener("change", () => figures());
  $("highlight-select").addEventListener("change", () => traces());
  $("show-total").addEventListener("change", () => traces());
  setInterval(() => {
    if (!state.engineId) return;
    if (state.connected) setLive("live");  // the "no cycle for N s" text
    if (Date.now() - state.lastCycleAt > POLL_MS) { refreshLatest(); plots(); }
    alerts();  // an alert's state may change (cleared, acknowledged elsewhere) without an event reaching us
  }, POLL_MS);
  setInterval(refreshFleet, POLL_MS);
  start().then(refreshFleet);
}

setup();
