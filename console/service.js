// The service at a glance: health and readiness, the store and its objects, the model
// cache and the estimate queue, and per endpoint the requests, errors, rate and latency
// percentiles, all read from the server (/metrics needs the admin scope). Refreshed every
// 5 s while the section is shown.

import * as api from "./api.js";
import { $, el, facts, size } from "./dom.js";

let timer = null;
let previous = null; // {at, counts} of the last /metrics read, for the request rates

export function init() {
  $("service-refresh").addEventListener("click", refresh);
}

export function shown() {
  refresh();
  clearInterval(timer);
  timer = setInterval(() => ($("service").hidden ? clearInterval(timer) : refresh()), 5000);
}

async function text(path) {
  try {
    return await api.call("GET", path);
  } catch (e) {
    return `${e.message}`;
  }
}

async function refresh() {
  const [health, ready, objects] = await Promise.all([text("/healthz"), text("/readyz"), api.call("GET", "/v1/objects").catch((e) => e)]);
  let metrics = null;
  let why = "";
  try {
    metrics = parse(await api.call("GET", "/metrics"));
  } catch (e) {
    why = e.status === 403 ? `Request figures need a key with the admin scope: ${e.message}` : `Metrics: ${e.message}`;
  }
  const c = api.session.caller;
  const g = (name) => (metrics ? metrics.value(name) : undefined);
  const pairs = [
    ["Health", health],
    ["Readiness", ready],
    ["Objects in the store", objects instanceof Error ? objects.message : String(objects.objects.length)],
    ["Server", c?.read_only ? "read-only replica" : "writer"],
    ["API keys", c?.keys_required ? "required" : "none configured"],
  ];
  if (metrics) {
    pairs.push(
      ["Objects in memory", `${g("b2tf_objects_loaded")} (${size(g("b2tf_cache_bytes"))})`],
      ["Estimates running / waiting", `${g("b2tf_estimates_running")} / ${g("b2tf_estimate_queue_length")}`],
      ["Mean estimate time", g("b2tf_estimate_service_seconds") === undefined ? "–" : `${(g("b2tf_estimate_service_seconds") * 1000).toFixed(0)} ms`],
      ["Onboardings running", String(g("b2tf_onboardings_running"))],
      ["Tracking sessions", String(g("b2tf_track_sessions_open"))],
    );
  }
  $("service-status").replaceChildren(facts(pairs));
  $("service-metrics-note").textContent = why;
  $("service-requests").tBodies[0].replaceChildren(...(metrics ? requestRows(metrics) : []));
}

function requestRows(m) {
  const now = performance.now();
  const rows = [];
  const counts = {};
  for (const [endpoint, byStatus] of m.requests) {
    // The console's own files are not the API's traffic.
    if (/^GET (\/|\/console.*)$/.test(endpoint)) continue;
    const total = [...byStatus.values()].reduce((a, b) => a + b, 0);
    const errors = [...byStatus].filter(([s]) => Number(s) >= 400).reduce((a, [, n]) => a + n, 0);
    counts[endpoint] = total;
    const rate = previous && endpoint in previous.counts ? ((total - previous.counts[endpoint]) * 60000) / (now - previous.at) : null;
    const buckets = m.latency.get(endpoint) ?? [];
    const ms = (q) => {
      const s = quantile(buckets, q);
      return s === null ? "–" : (s * 1000).toFixed(0);
    };
    rows.push(el("tr", {}, el("td", {}, endpoint), el("td", {}, String(total)), el("td", {}, String(errors)), el("td", {}, rate === null ? "–" : rate.toFixed(1)), el("td", {}, ms(0.5)), el("td", {}, ms(0.9)), el("td", {}, ms(0.99))));
  }
  previous = { at: now, counts };
  return rows;
}

// The q-quantile of a Prometheus histogram (cumulative [bound, count] pairs, +Inf last),
// interpolated linearly inside its bucket as Prometheus does; null when empty.
export function quantile(buckets, q) {
  const total = buckets.length ? buckets[buckets.length - 1][1] : 0;
  if (!total) return null;
  const rank = q * total;
  let [lowBound, lowCount] = [0, 0];
  for (const [bound, count] of buckets) {
    if (count >= rank) {
      if (!Number.isFinite(bound)) return lowBound;
      return lowBound + ((bound - lowBound) * (rank - lowCount)) / Math.max(count - lowCount, 1e-9);
    }
    [lowBound, lowCount] = [bound, count];
  }
  return lowBound;
}

// The Prometheus text format, as much of it as this page reads.
export function parse(textBody) {
  const values = new Map();
  const requests = new Map(); // "METHOD route" -> Map(status -> count)
  const latency = new Map(); // "METHOD route" -> [[le, cumulative count]]
  for (const line of textBody.split("\n")) {
    // Label values hold route templates with braces ("/v1/objects/{id}"): the label
    // block runs to the last "}" before the value.
    const m = /^([a-zA-Z_:][\w:]*)(?:\{(.*)\})?\s+(\S+)$/.exec(line.trim());
    if (!m) continue;
    const [, name, labelText = "", v] = m;
    const labels = Object.fromEntries([...labelText.matchAll(/(\w+)="([^"]*)"/g)].map((x) => [x[1], x[2]]));
    const value = Number(v);
    if (name === "b2tf_requests_total") {
      const key = `${labels.method} ${labels.route}`;
      if (!requests.has(key)) requests.set(key, new Map());
      requests.get(key).set(labels.status, value);
    } else if (name === "b2tf_request_seconds_bucket") {
      const key = `${labels.method} ${labels.route}`;
      if (!latency.has(key)) latency.set(key, []);
      latency.get(key).push([labels.le === "+Inf" ? Infinity : Number(labels.le), value]);
    } else if (!labelText) values.set(name, value);
  }
  return { requests, latency, value: (name) => values.get(name) };
}
