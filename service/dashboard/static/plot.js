// Plain SVG plots: a bar chart with ±1σ whiskers and status words, and x-y line plots. No library: the plant's
// network is air-gapped and the page has no build step. Every axis carries its label and unit.

const NS = "http://www.w3.org/2000/svg";

export function el(tag, attrs = {}, parent = null, text = null) {
  const node = document.createElementNS(NS, tag);
  for (const [k, v] of Object.entries(attrs)) if (v !== null && v !== undefined) node.setAttribute(k, String(v));
  if (text !== null) node.textContent = text;
  if (parent) parent.appendChild(node);
  return node;
}

/** About n round tick values covering [lo, hi], and the step between them. */
export function ticks(lo, hi, n = 6) {
  if (!(hi > lo)) return { values: [lo], step: 1 };
  const raw = (hi - lo) / n;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((s) => s >= raw);
  const values = [];
  for (let t = Math.ceil(lo / step) * step; t <= hi + step * 1e-9; t += step) values.push(+t.toFixed(12));
  return { values, step };
}

/** A tick's text with as many decimals as the step needs (2.5 -> 1 decimal, 0.05 -> 2, 200 -> none). */
function tickText(t, step) {
  const dec = Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9) + (String(step).includes("25") ? 1 : 0)));
  return t.toFixed(dec);
}

/** Clears an svg and draws axes for [x0,x1] x [y0,y1]; returns the two scale functions and the plot box. */
function frame(svg, { width, height, x0, x1, y0, y1, xLabel, yLabel, margin, xTicks = true }) {
  svg.replaceChildren();
  svg.setAttribute("viewBox", `0 0 ${width} ${height}`);
  const m = { left: 70, right: 14, top: 12, bottom: 42, ...margin };
  const w = width - m.left - m.right, h = height - m.top - m.bottom;
  const sx = (x) => m.left + ((x - x0) / (x1 - x0 || 1)) * w;
  const sy = (y) => m.top + h - ((y - y0) / (y1 - y0 || 1)) * h;
  const yt = ticks(y0, y1, 5);
  for (const t of yt.values) {
    el("line", { x1: m.left, x2: m.left + w, y1: sy(t), y2: sy(t), class: "grid" }, svg);
    el("text", { x: m.left - 6, y: sy(t) + 4, "text-anchor": "end" }, svg, tickText(t, yt.step));
  }
  if (xTicks) {
    const xt = ticks(x0, x1, 8);
    for (const t of xt.values) {
      el("line", { x1: sx(t), x2: sx(t), y1: m.top + h, y2: m.top + h + 4, class: "axis" }, svg);
      el("text", { x: sx(t), y: m.top + h + 16, "text-anchor": "middle" }, svg, tickText(t, xt.step));
    }
  }
  el("line", { x1: m.left, x2: m.left + w, y1: m.top + h, y2: m.top + h, class: "axis" }, svg);
  el("line", { x1: m.left, x2: m.left, y1: m.top, y2: m.top + h, class: "axis" }, svg);
  el("text", { x: m.left + w / 2, y: height - 6, "text-anchor": "middle", class: "axis-label" }, svg, xLabel);
  el("text", { x: 14, y: m.top + h / 2, "text-anchor": "middle", class: "axis-label",
    transform: `rotate(-90 14 ${m.top + h / 2})` }, svg, yLabel);
  return { sx, sy, m, w, h };
}

export function emptyPlot(svg, message, width = 700, height = 120) {
  svg.replaceChildren();
  svg.setAttribute("viewBox", `0 0 ${width} ${height}`);
  el("text", { x: width / 2, y: height / 2, "text-anchor": "middle", class: "empty" }, svg, message);
}

function range(arrays, pad = 0.05) {
  let lo = Infinity, hi = -Infinity;
  for (const a of arrays) for (const v of a) if (Number.isFinite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
  if (!Number.isFinite(lo)) return null;
  const span = hi - lo || Math.abs(hi) || 1;
  return [lo - pad * span, hi + pad * span];
}

/** series: [{x: [..], y: [..], cls, label}] drawn in order (later on top); NaN/null breaks a line.
 *  legend: [{cls, label}] laid out in a row above the plot. */
export function linePlot(svg, { series, xLabel, yLabel, legend = [], width = 700, height = 320, xRange = null }) {
  const xr = xRange || range(series.map((s) => s.x), 0);
  const yr = range(series.map((s) => s.y));
  if (!xr || !yr) return emptyPlot(svg, "no data yet", width, height);
  const { sx, sy, m } = frame(svg, { width, height, x0: xr[0], x1: xr[1], y0: yr[0], y1: yr[1], xLabel, yLabel,
    margin: { top: legend.length ? 30 : 12 } });
  for (const s of series) {
    let d = "", pen = "M";
    for (let i = 0; i < s.x.length; i++) {
      const x = s.x[i], y = s.y[i];
      if (!Number.isFinite(x) || !Number.isFinite(y)) { pen = "M"; continue; }
      d += `${pen}${sx(x).toFixed(1)},${sy(y).toFixed(1)}`;
      pen = "L";
    }
    const path = el("path", { d, class: s.cls }, svg);
    if (s.label) el("title", {}, path, s.label);
  }
  let x = m.left;
  for (const it of legend) {
    el("line", { x1: x, x2: x + 24, y1: 12, y2: 12, class: it.cls }, svg);
    const t = el("text", { x: x + 30, y: 16 }, svg, it.label);
    x += 40 + 6.5 * it.label.length;
    t.dataset.legend = it.label;
  }
  return null;
}

const DRAWN = new Set(["measured", "share", "prior"]);

/** bars: [{cylinder, value, sigma, status}]; a bar is drawn only for a value whose status has one (measured solid,
 *  share and prior hatched); each slot carries its number and its status word, so nothing rests on colour. */
export function barPlot(svg, { bars, yLabel, unit, width = 1200, height = 350 }) {
  const shown = bars.filter((b) => DRAWN.has(b.status) && Number.isFinite(b.value));
  const tops = shown.map((b) => b.value + (Number.isFinite(b.sigma) ? b.sigma : 0));
  const bottoms = shown.map((b) => b.value - (Number.isFinite(b.sigma) ? b.sigma : 0));
  const y0 = Math.min(0, ...bottoms), y1 = Math.max(0.1, ...tops) * 1.18;
  const { sx, sy, m, h } = frame(svg, { width, height, x0: 0, x1: bars.length, y0, y1, xLabel: "cylinder",
    yLabel, margin: { bottom: 104 }, xTicks: false });
  const defs = el("defs", {}, svg);
  for (const [id, angle] of [["share", 45], ["prior", -45]]) {
    const p = el("pattern", { id: `hatch-${id}`, width: 6, height: 6, patternUnits: "userSpaceOnUse",
      patternTransform: `rotate(${angle})` }, defs);
    el("rect", { width: 6, height: 6, fill: "#fff" }, p);
    el("line", { x1: 0, y1: 0, x2: 0, y2: 6, class: `hatch-${id}` }, p);
  }
  const slot = sx(1) - sx(0);
  const bw = Math.min(46, slot * 0.62);
  bars.forEach((b, i) => {
    const g = el("g", { class: "bar", "data-cylinder": b.cylinder, "data-status": b.status }, svg);
    const cx = sx(i + 0.5);
    const valueText = Number.isFinite(b.value) ? b.value.toFixed(3) : "—";
    el("title", {}, g, `cylinder ${b.cylinder}: ${valueText}${Number.isFinite(b.value) ? " " + unit : ""}`
      + (Number.isFinite(b.sigma) ? ` ± ${b.sigma.toFixed(3)} ${unit}` : "") + ` (${b.status})`);
    let labelY;
    if (DRAWN.has(b.status) && Number.isFinite(b.value)) {
      const yTop = sy(Math.max(b.value, 0)), yBase = sy(Math.min(b.value, 0));
      el("rect", { x: cx - bw / 2, y: yTop, width: bw, height: Math.max(1, yBase - yTop),
        class: `bar-${b.status}`, fill: b.status === "measured" ? null : `url(#hatch-${b.status})` }, g);
      labelY = yTop - 4;
      if (Number.isFinite(b.sigma)) {
        const ya = sy(b.value + b.sigma), yb = sy(b.value - b.sigma);
        el("line", { x1: cx, x2: cx, y1: ya, y2: yb, class: "whisker" }, g);
        for (const y of [ya, yb]) el("line", { x1: cx - bw / 4, x2: cx + bw / 4, y1: y, y2: y, class: "whisker" }, g);
        labelY = ya - 4;
      }
    } else {
      el("rect", { x: cx - bw / 2, y: sy(y1 * 0.25), width: bw, height: sy(0) - sy(y1 * 0.25), class: "bar-missing" }, g);
      labelY = sy(y1 * 0.25) - 4;
    }
    const vertical = slot < 40;
    el("text", { x: cx, y: labelY, "text-anchor": vertical ? "start" : "middle", class: "bar-value",
      transform: vertical ? `rotate(-90 ${cx + 3} ${labelY})` : null }, g, valueText);
    el("text", { x: cx, y: m.top + h + 15, "text-anchor": "middle", class: "bar-cylinder" }, g, String(b.cylinder));
    const sy0 = m.top + h + 24;
    el("text", { x: cx + 3, y: sy0, "text-anchor": "end", transform: `rotate(-90 ${cx + 3} ${sy0})`,
      class: `status-word status-${b.status}` }, g, b.status);
  });
  if (y0 < 0) el("line", { x1: m.left, x2: sx(bars.length), y1: sy(0), y2: sy(0), class: "axis" }, svg);
}
