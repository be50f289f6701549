// A machine page: its verdict, timelines of verdicts and probabilities, the evidence of its last windows, its
// sensors against what the model expected (…/expected) and as measured (…/sensors).
// Fed by /events/machine?id=<fleet>/<machine> (server-sent events: the machine each time it changes).
"use strict";
const ident = new URLSearchParams(location.search).get("id") || "";
const hw = window.hw = {updates: 0, firstRowsMs: null};
document.getElementById("name").textContent = ident;
document.title = "hydrowatch · " + ident;

function verdictSection(m) {
  const r = m.row;
  const since = clock(r.since_wall);
  document.getElementById("verdict").innerHTML = `<h2>Verdict</h2><div class="facts lvl-${r.level}">
    <span><span class="badge">${esc(r.state)}</span> p = ${r.p.toFixed(2)}</span>
    <span><b>since</b> ${since} (t = ${r.since_s.toFixed(1)} s, ${r.windows} windows received)</span>
    <span><b>last window</b> ends t = ${r.last_s.toFixed(1)} s</span>
    <span><b>model</b> ${esc(m.model_version)}</span>
    ${r.degradation ? `<span><b>degradation</b> ${degradationHtml(r.degradation)}</span>` : ""}</div>
    <p class="note">${esc(r.why)}</p>${componentsTable(r.components)}`;
}

// A cycles machine: each component's latest verdict (…/cycle_health), the evidence behind the machine's verdict.
function componentsTable(c) {
  if (!c) return "";
  const num = (x, d) => x == null ? "–" : Number(x).toFixed(d);
  return `<table id="components"><thead><tr><th>component</th><th>state</th><th>healthy state</th><th>p</th>
    <th>p (healthy)</th><th>novelty</th><th>since</th><th>label</th></tr></thead><tbody>` + c.map((x) =>
    `<tr class="lvl-${esc(x.level)}" data-component="${esc(x.component)}"><td>${esc(x.component)}</td>` +
    `<td><span class="badge">${esc(x.state)}</span></td><td>${esc(x.healthy ?? "–")}</td>` +
    `<td class="num">${num(x.p, 2)}</td><td class="num">${num(x.p_healthy, 2)}</td>` +
    `<td class="num">${num(x.novelty, 2)}</td><td>cycle ${x.since_cycle} (t = ${x.since_s.toFixed(0)} s)</td>` +
    `<td>${esc(x.truth ?? "")}</td></tr>`).join("") + "</tbody></table>";
}

function evidenceSection(m) {
  const box = document.getElementById("evidence");
  const ev = m.evidence;
  if (!ev.length && m.row.components) {
    box.innerHTML = `<p class="note">A cycles machine: the evidence is each component's probability and novelty
      (above; novelty above 1: no trained state explains the cycle, 'unknown').</p>`;
    return;
  }
  if (!ev.length) {
    box.innerHTML = `<p class="note">No evidence message (…/kl) for this machine yet: the scorer publishes one per
      judged window (none for invalid windows).</p>`;
    return;
  }
  const last = ev[ev.length - 1];
  const rows = Object.keys(last.scores);
  const states = Object.keys(last.scores[rows[0]]);
  const verdict = m.row.state;
  const values = rows.flatMap((s) => states.map((k) => last.scores[s][k]));
  // shade on a log scale from the smallest to the largest score (a score of 0 counts as 1e-9)
  const lo = Math.max(Math.min(...values), 1e-9), hi = Math.max(...values, lo);
  const share = (v) => Math.min(1, Math.max(0, Math.log(Math.max(v, lo) / lo) / (Math.log(hi / lo) || 1)));
  const shade = (v) => `rgba(198,40,40,${(0.08 + 0.6 * share(v)).toFixed(2)})`;
  let html = `<p class="note">Last window ${last.window_start.toFixed(1)}–${last.window_end.toFixed(1)} s: how far the
    window's residuals are from each trained state's, per sensor or relation (smaller = closer; relative entropy in
    nats for entropy models, relation score F for parity models). The verdict's state is outlined.</p>
    <table class="heat"><thead><tr><th></th>${states.map((k) => `<th>${esc(k)}</th>`).join("")}</tr></thead><tbody>`;
  for (const s of rows) {
    html += `<tr><th>${esc(s)}</th>` + states.map((k) => {
      const v = last.scores[s][k];
      const mark = k === verdict ? ' style="outline:2px solid #1d2329;background:' + shade(v) + '"' : ` style="background:${shade(v)}"`;
      return `<td${mark}>${v.toPrecision(3)}</td>`;
    }).join("") + "</tr>";
  }
  html += `</tbody></table><h2 style="margin-top:10px">Last ${ev.length} windows: score of each sensor or relation against
    "${esc(states.includes(verdict) ? verdict : states[0])}"</h2><div id="evidence-lines"></div><div class="legend" id="e-legend"></div>`;
  box.innerHTML = html;
  const against = states.includes(verdict) ? verdict : states[0];
  const xs = ev.map((w) => w.window_end);
  const series = Object.fromEntries(rows.map((s) => [s, ev.map((w) => (w.scores[s] || {})[against] ?? null)]));
  const all = Object.values(series).flat().filter((v) => v != null && v > 0);
  const entries = lineChart(document.getElementById("evidence-lines"), xs, series,
    {y0: Math.min(...all), y1: Math.max(...all), height: 120, log: true});
  legend(document.getElementById("e-legend"), entries);
}

const ORDER = ["voltage", "flow", "speed", "torque", "temperature", "supply_pressure", "load_pressure"];
const rank = (n) => (ORDER.includes(n) ? ORDER.indexOf(n) : ORDER.length);
const byChannel = (a, b) => rank(a) - rank(b) || a.localeCompare(b);

function sensorsSection(m) {
  const box = document.getElementById("sensors");
  const s = m.sensors;
  if (!s || !s.t.length) {
    box.innerHTML = `<p class="note">No samples yet: the service follows this machine's sensors (…/sensors) from the
      moment its page opens.</p>`;
    return;
  }
  const names = Object.keys(s.channels).sort(byChannel);
  box.innerHTML = names.map((n) => `<div class="sensor"><div class="note">${esc(n)} [${esc(s.units[n])}]</div>` +
    `<div id="sensor-${esc(n)}"></div></div>`).join("");
  for (const n of names) {
    const values = s.channels[n].filter((v) => v != null);
    lineChart(document.getElementById("sensor-" + n), s.t, {[n]: s.channels[n]},
      {y0: Math.min(...values), y1: Math.max(...values), height: 80, marks: m.timeline.end_s});
  }
}

// Each sensor the model predicts: measured and expected over the last windows (0.1 s means from the scorer).
function expectedSection(m) {
  const box = document.getElementById("expected");
  const x = m.expected;
  if (!x || !Object.keys(x).length) {
    box.innerHTML = `<p class="note">Nothing yet: the scorer publishes what the model expected (…/expected) for each
      window it judges; the service follows this machine's from the moment its page opens (one window, 5 s). Models
      that predict no sensor (stats) publish none.</p>`;
    legend(document.getElementById("x-legend"), []);
    return;
  }
  const names = Object.keys(x).sort(byChannel);
  box.innerHTML = names.map((n) => `<div class="sensor" data-sensor="${esc(n)}"><div class="note">${esc(n)}
    [${esc(x[n].unit)}]: expected by the ${esc(x[n].source)}</div><div id="expected-${esc(n)}"></div></div>`).join("");
  let entries = [];
  for (const n of names) {
    const s = x[n];
    const values = [...s.measured, ...s.expected].filter((v) => v != null);
    entries = lineChart(document.getElementById("expected-" + n), s.t, {measured: s.measured, expected: s.expected},
      {y0: Math.min(...values), y1: Math.max(...values), height: 100, marks: m.timeline.end_s,
        dashes: {expected: "6 3"}});
  }
  legend(document.getElementById("x-legend"), entries);
}

function draw(m) {
  verdictSection(m);
  const t = m.timeline;
  stateBand(document.getElementById("states"), t);
  const seen = [...new Set(t.level)];
  legend(document.getElementById("state-legend"), seen.map((l) => [l, LEVEL_COLOURS[l]]));
  document.getElementById("p-title").textContent = m.row.components ? "Probability of each component's healthy state"
    : "Probability of each trained state";
  const entries = lineChart(document.getElementById("probabilities"), t.end_s, t.probabilities);
  legend(document.getElementById("p-legend"), entries);
  evidenceSection(m);
  expectedSection(m);
  sensorsSection(m);
  hw.updates += 1;
  if (hw.firstRowsMs === null) requestAnimationFrame(() => { hw.firstRowsMs = performance.now(); });
}

const source = new EventSource("/events/machine?id=" + encodeURIComponent(ident));
showConnection(source);
source.onmessage = (e) => draw(JSON.parse(e.data));
