// What both pages use: escaping, clock times, the connection indicator.
"use strict";
const esc = (s) => String(s ?? "").replace(/[&<>"']/g, (c) => ({"&": "&amp;", "<": "&lt;", ">": "&gt;",
  '"': "&quot;", "'": "&#39;"}[c]));
const clock = (epochS) => epochS == null ? "" : new Date(epochS * 1000).toLocaleTimeString([], {hour12: false});

// Show in #live whether the event stream is up (EventSource reconnects by itself).
function showConnection(source) {
  const live = document.getElementById("live");
  source.onopen = () => { live.textContent = "live"; live.classList.remove("down"); };
  source.onerror = () => { live.textContent = "disconnected: retrying…"; live.classList.add("down"); };
}

// Operating time until an alert, for people: "now", seconds, minutes below two hours, else hours.
function duration(s) {
  if (s <= 0) return "now";
  if (s < 120) return `${Math.round(s)} s`;
  if (s < 7200) return `${Math.round(s / 60)} min`;
  return `${(s / 3600).toFixed(1)} h`;
}

// Each component's wear (index, 95 % interval, trend, time to alert), in the server's order: most urgent first.
function degradationHtml(d) {
  if (!d) return "";
  const num = (x) => x == null ? "–" : Number(x).toFixed(2);
  return Object.entries(d).map(([fault, v]) => {
    const value = v !== null && typeof v === "object" ? v.value : v;
    const ci = v && v.ci95 ? ` [${num(v.ci95[0])}–${num(v.ci95[1])}]` : "";
    const trend = v && v.rate_per_h != null ? ` ${v.rate_per_h >= 0 ? "↑" : "↓"}${Math.abs(v.rate_per_h).toFixed(2)}/h` : "";
    const soon = v && v.alert_in_s != null;
    const either = soon && v.untold_from ? ` (or ${esc(v.untold_from)}: not yet told apart)` : "";
    const alert = (!soon ? "" : v.alert_in_s <= 0 ? " at alert" : ` alert in ${duration(v.alert_in_s)}`) + either;
    const title = v && v.reason ? ` title="${esc(v.reason)}"` : "";
    return `<span class="deg${soon ? " soon" : ""}"${title}>${esc(fault)} ${num(value)}${ci}${trend}${alert}</span>`;
  }).join("");
}

// A cycles machine's components (…/cycle_health): one chip per component, coloured by its level, in the rig's order.
function componentsHtml(c) {
  if (!c) return "";
  return c.map((x) => `<span class="comp ${esc(x.level)}" title="${esc(x.text)}">${esc(x.component)} ` +
    `${esc(x.state)}</span>`).join("");
}
