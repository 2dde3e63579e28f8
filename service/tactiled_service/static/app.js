// tactiled dashboard: one card per sensor (strain heat map, contact ellipse, curvature axis,
// readouts with 1-sigma uncertainties, a strip chart of the last 10 s) and the health counters.
//
// Messages come from /v1/stream at a capped rate (MAX_RATE per sensor and stream); each one
// only replaces the latest state of its sensor (and appends one sample to its strip chart's
// bounded ring), and drawing happens once per animation frame from that state, so the page
// never queues work and never falls behind the stream.
"use strict";

const MAX_RATE = 30;         // Hz per sensor and stream asked of the server
const HEALTH_PERIOD = 1000;  // ms between /v1/health polls
const MIN_SCALE = 0.002;     // strain at the top of the colour scale, at least
const STRIP_S = 10;          // seconds of history in the strip chart
const STRIP_CAP = 2048;      // samples kept per sensor (10 s at up to 200 Hz): a ring, never grows
const STRIP_MIN_DT = 1000 / 30;  // ms between strip redraws (it scrolls; 30 Hz is smooth enough)

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
  s = {info: null, est: null, frame: null, dirty: true, el: card, canvas: $("canvas.map", card),
       scale: MIN_SCALE, strip: newStrip($("canvas.strip", card), $(".strip-tip", card))};
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
      case "estimate": {
        const s = sensorState(msg.sensor);
        s.est = msg;
        s.dirty = true;
        stripAdd(s.strip, msg);
        break;
      }
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
  if (e.line && e.angle_deg !== null && e.angle_deg !== undefined) {
    // A line contact (a cylinder on a flat array): the line, across the whole array.
    const len = Math.hypot(w, h) * k, t = -e.angle_deg * Math.PI / 180;
    ctx.beginPath();
    ctx.moveTo(-len * Math.cos(t), -len * Math.sin(t));
    ctx.lineTo(len * Math.cos(t), len * Math.sin(t));
    ctx.strokeStyle = "#39d353";
    ctx.lineWidth = 3;
    ctx.stroke();
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
  // a line contact has no total force: its load per length stands in the force's cell
  set("force_n", e.line && e.force_n === null
      ? `line: ${fmt(e.line.load_n_per_mm, e.line.load_n_per_mm_std, "N/mm", 4)}`
      : fmt(e.force_n, std.force_n, "N", 3));
  set("x_mm", fmt(e.x_mm, std.x_mm, "mm", 2));
  set("y_mm", fmt(e.y_mm, std.y_mm, "mm", 2));
  set("ellipse", e.ellipse ? `${e.ellipse.a_mm.toFixed(2)} × ${e.ellipse.b_mm.toFixed(2)} mm @ ` +
                             `${e.ellipse.theta_deg.toFixed(0)}°` : "—");
  set("frames_used", e.frames_used === undefined ? "—" : String(e.frames_used));
  set("velocity", e.vx_mm_s === null || e.vx_mm_s === undefined ? "—" :
      `${e.vx_mm_s.toFixed(2)}, ${e.vy_mm_s.toFixed(2)} ± ` +
      `${Math.hypot(std.vx_mm_s || 0, std.vy_mm_s || 0).toFixed(2)} mm/s`);
  set("angle_rate_deg_s", fmt(e.angle_rate_deg_s, std.angle_rate_deg_s, "°/s", 1));
  set("force_rate_n_s", fmt(e.force_rate_n_s, std.force_rate_n_s, "N/s", 3));
  set("gate", e.gate);
  set("seq", String(e.seq));
  set("latency_ms", fmt(e.latency_ms, null, "ms", 2));
  set("peak", e.peak === null || e.peak === undefined ? "—" : (e.peak * 100).toFixed(3) + " %");
  $(".model-label", el).textContent = e.label ? `(${e.label})` : "";
}

// -- strip chart: the last STRIP_S seconds of force, R1 and angle --------------------------
// One sample per estimate received (time = when it arrived here), kept in a fixed ring.  Each
// lane draws the value as a line over its 1-sigma band; a null value (withheld, or no contact)
// breaks the line, and a withheld one is marked under the lane; hovering shows the value with
// its sigma, or why it is missing (the estimate's `reasons` entry).
const LANES = [
  {key: "force_n", label: "force", unit: "N", digits: 3, span: 0.5, colour: "#39d353"},
  {key: "r1_mm", label: "R1", unit: "mm", digits: 2, span: 5, colour: "#58a6ff"},
  // psi lives in [0, 180): a step across the fold is not a motion, so the line breaks there
  {key: "angle_deg", label: "angle", unit: "°", digits: 1, fixed: [0, 180], fold: 180,
   colour: "#f0883e"},
];
const STRIP_PAD = {left: 92, right: 10, top: 6, bottom: 18, gap: 8};

// Lane k spans [top, bottom] in canvas pixels (also published as data-lanes, for tests).
function stripLanes(c) {
  const P = STRIP_PAD;
  const h = (c.height - P.top - P.bottom - P.gap * (LANES.length - 1)) / LANES.length;
  return LANES.map((_, k) => [P.top + k * (h + P.gap), P.top + k * (h + P.gap) + h]);
}

function newStrip(canvas, tip) {
  const strip = {canvas, tip, buf: new Array(STRIP_CAP), start: 0, len: 0, drawn: 0,
                 mouse: null};
  canvas.dataset.lanes = JSON.stringify(stripLanes(canvas));
  canvas.addEventListener("mousemove", (ev) => {
    const r = canvas.getBoundingClientRect();
    // the canvas may be drawn smaller than its pixel size (narrow window): map back
    strip.mouse = {x: (ev.clientX - r.left) * canvas.width / r.width,
                   y: (ev.clientY - r.top) * canvas.height / r.height,
                   cssX: ev.clientX - r.left, cssY: ev.clientY - r.top};
    strip.drawn = 0;  // redraw now, with the hover
  });
  canvas.addEventListener("mouseleave", () => { strip.mouse = null; tip.hidden = true; strip.drawn = 0; });
  return strip;
}

function stripAt(strip, i) { return strip.buf[(strip.start + i) % STRIP_CAP]; }

function stripAdd(strip, e) {
  const sample = {t: performance.now(), seq: e.seq, gate: e.gate, contact: !!e.contact,
                  v: [], sd: [], why: []};
  const std = e.std || {}, reasons = e.reasons || {};
  for (const lane of LANES) {
    const v = e.contact ? e[lane.key] : null;
    sample.v.push(v === undefined ? null : v);
    sample.sd.push(v === null || v === undefined ? null : (std[lane.key] ?? null));
    sample.why.push(v !== null && v !== undefined ? (reasons[lane.key] || null) :
      !e.contact ? "no contact" : (reasons[lane.key] || "not estimated"));
  }
  if (strip.len < STRIP_CAP) {
    strip.buf[(strip.start + strip.len) % STRIP_CAP] = sample;
    strip.len++;
  } else {  // full: the oldest sample makes room
    strip.buf[strip.start] = sample;
    strip.start = (strip.start + 1) % STRIP_CAP;
  }
}

function laneRange(strip, k, lane, from) {
  if (lane.fixed) return lane.fixed;
  const tops = [];
  for (let i = 0; i < strip.len; i++) {
    const p = stripAt(strip, i);
    if (p.t >= from && p.v[k] !== null) tops.push(p.v[k] + (p.sd[k] || 0));
  }
  // The scale follows most of the window, not its extremes: one wild radius (or a band far
  // wider than the values, a radius barely observed) must not flatten the line; what lies
  // above is drawn clipped at the lane's top.
  tops.sort((a, b) => a - b);
  const q = tops.length ? tops[Math.floor(0.95 * (tops.length - 1))] : 0;
  const top = Math.max(lane.span, 1.25 * q);
  const step = Math.pow(10, Math.floor(Math.log10(top)));
  return [0, Math.ceil(top / step * 2) / 2 * step];
}

function fmtSample(lane, k, p) {
  const v = p.v[k], sd = p.sd[k];
  const where = `seq ${p.seq}${p.gate && p.gate !== "fit" ? ` (${p.gate})` : ""}`;
  if (v === null) return `${lane.label} withheld: ${p.why[k]} · ${where}`;
  let text = `${lane.label} ${v.toFixed(lane.digits)}`;
  if (sd !== null) text += ` ± ${sd.toFixed(lane.digits)}`;
  text += ` ${lane.unit} · ${where}`;
  return p.why[k] ? `${text} · ${p.why[k]}` : text;
}

function drawStrip(strip, now) {
  const c = strip.canvas, ctx = c.getContext("2d");
  const P = STRIP_PAD, from = now - STRIP_S * 1000;
  while (strip.len && stripAt(strip, 0).t < from - 1000) {  // forget what scrolled off
    strip.buf[strip.start] = undefined;
    strip.start = (strip.start + 1) % STRIP_CAP;
    strip.len--;
  }
  const w = c.width - P.left - P.right;
  const lanes = stripLanes(c);
  const X = (t) => P.left + (t - from) / (STRIP_S * 1000) * w;
  ctx.fillStyle = "#0b0f13";
  ctx.fillRect(0, 0, c.width, c.height);
  ctx.font = "11px sans-serif";
  // time axis
  ctx.fillStyle = "#8b949e";
  ctx.strokeStyle = "#1f262d";
  ctx.lineWidth = 1;
  for (let s = 0; s <= STRIP_S; s += 2) {
    const x = X(from + s * 1000);
    ctx.beginPath(); ctx.moveTo(x, P.top); ctx.lineTo(x, c.height - P.bottom); ctx.stroke();
    const label = s === STRIP_S ? "now" : `−${STRIP_S - s} s`;
    ctx.fillText(label, Math.min(x - 10, c.width - 24), c.height - 5);
  }
  let hover = null;
  LANES.forEach((lane, k) => {
    const [top, bottom] = lanes[k], laneH = bottom - top;
    const [lo, hi] = laneRange(strip, k, lane, from);
    const Y = (v) => bottom - (Math.min(Math.max(v, lo), hi) - lo) / (hi - lo) * laneH;
    ctx.strokeStyle = "#2a333c";
    ctx.strokeRect(P.left + 0.5, top + 0.5, w, laneH);
    // runs of consecutive samples with a value: a line, and a band where sigma is known
    const runs = [];
    let run = [];
    for (let i = 0; i < strip.len; i++) {
      const p = stripAt(strip, i);
      if (p.t < from) continue;
      const prev = run.length ? run[run.length - 1] : null;
      const jump = lane.fold && prev && Math.abs(p.v[k] - prev.v[k]) > lane.fold / 2;
      if (p.v[k] === null || jump) {
        if (run.length) runs.push(run);
        run = p.v[k] === null ? [] : [p];
        if (p.v[k] === null && p.contact) {  // withheld: mark it, so the gap has a cause to hover
          ctx.fillStyle = "#d2992299";
          ctx.fillRect(X(p.t) - 1, bottom - 4, 2, 4);
        }
        continue;
      }
      run.push(p);
    }
    if (run.length) runs.push(run);
    for (const r of runs) {
      ctx.fillStyle = lane.colour + "40";  // the 1-sigma band, translucent
      let band = [];
      const flush = () => {
        if (band.length > 1) {
          ctx.beginPath();
          band.forEach((p, j) => { const x = X(p.t), y = Y(p.v[k] + p.sd[k]);
                                   if (j) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
          for (let j = band.length - 1; j >= 0; j--) ctx.lineTo(X(band[j].t), Y(band[j].v[k] - band[j].sd[k]));
          ctx.closePath();
          ctx.fill();
        }
        band = [];
      };
      for (const p of r) { if (p.sd[k] === null) flush(); else band.push(p); }
      flush();
      ctx.strokeStyle = lane.colour;
      ctx.lineWidth = 1.5;
      ctx.beginPath();
      r.forEach((p, j) => { if (j) ctx.lineTo(X(p.t), Y(p.v[k])); else ctx.moveTo(X(p.t), Y(p.v[k])); });
      ctx.stroke();
      if (r.length === 1) { ctx.fillStyle = lane.colour; ctx.fillRect(X(r[0].t) - 1.5, Y(r[0].v[k]) - 1.5, 3, 3); }
    }
    // labels: name and unit, scale, the latest value
    const last = strip.len ? stripAt(strip, strip.len - 1) : null;
    ctx.fillStyle = lane.colour;
    ctx.font = "bold 12px sans-serif";
    ctx.fillText(`${lane.label} (${lane.unit})`, 6, top + 14);
    ctx.font = "11px sans-serif";
    ctx.fillStyle = "#e6e9ec";
    ctx.fillText(last && last.t >= from ? (last.v[k] === null ? "—" : last.v[k].toFixed(lane.digits)) : "",
                 6, top + 30);
    ctx.fillStyle = "#8b949e";
    ctx.fillText(String(+hi.toPrecision(3)), P.left - 30, top + 10);
    ctx.fillText(String(lo), P.left - 30, bottom - 1);
    const m = strip.mouse;
    if (m && m.y >= top && m.y <= bottom && m.x >= P.left && strip.len) {
      // the sample nearest the pointer in time (samples are in time order: bisect)
      const t = from + (m.x - P.left) / w * STRIP_S * 1000;
      let a = 0, b = strip.len - 1;
      while (a < b) { const mid = (a + b) >> 1; if (stripAt(strip, mid).t < t) a = mid + 1; else b = mid; }
      let best = stripAt(strip, a);
      if (a > 0 && Math.abs(stripAt(strip, a - 1).t - t) < Math.abs(best.t - t)) best = stripAt(strip, a - 1);
      if (best.t >= from && Math.abs(X(best.t) - m.x) <= 12) hover = {lane, k, p: best, top, bottom};
    }
  });
  const tip = strip.tip;
  if (hover) {
    const x = X(hover.p.t);
    ctx.strokeStyle = "#e6e9ec88";
    ctx.beginPath(); ctx.moveTo(x, hover.top); ctx.lineTo(x, hover.bottom); ctx.stroke();
    tip.textContent = fmtSample(hover.lane, hover.k, hover.p);
    tip.hidden = false;
    const m = strip.mouse, r = c.getBoundingClientRect();
    tip.style.left = `${Math.min(m.cssX + 14, Math.max(0, r.width - 300))}px`;
    tip.style.top = `${m.cssY + 16}px`;
  } else {
    tip.hidden = true;
  }
}

function render(now) {
  for (const s of state.sensors.values()) {
    const st = s.strip;
    // the strip scrolls, so it is redrawn while it shows anything (or is hovered), ~30 Hz
    if ((st.len || st.mouse || !st.drawn) && now - st.drawn >= STRIP_MIN_DT) {
      st.drawn = now;
      drawStrip(st, performance.now());
    }
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
