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
