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

// A degradation index per component (value, 95 % interval, trend, time to alert), when a verdict carries one.
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
