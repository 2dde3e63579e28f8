// tactiled dashboard: one card per sensor (strain heat map, contact ellipse, curvature axis,
// readouts with 1-sigma uncertainties) and the health counters.
//
// Messages come from /v1/stream at a capped rate (MAX_RATE per sensor and stream); each one
// only replaces the latest state of its sensor, and drawing happens once per animation frame
// from that latest state, so the page never queues work and never falls behind the stream.
"use strict";

const MAX_RATE = 30;         // Hz per sensor and stream asked of the server
const HEALTH_PERIOD = 1000;  // ms between /v1/health polls
const MIN_SCALE = 0.002;     // strain at the top of the colour scale, at least

const state = {
  sensors: new Map(),        // name -> {info, est, frame, dirty, el, canvas, scale}
  ws: null,
  retry: 500,
  health: null,              // the last /v1/health answer
};

const $ = (sel, root = document) => root.querySelector(sel);

function message(text) { $("#message").textContent = text || ""; }

function setConn(text, up) {
  const el = $("#conn");
  el.textContent = text;
  el.className = "conn " + (up ? "up" : "down");
}

// -- colour map (inferno-like, 0..1) ---------------------------------------------------------
const STOPS = [[0, 0, 4], [40, 11, 84], [101, 21, 110], [159, 42, 99], [212, 72, 66],
               [245, 125, 21], [250, 193, 39], [252, 255, 164]];
function colour(t) {
  t = Math.min(1, Math.max(0, t)) * (STOPS.length - 1);
  const i = Math.min(STOPS.length - 2, Math.floor(t)), f = t - i;
  const a = STOPS[i], b = STOPS[i + 1];
  return `rgb(${a.map((v, k) => Math.round(v + f * (b[k] - v))).join(",")})`;
}

// -- number formatting -----------------------------------------------------------------------
function fmt(value, std, unit, digits) {
  if (value === null || value === undefined) return "—";
  let s = value.toFixed(digits);
  if (std !== null && std !== undefined) s += " ± " + std.toFixed(digits);
  return s + (unit ? " " + unit : "");
}

// -- sensors ---------------------------------------------------------------------------------
function sensorState(name) {
  let s = state.sensors.get(name);
  if (s) return s;
  const card = $("#sensor-card").content.firstElementChild.cloneNode(true);
  card.id = "sensor-" + name;
  card.dataset.sensor = name;
  $(".name", card).textContent = name;
  $("#sensors").appendChild(card);
  s = {info: null, est: null, frame: null, dirty: true, el: card, canvas: $("canvas", card),
       scale: MIN_SCALE};
  state.sensors.set(name, s);
  if (state.health && state.health.sensors[name]) showStatus(s, state.health.sensors[name]);
  return s;
}

function showStatus(s, x) {
  const b = $(".status", s.el);
  b.textContent = x.status;
  b.className = "badge status " + x.status;
  b.title = x.reason;
}

async function loadSensors() {
  try {
    const r = await fetch("/v1/sensors", {credentials: "same-origin"});
    if (!r.ok) { message(`sensors: ${r.status} ${(await r.json()).detail || ""}`); return; }
    for (const info of (await r.json()).sensors) {
      const s = sensorState(info.name);
      s.info = info;
      s.dirty = true;
    }
  } catch (err) { message("cannot load sensors: " + err); }
}

// -- the stream ------------------------------------------------------------------------------
function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(`${proto}//${location.host}/v1/stream`);
  state.ws = ws;
  setConn("connecting…", false);
  ws.onopen = () => { state.retry = 500; setConn("live", true); };
  ws.onmessage = (ev) => {
    let msg;
    try { msg = JSON.parse(ev.data); } catch { return; }
    switch (msg.type) {
      case "version":
        $("#version").textContent = `v${msg.release}`;
        for (const name of msg.sensors) sensorState(name);
        ws.send(JSON.stringify({type: "subscribe", streams: ["estimates", "frames"],
                                max_rate: MAX_RATE}));
        break;
      case "estimate": { const s = sensorState(msg.sensor); s.est = msg; s.dirty = true; break; }
      case "frame": { const s = sensorState(msg.sensor); s.frame = msg; s.dirty = true; break; }
      case "error": message(`server: ${msg.message}`); break;
      default: break;
    }
  };
  ws.onclose = (ev) => {
    setConn(`disconnected (${ev.code}${ev.reason ? ": " + ev.reason : ""}); retrying`, false);
    setTimeout(connect, state.retry);
    state.retry = Math.min(5000, state.retry * 2);
  };
}

// -- drawing ---------------------------------------------------------------------------------
function geometry(s) {
  const f = s.frame, i = s.info;
  return {
    rows: i ? i.rows : (f ? f.rows : 8), cols: i ? i.cols : (f ? f.cols : 8),
    dx: i ? i.dx_mm : 3.3, dy: i ? i.dy_mm : 3.9,
  };
}

function drawMap(s) {
  const c = s.canvas, ctx = c.getContext("2d");
  const g = geometry(s);
  // x (along the finger, rows) to the right, y (around it, columns) upward; one scale (px/mm)
  // for both, so the ellipse keeps its shape and angle.
  const pad = 24, w = g.rows * g.dx, h = g.cols * g.dy;
  const height = Math.round(2 * pad + (c.width - 2 * pad) * h / w);  // the array's aspect
  if (c.height !== height) c.height = height;
  const k = (c.width - 2 * pad) / w;
  const X = (x) => pad + (x + g.dx / 2) * k;
  const Y = (y) => c.height - pad - (y + g.dy / 2) * k;
  ctx.fillStyle = "#000";
  ctx.fillRect(0, 0, c.width, c.height);
  const strain = s.frame ? s.frame.strain : null;
  let peak = 0;
  if (strain) for (const row of strain) for (const v of row) peak = Math.max(peak, v);
  // Scale rises at once and decays slowly: no flicker as the contact fades.
  s.scale = Math.max(MIN_SCALE, peak, 0.97 * s.scale);
  for (let m = 0; m < g.rows; m++) {
    for (let n = 0; n < g.cols; n++) {
      const v = strain ? strain[m][n] : 0;
      ctx.fillStyle = colour(v / s.scale);
      ctx.fillRect(X(m * g.dx - g.dx / 2) + 1, Y(n * g.dy + g.dy / 2) + 1, g.dx * k - 2,
                   g.dy * k - 2);
    }
  }
  ctx.fillStyle = "#8b949e";
  ctx.font = "11px sans-serif";
  ctx.fillText("x →", c.width - pad - 22, c.height - 6);
  ctx.fillText("y ↑", 4, pad - 8);
  ctx.fillText(`scale ${(s.scale * 100).toFixed(2)} % strain`, pad, 14);
  const e = s.est;
  if (!e || !e.contact || e.x_mm === null || e.y_mm === null) return;
  const cx = X(e.x_mm), cy = Y(e.y_mm);
  ctx.save();
  ctx.translate(cx, cy);
  if (e.ellipse) {
    ctx.save();
    ctx.rotate(-e.ellipse.theta_deg * Math.PI / 180);  // y is up on screen
    ctx.beginPath();
    ctx.ellipse(0, 0, e.ellipse.a_mm * k, e.ellipse.b_mm * k, 0, 0, 2 * Math.PI);
    ctx.strokeStyle = "#39d353";
    ctx.lineWidth = 2;
    ctx.stroke();
    ctx.restore();
  }
  if (e.angle_deg !== null && e.angle_deg !== undefined) {
    // The curvature axis: the R2 direction (a cylinder's axis).
    const len = Math.max(e.ellipse ? e.ellipse.a_mm * 1.6 : 0, 6) * k;
    const t = -e.angle_deg * Math.PI / 180;
    ctx.beginPath();
    ctx.moveTo(-len * Math.cos(t), -len * Math.sin(t));
    ctx.lineTo(len * Math.cos(t), len * Math.sin(t));
    ctx.setLineDash([6, 4]);
    ctx.strokeStyle = "#58a6ff";
    ctx.lineWidth = 2;
    ctx.stroke();
  }
  ctx.setLineDash([]);
  ctx.fillStyle = "#fff";
  ctx.beginPath();
  ctx.arc(0, 0, 3, 0, 2 * Math.PI);
  ctx.fill();
  ctx.restore();
}

function drawReadouts(s) {
  const e = s.est, el = s.el;
  if (!e) return;
  const std = e.std || {};
  const set = (k, text) => { const td = $(`[data-k="${k}"]`, el); if (td) td.textContent = text; };
  set("contact", e.contact ? "yes" : "no");
  set("model", e.model || "—");
  set("r1_mm", fmt(e.r1_mm, std.r1_mm, "mm", 2));
  set("r2_mm", e.contact && e.r2_mm === null && e.model ? "∞" : fmt(e.r2_mm, std.r2_mm, "mm", 2));
  set("angle_deg", fmt(e.angle_deg, std.angle_deg, "°", 1));
  set("force_n", fmt(e.force_n, std.force_n, "N", 3));
  set("x_mm", fmt(e.x_mm, std.x_mm, "mm", 2));
  set("y_mm", fmt(e.y_mm, std.y_mm, "mm", 2));
  set("ellipse", e.ellipse ? `${e.ellipse.a_mm.toFixed(2)} × ${e.ellipse.b_mm.toFixed(2)} mm @ ` +
                             `${e.ellipse.theta_deg.toFixed(0)}°` : "—");
  set("gate", e.gate);
  set("seq", String(e.seq));
  set("latency_ms", fmt(e.latency_ms, null, "ms", 2));
  set("peak", e.peak === null || e.peak === undefined ? "—" : (e.peak * 100).toFixed(3) + " %");
  $(".model-label", el).textContent = e.label ? `(${e.label})` : "";
}

function render() {
  for (const s of state.sensors.values()) {
    if (!s.dirty) continue;
    s.dirty = false;
    drawMap(s);
    drawReadouts(s);
  }
  requestAnimationFrame(render);
}

// -- health ----------------------------------------------------------------------------------
async function pollHealth() {
  try {
    const r = await fetch("/v1/health", {credentials: "same-origin"});
    const h = await r.json();
    state.health = h;
    const overall = $("#overall");
    overall.textContent = h.status;
    overall.className = "badge " + h.status;
    const tbody = $("#health tbody");
    tbody.textContent = "";
    for (const [name, x] of Object.entries(h.sensors)) {
      const tr = document.createElement("tr");
      tr.dataset.sensor = name;
      const cells = [name, x.status, x.frame_rate_hz.toFixed(0), x.fit_rate_hz.toFixed(0),
        x.frames, x.crc_errors, x.lost_frames, x.duplicated_frames, x.superseded_frames,
        x.worker_restarts, x.last_frame_age_s === null ? "—" :
        (x.last_frame_age_s * 1000).toFixed(0) + " ms", x.reason];
      for (const v of cells) {
        const td = document.createElement("td");
        td.textContent = String(v);
        tr.appendChild(td);
      }
      tr.children[1].className = "badge " + x.status;
      tbody.appendChild(tr);
      const s = state.sensors.get(name);
      if (s) showStatus(s, x);
    }
    const subs = h.subscribers;
    const dropped = subs.clients.reduce((n, c) => n + c.dropped, 0);
    $("#subscribers").textContent = `${subs.count} subscriber(s) of ${subs.limit}; ` +
      `dropped messages ${dropped}; closed for not reading ${subs.stalled}; ` +
      `worker restarts ${h.workers.restarts}`;
  } catch (err) {
    $("#overall").textContent = "?";
  }
  setTimeout(pollHealth, HEALTH_PERIOD);
}

loadSensors();
connect();
pollHealth();
requestAnimationFrame(render);
