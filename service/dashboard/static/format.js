// Numbers and units as the page prints them. The API carries the unit in each field's name (docs: contract of
// issue #17); unitOf reads it back so a value is never printed without its unit.

const SUFFIX_UNITS = [  // longest suffix first: "_rad_s" before "_s"
  ["_rad_s", "rad/s"], ["_bar", "bar"], ["_nm", "N·m"], ["_rpm", "rpm"], ["_deg", "°"], ["_kw", "kW"],
  ["_pct", "%"], ["_s", "s"],
];

/** The unit named by a field's suffix, and the name without it: "fmep_baseline_bar" -> ["fmep baseline", "bar"]. */
export function unitOf(key) {
  for (const [suffix, unit] of SUFFIX_UNITS) {
    if (key.endsWith(suffix) && key.length > suffix.length) {
      return [key.slice(0, -suffix.length).replaceAll("_", " "), unit];
    }
  }
  return [key.replaceAll("_", " "), ""];
}

export function isNum(v) {
  return typeof v === "number" && Number.isFinite(v);
}

/** A number with a fixed count of decimals, or "—" where there is none (null, NaN: the API's "no value"). */
export function fmt(v, digits = 3) {
  return isNum(v) ? v.toFixed(digits) : "—";
}

/** Enough decimals to show about four significant figures, at most six. */
export function fmtAuto(v) {
  if (!isNum(v)) return "—";
  const mag = Math.abs(v) > 0 ? Math.floor(Math.log10(Math.abs(v))) : 0;
  return v.toFixed(Math.min(6, Math.max(0, 3 - mag)));
}

export function withUnit(text, unit) {
  return text === "—" || !unit ? text : `${text} ${unit}`;
}

/** A value of unknown shape as text: numbers with their key's unit; a long list of cycle indices shortened. */
export function describeValue(key, value) {
  const [, unit] = unitOf(key);
  if (value === null || value === undefined) return "—";
  if (isNum(value)) return withUnit(Number.isInteger(value) ? String(value) : fmtAuto(value), unit);
  if (Array.isArray(value)) {
    const items = value.map((v) => (isNum(v) && !Number.isInteger(v) ? fmtAuto(v) : String(v)));
    const shown = items.length > 16 ? [...items.slice(0, 10), "…", ...items.slice(-5)] : items;
    return withUnit(shown.join(", "), unit) + (items.length > 16 ? ` (${items.length} values)` : "");
  }
  if (typeof value === "object") {
    return Object.entries(value).map(([k, v]) => `${unitOf(k)[0]}: ${describeValue(k, v)}`).join("; ");
  }
  return String(value);
}

/** The monitor's backlog (GET /engines' `backlog`) in words: cycles waiting, seconds behind, what the bounded queue
 * dropped, and a warm-up's hold (a board's input kept while the kernels compiled, analysed after). ``degraded``: as
 * /health would say it; an engine catching up on a hold that dropped nothing is starting, not degraded. */
export function backlogWords(b) {
  if (!b) return { text: "—", degraded: false };
  const cycles = isNum(b.queued_cycles) ? `${fmt(b.queued_cycles, 0)} cycles` : `${fmt(b.queued_s, 1)} s of data`;
  const dropped = b.dropped_records ? `; dropped ${isNum(b.dropped_cycles) ? `~${fmt(b.dropped_cycles, 0)} cycles`
    : `${b.dropped_records} records`} to keep up` : "";
  const held = b.held_s > 0 ? `; ${b.holding ? "holding" : "held"} the board's input while the kernels warmed up `
    + `(up to ${fmt(b.held_s, 1)} s, ${fmt(b.held_bytes / 1e6, 0)} MB)${b.holding ? ": catching up" : ""}` : "";
  const starting = Boolean(b.holding) && !b.dropped_records;
  return { text: `${cycles} queued, ${fmt(b.behind_s, 1)} s behind${dropped}${held}`,
           degraded: Boolean(b.behind) && !starting };
}
