// The fleet page: one row per machine, most urgent first, updated in place from /events (server-sent events).
// The server decides order, levels and filters (hydrowatch.web.live); this script only draws what it is sent.
// Only the rows in view (and a margin) are in the table: spacer rows stand for the others, so that a page of
// 1000 machines lays out and paints ~60 rows per update instead of 1000.
"use strict";
const LEVELS = ["alert", "unknown", "warning", "invalid", "healthy"];
const MARGIN = 20;        // rows drawn above and below the view
const table = document.getElementById("fleet-table");
const tbody = document.getElementById("rows");
const rows = new Map();   // id -> row as sent
const html = new Map();   // id -> its <tr> markup (made again when the row changes)
let order = [];
let rowHeight = 0;
let drawn = "";
let source = null;
let pending = [];
let anyDegradation = false;
let anyComponents = false;  // a rig's cycles machine shown: the components column appears
// what tests and the benchmark read: first rows drawn (ms after navigation), every update's lag
const hw = window.hw = {seq: -1, snapshots: 0, firstRowsMs: null, lags: [], applied: 0, shown: 0};

function cells(r) {
  const href = "/machine?id=" + encodeURIComponent(r.id);
  return `<td><a href="${href}">${esc(r.machine)}</a></td><td>${esc(r.fleet)}</td>` +
    `<td><span class="badge">${esc(r.state)}</span></td><td class="num">${r.p.toFixed(2)}</td>` +
    `<td>${clock(r.since_wall)} <span class="note">(t = ${r.since_s.toFixed(1)} s)</span></td>` +
    `<td class="num">${r.last_s.toFixed(1)}</td><td class="num">${r.windows}</td>` +
    `<td class="degcol"${anyDegradation ? "" : " hidden"}>${degradationHtml(r.degradation)}</td>` +
    `<td class="compcol"${anyComponents ? "" : " hidden"}>${componentsHtml(r.components)}</td>` +
    `<td class="why">${esc(r.why)}</td>`;
}

function trHtml(id) {
  let h = html.get(id);
  if (h === undefined) {
    const r = rows.get(id);
    h = `<tr class="lvl-${r.level}" data-id="${esc(r.id)}">${cells(r)}</tr>`;
    html.set(id, h);
  }
  return h;
}

// Draw the rows in view; the spacers keep the table as tall as all rows would make it.
let tableTop = null;  // document offset of the first row, px (measured once, again on resize)
function draw() {
  if (tableTop === null) tableTop = table.getBoundingClientRect().top + window.scrollY + table.tHead.offsetHeight;
  const top = tableTop;
  const h = rowHeight || 27;
  const count = Math.ceil(window.innerHeight / h) + 2 * MARGIN;
  // (clamped: the view may lie past the end of a list that just got shorter)
  const first = Math.max(0, Math.min(Math.floor((window.scrollY - top) / h) - MARGIN, order.length - count));
  const last = Math.min(order.length, first + count);
  const columns = 8 + anyDegradation + anyComponents;
  const spacer = (n) => `<tr class="spacer"><td colspan="${columns}" style="height:${n * h}px"></td></tr>`;
  let out = first ? spacer(first) : "";
  for (let i = first; i < last; i++) out += trHtml(order[i]);
  if (last < order.length) out += spacer(order.length - last);
  if (out !== drawn) {
    tbody.innerHTML = out;
    drawn = out;
  }
  if (!rowHeight && order.length) {
    const tr = tbody.querySelector("tr:not(.spacer)");
    if (tr && tr.offsetHeight) { rowHeight = tr.offsetHeight; draw(); }
  }
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

// Set what an element shows only when it changes (each change costs the browser a layout).
function setHtml(id, text) {
  const el = document.getElementById(id);
  if (el.dataset.html !== text) { el.innerHTML = text; el.dataset.html = text; }
}

function drawHeader(m) {
  setHtml("counts", LEVELS.map((l) =>
    `<button class="chip ${l}${m.counts[l] ? "" : " zero"}" data-level="${l}" title="show ${l} only">${m.counts[l]} ${l}</button>`
  ).join(""));
  setOptions(document.getElementById("state"), m.states,
    [["", "every state"], ["attention", "needs attention"], ...LEVELS.map((l) => [l, "level: " + l])]);
  setOptions(document.getElementById("fleet"), m.fleets, [["", "every fleet"]]);
}

function apply(m) {
  if (m.snapshot) {
    rows.clear();
    html.clear();
    hw.snapshots += 1;
  }
  if (!anyDegradation && m.rows.some((r) => r.degradation)) {
    anyDegradation = true;
    document.querySelectorAll("th.degcol").forEach((th) => { th.hidden = false; });
    html.clear();
  }
  if (!anyComponents && m.rows.some((r) => r.components)) {
    anyComponents = true;
    document.querySelectorAll("th.compcol").forEach((th) => { th.hidden = false; });
    html.clear();
  }
  for (const r of m.rows) {
    rows.set(r.id, r);
    html.delete(r.id);
  }
  if (m.order) {
    order = m.order;
    if (rows.size > 2 * order.length + 100) {  // forget rows that left the filter long ago
      const keep = new Set(order);
      for (const id of rows.keys()) if (!keep.has(id)) { rows.delete(id); html.delete(id); }
    }
  }
}

function flush() {
  const started = performance.now();
  const batch = pending;
  pending = [];
  for (const m of batch) apply(m);
  draw();
  const last = batch[batch.length - 1];
  drawHeader(last);
  if (batch.some((m) => m.snapshot)) stick();
  setHtml("shown", `${order.length} shown`);
  const empty = document.getElementById("empty");
  if (empty.hidden !== order.length > 0) empty.hidden = order.length > 0;
  hw.seq = last.seq;
  hw.shown = order.length;
  hw.applied += batch.length;
  hw.scriptMs = (hw.scriptMs || 0) + performance.now() - started;
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
  if (first !== true) window.scrollTo(0, 0);  // another filter: its most urgent machines first
  const params = new URLSearchParams();
  for (const id of ["state", "fleet", "machine"]) {
    const v = first === true ? new URLSearchParams(location.search).get(id) : document.getElementById(id).value;
    if (v) params.set(id, v);
  }
  if (first === true) document.getElementById("machine").value = params.get("machine") || "";
  history.replaceState(null, "", params.toString() ? "?" + params : location.pathname);
  source = new EventSource("/events?" + params);
  showConnection(source);
  source.onmessage = (e) => {
    if (!pending.length) requestAnimationFrame(flush);
    pending.push(JSON.parse(e.data));
  };
}

for (const id of ["state", "fleet"]) document.getElementById(id).addEventListener("change", connect);
let typing = null;  // the machine filter follows typing after a pause (one new stream, not one per key)
document.getElementById("machine").addEventListener("input", () => {
  clearTimeout(typing);
  typing = setTimeout(connect, 250);
});
document.getElementById("counts").addEventListener("click", (e) => {
  const level = e.target.dataset && e.target.dataset.level;
  if (!level) return;
  const select = document.getElementById("state");
  select.value = select.value === level ? "" : level;
  connect();
});
let scrolling = false;
const redraw = () => {
  if (scrolling) return;
  scrolling = true;
  requestAnimationFrame(() => { scrolling = false; draw(); });
};
window.addEventListener("scroll", redraw, {passive: true});
// the table's header sticks under the page's header, whatever height that has
const stick = () => document.documentElement.style.setProperty(
  "--header", document.querySelector("header").offsetHeight + "px");
window.addEventListener("resize", () => { tableTop = null; stick(); redraw(); });
stick();
connect(true);
