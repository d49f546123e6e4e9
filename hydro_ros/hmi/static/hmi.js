// hydro_ros operator HMI: renders what the server pushes on /ws; text from the graph is set as text, never as HTML.
"use strict";

const view = { actionsEnabled: false, residuals: { names: [], rows: [] }, windowS: 60, diagStamps: {} };
// what make bench reads: seconds from a /diagnostics stamp to the tile in the DOM (one per new stamp),
// bytes received, and milliseconds spent updating the DOM and drawing the plots
window.hmiLatencies = [];
window.hmiBytes = 0;
window.hmiRenderMs = [];
window.hmiDrawMs = [];

function timed(samples, work) {
  const start = performance.now();
  work();
  samples.push(performance.now() - start);
  if (samples.length > 2000) samples.splice(0, 1000);
}

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attrs)) node.setAttribute(key, value);
  for (const child of children) node.append(child instanceof Node ? child : document.createTextNode(String(child)));
  return node;
}

function clockTime(wall) {
  return wall == null ? "" : new Date(wall * 1000).toLocaleTimeString([], { hour12: false });
}

function stampText(stamp) {
  // live stamps are wall clock; a replayed bag's are seconds of sim time
  return stamp > 1e9 ? `at ${clockTime(stamp)}` : `at stamp ${stamp.toFixed(1)} s`;
}

function connect() {
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws`);
  const badge = document.getElementById("connection");
  ws.onopen = () => { badge.textContent = "live"; badge.className = "badge OK"; };
  ws.onclose = () => {
    badge.textContent = "disconnected: retrying"; badge.className = "badge ERROR";
    setTimeout(connect, 1000);
  };
  ws.onmessage = (event) => {
    window.hmiBytes += event.data.length;
    timed(window.hmiRenderMs, () => render(JSON.parse(event.data)));
  };
}

function render(message) {
  view.actionsEnabled = message.actions_enabled;
  const machines = [...new Set(message.tiles.map((tile) => tile.machine))].join(", ");
  document.getElementById("title").textContent = `hydro_ros operator HMI${machines ? `: ${machines}` : ""}`;
  document.getElementById("clock").textContent = clockTime(message.wall);
  renderHalt(message);
  renderTiles(message.tiles);
  renderAlarms(message.alarms);
  renderCatalog(message);
  renderJoints(message);
  renderActions(message.actions, message.refusals || []);
  mergeResiduals(message.residuals);
  requestAnimationFrame(() => timed(window.hmiDrawMs, drawPlots));
}

function renderHalt(message) {
  const halt = document.getElementById("halt");
  if (message.halt === null) {
    halt.className = "halt unknown"; halt.textContent = "halt state unknown: nothing on /fdi/halt yet";
  } else if (message.halt && message.halt_kind === "hold") {
    halt.className = "halt paused"; halt.textContent = `PAUSED since ${clockTime(message.halt_since_wall)}: ${message.halt_reason}`;
  } else if (message.halt) {
    halt.className = "halt requested";
    halt.textContent = `HALT REQUESTED since ${clockTime(message.halt_since_wall)}: ${message.halt_reason || "severe fault"}`;
  } else {
    halt.className = "halt running"; halt.textContent = "no halt request";
  }
}

function renderTiles(tiles) {
  const box = document.getElementById("tiles");
  if (!tiles.length) return;
  box.replaceChildren(...tiles.map((tile) => {
    const detected = tile.detected_stamp_s == null ? "" : ` (first detection ${stampText(tile.detected_stamp_s)})`;
    return el("div", { class: `tile ${tile.level}`, "data-actuator": tile.actuator, "data-level": tile.level },
      el("div", { class: "name" }, `${tile.actuator} `, el("span", { class: `badge level ${tile.level}` }, tile.level)),
      el("div", { class: "fault" }, tile.fault),
      el("div", { class: "muted" }, `since ${clockTime(tile.since_wall)}${detected}`),
      el("div", { class: "muted" }, `${tile.machine}, ${tile.values.method || ""} pattern ${tile.values.pattern || "-"}`));
  }));
  const now = Date.now() / 1000;
  for (const tile of tiles) {
    if (view.diagStamps[tile.actuator] !== tile.diag_stamp_s) {
      // the first stamp a page sees may be old; a placeholder tile has none
      if (typeof view.diagStamps[tile.actuator] === "number" && tile.diag_stamp_s !== null) {
        window.hmiLatencies.push(now - tile.diag_stamp_s);
      }
      view.diagStamps[tile.actuator] = tile.diag_stamp_s;
    }
  }
}

function renderAlarms(alarms) {
  const body = document.querySelector("#alarms tbody");
  body.replaceChildren(...alarms.map((alarm) => {
    let state = alarm.active ? "active" : `cleared ${clockTime(alarm.cleared_wall)}`;
    if (alarm.acknowledged_wall != null) state += `, acknowledged ${clockTime(alarm.acknowledged_wall)}`;
    return el("tr", { "data-alarm": alarm.id, class: alarm.active ? "active" : "cleared" },
      el("td", {}, clockTime(alarm.raised_wall)), el("td", {}, alarm.actuator), el("td", {}, alarm.fault),
      el("td", {}, el("span", { class: `badge ${alarm.level}` }, alarm.level)), el("td", {}, state));
  }));
  const button = document.getElementById("acknowledge");
  button.disabled = !view.actionsEnabled;
  button.title = view.actionsEnabled ? "clears the latched alarms of the FDI node (needs the operator token)"
    : "read-only HMI: the server has no operator token configured";
}

function energy(joules) {
  return joules == null ? "-" : `${(joules / 1000).toFixed(1)} kJ`;
}

function renderCatalog(message) {
  const status = document.getElementById("catalog-status");
  const body = document.querySelector("#catalog tbody");
  if (message.catalog_error) status.textContent = message.catalog_error;
  else if (message.catalog) status.textContent = `${message.catalog.length} stored path(s)`;
  const rows = [];
  for (const entry of message.catalog || []) {
    for (const [method, solution] of Object.entries(entry.solutions || {})) {
      const button = el("button", { type: "button", class: "request", "data-path": entry.path, "data-method": method }, "Request");
      button.disabled = !view.actionsEnabled;
      button.addEventListener("click", () => act("/api/request", { path: entry.path, method }));
      rows.push(el("tr", {}, el("td", {}, entry.path), el("td", {}, method), el("td", {}, energy(solution.cp_energy_J)),
        el("td", {}, energy(solution.ls_energy_J)), el("td", {}, solution.limits_ok ? "ok" : "violated"), el("td", {}, button)));
    }
  }
  const signature = JSON.stringify([message.catalog, view.actionsEnabled]);
  if (body.dataset.signature !== signature) { body.replaceChildren(...rows); body.dataset.signature = signature; }
  const result = message.result;
  const line = document.getElementById("result");
  if (result) {
    line.className = result.ok ? "done" : "refused";
    line.textContent = result.ok ? `served ${result.path} (${result.method || ""}) at ${clockTime(result.received_wall)}`
      : `trajectory server: ${result.path || ""}: ${result.error}`;
  }
}

function renderJoints(message) {
  const entries = Object.entries(message.joints || {});
  if (entries.length) {
    document.getElementById("joints").textContent = entries.map(([name, q]) => `${name} ${q === null ? "n/a" : q.toFixed(3)} rad`).join(", ");
  }
}

function renderActions(actions, refusals) {
  document.getElementById("actions").replaceChildren(...actions.map((a) => el("li", { class: a.ok ? "done" : "refused" },
    `${clockTime(a.wall)} ${a.action} from ${a.client}: ${a.ok ? "done" : "refused"}: ${a.detail}`)));
  document.getElementById("refusals").replaceChildren(...refusals.map((r) => el("li", { class: "refused" },
    `${clockTime(r.wall)} ${r.action} from ${r.client} refused${r.count > 1 ? ` (${r.count}x)` : ""}: ${r.detail}`)));
}

async function act(url, body) {
  const status = document.getElementById("action-status");
  const token = document.getElementById("token").value;
  const headers = { "Content-Type": "application/json" };
  if (token) headers.Authorization = `Bearer ${token}`;
  status.textContent = "sending...";
  try {
    const response = await fetch(url, { method: "POST", headers, body: JSON.stringify(body) });
    const answer = await response.json();
    status.className = answer.ok ? "done" : "refused";
    status.textContent = answer.ok ? `done: ${answer.detail}` : `refused: ${answer.error}`;
  } catch (error) {
    status.className = "refused";
    status.textContent = `refused: ${error}`;
  }
}

function mergeResiduals(residuals) {
  view.windowS = residuals.window_s;
  document.getElementById("plot-window").textContent = `(last ${residuals.window_s} s)`;
  if (residuals.reset || JSON.stringify(residuals.names) !== JSON.stringify(view.residuals.names)) {
    view.residuals = { names: residuals.names, rows: [] };
  }
  view.residuals.rows.push(...residuals.rows);
  const rows = view.residuals.rows;
  if (rows.length) {
    const oldest = rows[rows.length - 1][0] - view.windowS;
    let drop = 0;
    while (drop < rows.length && rows[drop][0] < oldest) drop += 1;
    rows.splice(0, drop);
  }
}

function residualChannels(names) {
  // <actuator>/mean_r_<p|Q><A|B> paired with <actuator>/threshold_<p|Q><A|B>
  const channels = [];
  names.forEach((name, index) => {
    const match = /^(.*)\/mean_r_([pQ])([AB])$/.exec(name);
    if (!match) return;
    const threshold = names.indexOf(`${match[1]}/threshold_${match[2]}${match[3]}`);
    channels.push({ label: `${match[1]} chamber ${match[3]}`, unit: match[2] === "p" ? "MPa" : "L/min",
      residual: index + 1, threshold: threshold < 0 ? null : threshold + 1 });
  });
  return channels;
}

function drawPlots() {
  const { names, rows } = view.residuals;
  const box = document.getElementById("plots");
  const channels = residualChannels(names);
  if (!channels.length) return;
  if (box.dataset.names !== names.join(",")) {
    box.replaceChildren(...channels.map((c, i) => el("figure", {},
      el("canvas", { width: 460, height: 170, id: `plot-${i}`, "data-channel": c.label }),
      el("figcaption", {}, `${c.label}: filtered residual (blue) and adaptive threshold \u00b1 (red), ${c.unit}`))));
    box.dataset.names = names.join(",");
  }
  channels.forEach((channel, i) => drawChannel(document.getElementById(`plot-${i}`), rows, channel));
}

function drawChannel(canvas, rows, channel) {
  const ctx = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height, left = 48, bottom = 18;
  ctx.clearRect(0, 0, w, h);
  if (!rows.length) return;
  const t1 = rows[rows.length - 1][0], t0 = t1 - view.windowS;
  let bound = 1e-6;
  for (const row of rows) {
    for (const k of [channel.residual, channel.threshold]) if (k !== null && row[k] !== null) bound = Math.max(bound, Math.abs(row[k]));
  }
  bound *= 1.15;
  const x = (t) => left + ((t - t0) / (t1 - t0)) * (w - left - 4);
  const y = (v) => (h - bottom) / 2 - (v / bound) * ((h - bottom) / 2 - 4);
  ctx.strokeStyle = "#bdbdbd"; ctx.beginPath(); ctx.moveTo(left, y(0)); ctx.lineTo(w, y(0)); ctx.stroke();
  ctx.fillStyle = "#616161"; ctx.font = "11px sans-serif";
  ctx.fillText(`${bound.toPrecision(2)}`, 2, 12); ctx.fillText(`-${bound.toPrecision(2)}`, 2, h - bottom - 2);
  ctx.fillText(`-${view.windowS} s`, left, h - 4); ctx.fillText("now", w - 26, h - 4);
  const line = (k, sign, colour, dash) => {
    ctx.strokeStyle = colour; ctx.setLineDash(dash); ctx.beginPath();
    let pen = false;
    for (const row of rows) {
      if (row[k] === null) { pen = false; continue; }
      const px = x(row[0]), py = y(sign * row[k]);
      if (pen) ctx.lineTo(px, py); else ctx.moveTo(px, py);
      pen = true;
    }
    ctx.stroke(); ctx.setLineDash([]);
  };
  if (channel.threshold !== null) { line(channel.threshold, 1, "#c62828", [5, 3]); line(channel.threshold, -1, "#c62828", [5, 3]); }
  line(channel.residual, 1, "#1565c0", []);
}

const alarmLog = { offset: 0, limit: 20, total: 0 };

async function loadAlarmLog() {
  const range = document.getElementById("alarm-log-range");
  let answer;
  try {
    const response = await fetch(`/api/alarm_log?offset=${alarmLog.offset}&limit=${alarmLog.limit}`);
    answer = await response.json();
    if (!response.ok) { range.textContent = answer.error; return; }
  } catch (error) {
    range.textContent = `not reachable (${error})`;
    return;
  }
  alarmLog.total = answer.total;
  const last = Math.min(alarmLog.offset + answer.events.length, answer.total);
  range.textContent = answer.total ? `${alarmLog.offset + 1}-${last} of ${answer.total}, newest first` : "empty";
  document.querySelector("#alarm-log tbody").replaceChildren(...answer.events.map((e) => el("tr", { "data-event": e.event },
    el("td", {}, new Date(e.wall_time * 1000).toLocaleString()), el("td", {}, e.actuator || "(all)"), el("td", {}, e.event),
    el("td", {}, e.fault), el("td", {}, ["", "WARN", "ERROR"][e.level] || ""))));
  document.getElementById("alarm-log-newer").disabled = alarmLog.offset === 0;
  document.getElementById("alarm-log-older").disabled = last >= answer.total;
}

document.getElementById("alarm-log-newer").addEventListener("click", () => {
  alarmLog.offset = Math.max(0, alarmLog.offset - alarmLog.limit); loadAlarmLog();
});
document.getElementById("alarm-log-older").addEventListener("click", () => { alarmLog.offset += alarmLog.limit; loadAlarmLog(); });
setInterval(loadAlarmLog, 5000);
loadAlarmLog();
document.getElementById("acknowledge").addEventListener("click", () => act("/api/acknowledge", {}));
document.getElementById("operator").addEventListener("submit", (event) => event.preventDefault());
connect();
