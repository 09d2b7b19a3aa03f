// The service's HTTP API (prefix api/v1, relative to the page so a reverse proxy may mount it under a path).
// Every call resolves to {ok, status, data, message}: an HTTP error is a state to show in words, not an exception.

export const ENGINE_ID = /^[a-z0-9-]{1,40}$/;  // the contract's slug; anything else never reaches a URL

export function enginePath(engineId, rest) {
  if (!ENGINE_ID.test(engineId)) throw new Error(`not an engine id: ${engineId}`);
  return `api/v1/engines/${engineId}/${rest}`;
}

function detailOf(body) {
  if (!body) return "";
  if (typeof body.detail === "string") return body.detail;
  if (Array.isArray(body.detail)) return body.detail.map((d) => d.msg || JSON.stringify(d)).join("; ");
  return "";
}

async function call(path, init) {
  let resp;
  try {
    resp = await fetch(path, { cache: "no-store", ...init });
  } catch (err) {
    return { ok: false, status: 0, data: null, message: "the service cannot be reached" };
  }
  let body = null;
  try { body = await resp.json(); } catch { body = null; }
  if (resp.ok) return { ok: true, status: resp.status, data: body, message: "" };
  const detail = detailOf(body);
  return { ok: false, status: resp.status, data: body, message: `HTTP ${resp.status}${detail ? ": " + detail : ""}` };
}

export const getJSON = (path) => call(path, { method: "GET" });

export function postWithToken(path, token, body = {}) {
  const headers = { "Content-Type": "application/json" };
  if (token) headers.Authorization = `Bearer ${token}`;
  return call(path, { method: "POST", headers, body: JSON.stringify(body) });
}

/** Runs fn at most once per `ms`: requests made while a run is scheduled share it; one made while fn runs
 *  schedules one more run after it, so the last request is never lost. */
export function throttle(fn, ms) {
  let last = 0, timer = null, running = false, pending = false;
  const schedule = () => { timer = setTimeout(run, Math.max(0, last + ms - Date.now())); };
  async function run() {
    timer = null;
    running = true;
    last = Date.now();
    try { await fn(); } finally {
      running = false;
      if (pending) { pending = false; schedule(); }
    }
  }
  return function request() {
    if (running) pending = true;
    else if (!timer) schedule();
  };
}
