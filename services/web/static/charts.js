// Small SVG charts for the machine page, written for it (no chart library: a band of verdicts, a few lines).
"use strict";
const SVG = "http://www.w3.org/2000/svg";
const PALETTE = ["#1565c0", "#c62828", "#2e7d32", "#ef6c00", "#6a1b9a", "#00838f", "#ad1457", "#5d4037", "#9e9d24"];
const LEVEL_COLOURS = {alert: "#c62828", unknown: "#6a1b9a", warning: "#ef6c00", invalid: "#9e9e9e", healthy: "#2e7d32"};
const PAD = {left: 44, right: 10, top: 6, bottom: 18};

function svg(width, height) {
  const el = document.createElementNS(SVG, "svg");
  el.setAttribute("viewBox", `0 0 ${width} ${height}`);
  el.setAttribute("width", "100%");
  el.style.maxWidth = width + "px";
  return el;
}

function add(parent, name, attrs, text) {
  const el = document.createElementNS(SVG, name);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, v);
  if (text !== undefined) el.textContent = text;
  parent.appendChild(el);
  return el;
}

function scale(d0, d1, r0, r1) {
  const span = d1 - d0 || 1;
  return (v) => r0 + (v - d0) / span * (r1 - r0);
}

function timeAxis(el, x0, x1, width, height) {
  const y = height - 4;
  add(el, "text", {x: PAD.left, y}, `t = ${x0.toFixed(0)} s`);
  add(el, "text", {x: width - PAD.right, y, "text-anchor": "end"}, `${x1.toFixed(0)} s`);
}

// One rectangle per window, coloured by urgency level; hovering names the state.
function stateBand(container, t, width = 960, height = 46) {
  const el = svg(width, height);
  const n = t.start_s.length;
  if (!n) { container.replaceChildren(el); return; }
  // (min and max: a machine whose stream restarted, e.g. a restarted plant, starts its time again)
  const x0 = Math.min(...t.start_s), x1 = Math.max(...t.end_s);
  const x = scale(x0, x1, PAD.left, width - PAD.right);
  for (let i = 0; i < n; i++) {
    const r = add(el, "rect", {x: x(t.start_s[i]), y: PAD.top, width: Math.max(1, x(t.end_s[i]) - x(t.start_s[i])),
      height: height - PAD.top - PAD.bottom, fill: LEVEL_COLOURS[t.level[i]] || "#999"});
    add(r, "title", {}, `${t.state[i]} (p = ${t.p[i].toFixed(2)}), ${t.start_s[i].toFixed(1)}–${t.end_s[i].toFixed(1)} s`);
  }
  timeAxis(el, x0, x1, width, height);
  container.replaceChildren(el);
}

// Lines over time, one per series (null values break a line); y from y0 to y1.
// `marks`: x positions drawn as dashed vertical lines (inside the range only); `dashes`: series name → dash pattern.
function lineChart(container, xs, series, {y0 = 0, y1 = 1, width = 960, height = 160, log = false, marks = [],
                                           dashes = {}} = {}) {
  const el = svg(width, height);
  if (!(y1 > y0)) { y0 = log ? y0 / 2 : y0 - 1; y1 = log ? y1 * 2 : y1 + 1; }  // one value: a band around it
  const tr = log ? (v) => Math.log10(Math.max(v, 1e-12)) : (v) => v;
  const lo = xs.length ? Math.min(...xs) : 0, hi = xs.length ? Math.max(...xs) : 1;
  const x = scale(lo, hi, PAD.left, width - PAD.right);
  const y = scale(tr(y0), tr(y1), height - PAD.bottom, PAD.top);
  add(el, "line", {x1: PAD.left, x2: width - PAD.right, y1: y(tr(y0)), y2: y(tr(y0)), stroke: "#ccc"});
  add(el, "text", {x: PAD.left - 4, y: y(tr(y1)) + 9, "text-anchor": "end"}, String(+y1.toPrecision(3)));
  add(el, "text", {x: PAD.left - 4, y: y(tr(y0)), "text-anchor": "end"}, String(+y0.toPrecision(3)));
  for (const m of marks) {
    if (m < lo || m > hi) continue;
    add(el, "line", {x1: x(m), x2: x(m), y1: PAD.top, y2: height - PAD.bottom, stroke: "#9aa5b1",
      "stroke-dasharray": "3 3"});
  }
  const names = Object.keys(series);
  names.forEach((name, k) => {
    let d = "";
    series[name].forEach((v, i) => {
      if (v == null || !isFinite(tr(v))) { d += " "; return; }
      d += `${d.endsWith(" ") || !d ? "M" : "L"}${x(xs[i]).toFixed(1)},${y(tr(v)).toFixed(1)}`;
    });
    add(el, "path", {d: d.replace(/ +/g, " "), fill: "none", stroke: PALETTE[k % PALETTE.length], "stroke-width": 1.6,
      "stroke-dasharray": dashes[name] || "none"});
  });
  if (xs.length) timeAxis(el, lo, hi, width, height);
  container.replaceChildren(el);
  return names.map((name, k) => [name, PALETTE[k % PALETTE.length]]);
}

function legend(container, entries) {
  container.innerHTML = entries.map(([name, colour]) =>
    `<span><span class="sw" style="background:${esc(colour)}"></span>${esc(name)}</span>`).join("");
}
