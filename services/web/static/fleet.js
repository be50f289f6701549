// The fleet page: one row per machine, most urgent first, updated in place from /events (server-sent events).
// The server decides order, levels and filters (hydrowatch.web.live); this script only draws what it is sent.
"use strict";
const LEVELS = ["alert", "unknown", "warning", "invalid", "healthy"];
const tbody = document.getElementById("rows");
const rows = new Map();   // id -> row as sent
const trs = new Map();    // id -> <tr>
let order = [];
let source = null;
let pending = [];
let anyDegradation = false;
// what tests and the benchmark read: first rows drawn (ms after navigation), every update's lag
const hw = window.hw = {seq: -1, snapshots: 0, firstRowsMs: null, lags: [], applied: 0};


function degradationHtml(d) {
  if (!d) return "";
  return Object.entries(d).map(([fault, v]) => {
    const value = typeof v === "object" ? v.value : v;
    const ci = v && v.ci95 ? ` [${v.ci95[0].toFixed(2)}–${v.ci95[1].toFixed(2)}]` : "";
    const trend = v && v.rate_per_h != null ? ` ${v.rate_per_h >= 0 ? "↑" : "↓"}${Math.abs(v.rate_per_h).toFixed(2)}/h` : "";
    const alert = v && v.alert_in_s != null ? ` alert in ${(v.alert_in_s / 3600).toFixed(1)} h` : "";
    return `<span class="deg">${esc(fault)} ${Number(value).toFixed(2)}${ci}${trend}${alert}</span>`;
  }).join("");
}

function cells(r) {
  const href = "/machine?id=" + encodeURIComponent(r.id);
  return `<td><a href="${href}">${esc(r.machine)}</a></td><td>${esc(r.fleet)}</td>` +
    `<td><span class="badge">${esc(r.state)}</span></td><td class="num">${r.p.toFixed(2)}</td>` +
    `<td>${clock(r.since_wall)} <span class="note">(t = ${r.since_s.toFixed(1)} s)</span></td>` +
    `<td class="num">${r.last_s.toFixed(1)}</td><td class="num">${r.windows}</td>` +
    `<td class="degcol"${anyDegradation ? "" : " hidden"}>${degradationHtml(r.degradation)}</td>` +
    `<td class="why">${esc(r.why)}</td>`;
}

function trHtml(r) {
  return `<tr class="lvl-${r.level}" data-id="${esc(r.id)}">${cells(r)}</tr>`;
}

function setOptions(select, values, fixed) {
  const want = [...fixed, ...values.filter((v) => !fixed.some(([k]) => k === v)).map((v) => [v, v])];
  const key = want.map(([k]) => k).join("\n");
  if (select.dataset.key === key) return;
  const current = select.dataset.key === undefined ? new URLSearchParams(location.search).get(select.id) || ""
    : select.value;
  select.innerHTML = want.map(([k, label]) => `<option value="${esc(k)}">${esc(label)}</option>`).join("");
  select.value = current;
  select.dataset.key = key;
}

function drawHeader(m) {
  document.getElementById("counts").innerHTML = LEVELS.map((l) =>
    `<button class="chip ${l}${m.counts[l] ? "" : " zero"}" data-level="${l}" title="show ${l} only">${m.counts[l]} ${l}</button>`
  ).join("");
  setOptions(document.getElementById("state"), m.states,
    [["", "every state"], ["attention", "needs attention"], ...LEVELS.map((l) => [l, "level: " + l])]);
  setOptions(document.getElementById("fleet"), m.fleets, [["", "every fleet"]]);
}

function apply(m) {
  if (m.snapshot) {
    rows.clear();
    trs.clear();
    hw.snapshots += 1;
  }
  if (!anyDegradation && m.rows.some((r) => r.degradation)) {
    anyDegradation = true;
    document.querySelectorAll("th.degcol").forEach((th) => { th.hidden = false; });
    for (const [id, tr] of trs) tr.innerHTML = cells(rows.get(id));
  }
  if (m.snapshot) {
    for (const r of m.rows) rows.set(r.id, r);
    tbody.innerHTML = m.order.map((id) => trHtml(rows.get(id))).join("");
    for (const tr of tbody.children) trs.set(tr.dataset.id, tr);
    order = m.order;
  } else {
    for (const r of m.rows) {
      rows.set(r.id, r);
      let tr = trs.get(r.id);
      if (!tr) { tr = document.createElement("tr"); tr.dataset.id = r.id; trs.set(r.id, tr); }
      tr.className = "lvl-" + r.level;
      tr.innerHTML = cells(r);
    }
    if (m.order) {
      order = m.order;
      const fragment = document.createDocumentFragment();
      for (const id of order) fragment.appendChild(trs.get(id));
      tbody.replaceChildren(fragment);
      for (const id of trs.keys()) if (!tbody.contains(trs.get(id))) trs.delete(id);
    }
  }
  drawHeader(m);
  document.getElementById("shown").textContent = `${order.length} shown`;
  document.getElementById("empty").hidden = order.length > 0;
  hw.seq = m.seq;
}

function flush() {
  const batch = pending;
  pending = [];
  for (const m of batch) apply(m);
  hw.applied += batch.length;
  // measured after the browser has laid out and painted what changed
  requestAnimationFrame(() => setTimeout(() => {
    const now = Date.now();
    for (const m of batch) {
      for (const r of m.rows) if (r.published_ms && !m.snapshot) hw.lags.push(now - r.published_ms);
      if (m.snapshot && m.order.length && hw.firstRowsMs === null) hw.firstRowsMs = performance.now();
    }
  }, 0));
}

function connect(first) {
  if (source) source.close();
  const params = new URLSearchParams();
  for (const id of ["state", "fleet"]) {
    const v = first === true ? new URLSearchParams(location.search).get(id) : document.getElementById(id).value;
    if (v) params.set(id, v);
  }
  history.replaceState(null, "", params.toString() ? "?" + params : location.pathname);
  source = new EventSource("/events?" + params);
  showConnection(source);
  source.onmessage = (e) => {
    if (!pending.length) requestAnimationFrame(flush);
    pending.push(JSON.parse(e.data));
  };
}

for (const id of ["state", "fleet"]) document.getElementById(id).addEventListener("change", connect);
document.getElementById("counts").addEventListener("click", (e) => {
  const level = e.target.dataset && e.target.dataset.level;
  if (!level) return;
  const select = document.getElementById("state");
  select.value = select.value === level ? "" : level;
  connect();
});
connect(true);
