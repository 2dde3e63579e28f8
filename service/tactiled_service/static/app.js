// tactiled dashboard: every sensor's array at once, each at its own shape and pitch on one
// common scale (px per mm), with its live strain, every contact's ellipse (or line) and id; a
// panel that follows one contact (the strongest on any sensor, or the sensor or contact the
// user clicked) with its readouts and a strip chart of its last 10 s; the health counters.
//
// Messages come from /v1/stream at a capped rate (MAX_RATE per sensor and stream); each one
// only replaces the latest state of its sensor (and appends one sample to bounded rings), and
// drawing happens once per animation frame from that state, so the page never queues work and
// never falls behind the stream.
"use strict";

const MAX_RATE = 30;         // Hz per sensor and stream asked of the server
const HEALTH_PERIOD = 1000;  // ms between /v1/health polls
const MIN_SCALE = 0.005;     // strain at the top of the colour scale, at least: ten noise sigmas of
                             // the default sensor, so an untouched array's noise stays dark
const STRIP_S = 10;          // seconds of history in the strip chart
const STRIP_CAP = 2048;      // samples kept per ring (10 s at up to 200 Hz): never grows
const STRIP_MIN_DT = 1000 / 30;  // ms between strip redraws (it scrolls; 30 Hz is smooth enough)
const CONTACT_RINGS = 64;    // contacts whose history is kept at once (the oldest goes first)
const SWITCH = 1.2;          // following the strongest: change only for a force 20 % larger
// Layout: one scale for every array, the largest that keeps the arrays and the follow panel
// on the screen (wrapping into lines when that gives more), within [K_MIN, K_MAX] px per mm.
const K_MIN = 2, K_MAX = 16;
const MAP_PAD = 12;          // px around each array (axis hints)
const TILE_MIN_W = 188;      // px: what the brief readouts under a map need
const TILE_CHROME_W = 26;    // px: a tile's padding and border
const TILE_CHROME_H = 146;   // px: a tile's title, readouts, padding (until measured)
const GAP = 12;              // px between tiles (style.css: main's gap)
const GRID = "#20262d";      // the lines between tactels
const TAXEL_MIN = 20;        // in-plane reading at a tick's full length, at least: ten noise
                             // sigmas of the XELA descriptions, so an untouched array stays still

const state = {
  sensors: new Map(),        // name -> {name, info, est, frame, dirty, el, canvas, overlay, scale, drawn}
  rings: new Map(),          // "sensor" or "sensor#contact_id" -> its strip-chart samples
  ws: null,
  retry: 500,
  health: null,              // the last /v1/health answer
  k: 6,                      // px per mm, the same for every array
  follow: {mode: "auto", sensor: null, id: null},  // what the user asked to follow
  auto: null,                // the sensor followed as the strongest (kept unless beaten by SWITCH)
  note: "", noteUntil: 0,    // why the panel went back to the strongest
  shown: {key: null, src: null, label: null},
  strip: null,
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
// The legend in the header: the same colours, from 0 to each array's scale.
document.querySelector("#legend .ramp").style.background =
  `linear-gradient(to right, ${STOPS.map(c => `rgb(${c.join(",")})`).join(", ")})`;
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

// -- contacts --------------------------------------------------------------------------------
// An estimate lists its contacts in `contacts` (each with the keys of a one-contact estimate
// and its `contact_id`); a daemon that does not gives the one contact at the top level.
function contactsOf(e) {
  if (!e) return [];
  if (Array.isArray(e.contacts)) return e.contacts.filter((c) => c && c.contact !== false);
  return e.contact ? [e] : [];
}

const forceOf = (e) => (e && e.force_n) || 0;

// A contact with its estimate's envelope (seq, gate, latency...), for readouts and samples.
function withEnvelope(est, c) { return c === est ? est : Object.assign({}, est, {contacts: undefined}, c); }

// The id of an estimate's strongest contact (the top level), or null.
function topId(e) {
  if (!e || !e.contact) return null;
  if (e.contact_id !== undefined && e.contact_id !== null) return e.contact_id;
  let best = null;
  for (const c of contactsOf(e)) if (c !== e && (!best || forceOf(c) > forceOf(best))) best = c;
  return best && best.contact_id !== undefined ? best.contact_id : null;
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
  s = {name, info: null, est: null, frame: null, dirty: true, el: card,
       canvas: $("canvas.map", card), overlay: $("canvas.overlay", card), scale: MIN_SCALE,
       drawn: []};
  card.addEventListener("click", (ev) => clickSensor(s, ev));
  card.addEventListener("keydown", (ev) => {
    if (ev.key !== "Enter" && ev.key !== " ") return;
    ev.preventDefault();
    followThis({mode: "sensor", sensor: name, id: null});
  });
  state.sensors.set(name, s);
  if (state.health && state.health.sensors[name]) showStatus(s, state.health.sensors[name]);
  layout();
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
    layout();
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
      case "estimate": onEstimate(sensorState(msg.sensor), msg); break;
      case "frame": {
        const s = sensorState(msg.sensor);
        const grew = !s.frame && !s.info;
        s.frame = msg;
        s.dirty = true;
        if (grew) layout();  // the array's shape, until /v1/sensors answers
        break;
      }
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

function onEstimate(s, msg) {
  s.est = msg;
  s.dirty = true;
  ringAdd(ringFor(s.name), msg);
  if (Array.isArray(msg.contacts)) {
    for (const c of msg.contacts) {
      if (c && c.contact_id !== undefined && c.contact_id !== null) {
        ringAdd(ringFor(`${s.name}#${c.contact_id}`), withEnvelope(msg, c));
      }
    }
  }
}

// -- layout: one px-per-mm scale for every array -----------------------------------------------
function geometry(s) {
  const f = s.frame, i = s.info;
  return {
    rows: i ? i.rows : (f ? f.rows : 8), cols: i ? i.cols : (f ? f.cols : 8),
    dx: i ? (i.pitch_x_mm ?? i.dx_mm) : 3.3, dy: i ? (i.pitch_y_mm ?? i.dy_mm) : 3.9,
  };
}

function layout() {
  const list = [...state.sensors.values()];
  if (!list.length) return;
  const main = $("#sensors"), cs = getComputedStyle(main);
  const W = main.clientWidth - parseFloat(cs.paddingLeft) - parseFloat(cs.paddingRight);
  const panel = $("#follow-panel");
  const below = panel.offsetHeight + parseFloat(getComputedStyle(panel).marginBottom);
  const H = window.innerHeight - $("header").offsetHeight - parseFloat(cs.paddingTop) -
            parseFloat(cs.paddingBottom) - below;
  const first = list[0];
  const chromeH = first.el.offsetHeight > first.canvas.height ?
    first.el.offsetHeight - first.canvas.height : TILE_CHROME_H;
  const dims = list.map((s) => { const g = geometry(s); return [g.rows * g.dx, g.cols * g.dy]; });
  const fits = (k) => {  // the tiles, packed into lines left to right, fit W x H at k
    let lineW = 0, lineH = 0, total = 0;
    for (const [w, h] of dims) {
      const tw = Math.max(Math.round(w * k) + 2 * MAP_PAD + TILE_CHROME_W, TILE_MIN_W);
      const th = Math.round(h * k) + 2 * MAP_PAD + chromeH;
      if (tw > W) return false;
      if (lineW && lineW + GAP + tw > W) { total += lineH + GAP; lineW = 0; lineH = 0; }
      lineW += (lineW ? GAP : 0) + tw;
      lineH = Math.max(lineH, th);
    }
    return total + lineH <= H;
  };
  let lo = K_MIN, hi = K_MAX;
  if (fits(hi)) lo = hi;
  else for (let i = 0; i < 24; i++) { const mid = (lo + hi) / 2; if (fits(mid)) lo = mid; else hi = mid; }
  state.k = Math.floor(lo * 20) / 20;
  for (const s of list) sizeMap(s);
}

function sizeMap(s) {
  const g = geometry(s), k = state.k;
  const aw = Math.round(g.rows * g.dx * k), ah = Math.round(g.cols * g.dy * k);
  const w = aw + 2 * MAP_PAD, h = ah + 2 * MAP_PAD;
  for (const c of [s.canvas, s.overlay]) {
    if (c.width !== w) c.width = w;
    if (c.height !== h) c.height = h;
  }
  s.el.style.width = `${Math.max(w + TILE_CHROME_W, TILE_MIN_W)}px`;
  // what the page drew, for anyone measuring it: the grid and the array's box in canvas px
  Object.assign(s.el.dataset, {rows: g.rows, cols: g.cols, pitchXMm: g.dx, pitchYMm: g.dy,
                               pxPerMm: k});
  s.canvas.dataset.array = JSON.stringify([MAP_PAD, MAP_PAD, aw, ah]);
  s.canvas.dataset.grid = GRID;
  s.dirty = true;
}

// -- drawing ---------------------------------------------------------------------------------
// x (along the array's rows index) to the right, y (its columns index) upward, the origin at
// the centre of tactel [0, 0]; one scale (px/mm) for both axes and every array, so shapes,
// angles and sizes compare across sensors.
function mapFrame(s) {
  const g = geometry(s), k = state.k, c = s.canvas;
  const X = (x) => MAP_PAD + (x + g.dx / 2) * k;
  const Y = (y) => c.height - MAP_PAD - (y + g.dy / 2) * k;
  return {g, k, X, Y, w: g.rows * g.dx, h: g.cols * g.dy};
}

function drawMap(s) {
  const c = s.canvas, ctx = c.getContext("2d");
  const {g, X, Y} = mapFrame(s);
  ctx.fillStyle = "#000";
  ctx.fillRect(0, 0, c.width, c.height);
  const strain = s.frame && s.frame.rows === g.rows && s.frame.cols === g.cols ? s.frame.strain : null;
  let peak = 0;
  if (strain) for (const row of strain) for (const v of row) peak = Math.max(peak, v);
  // Scale rises at once and decays slowly: no flicker as the contact fades.
  s.scale = Math.max(MIN_SCALE, peak, 0.97 * s.scale);
  ctx.fillStyle = GRID;
  ctx.fillRect(MAP_PAD, MAP_PAD, c.width - 2 * MAP_PAD, c.height - 2 * MAP_PAD);
  for (let m = 0; m < g.rows; m++) {
    const x0 = Math.round(X((m - 0.5) * g.dx)) + 1, x1 = Math.round(X((m + 0.5) * g.dx)) - 1;
    for (let n = 0; n < g.cols; n++) {
      const y0 = Math.round(Y((n + 0.5) * g.dy)) + 1, y1 = Math.round(Y((n - 0.5) * g.dy)) - 1;
      ctx.fillStyle = colour((strain ? strain[m][n] : 0) / s.scale);
      ctx.fillRect(x0, y0, Math.max(1, x1 - x0), Math.max(1, y1 - y0));
    }
  }
  drawTaxels(s, ctx, g, X, Y);
  ctx.fillStyle = "#8b949e";
  ctx.font = "10px sans-serif";
  ctx.fillText("x →", c.width - MAP_PAD - 18, c.height - 2);
  ctx.fillText("y ↑", 1, MAP_PAD - 2);
}

// A 3-axis array's frame (taxels[m][n] = zeroed [x, y, z] readings): over the heat map of z,
// each taxel's in-plane reading (x, y) as a white tick from its centre, x to the right and y
// up, the longest (over a scale that rises at once and decays slowly) 0.45 of a pitch.  What
// was drawn goes to data-taxels on the map (canvas px): the frame's seq, the scale, and each
// taxel's [m, n, dx, dy].
function drawTaxels(s, ctx, g, X, Y) {
  const f = s.frame, t = f && Array.isArray(f.taxels) && f.taxels.length === g.rows ? f.taxels : null;
  if (!t) { delete s.canvas.dataset.taxels; return; }
  let peak = 0;
  for (const row of t) for (const v of row) peak = Math.max(peak, Math.hypot(v[0], v[1]));
  s.tscale = Math.max(TAXEL_MIN, peak, 0.97 * (s.tscale || 0));
  const reach = 0.45 * Math.min(g.dx, g.dy) * state.k;  // px at the scale
  const ticks = [];
  ctx.save();
  ctx.strokeStyle = "#fff";
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  for (let m = 0; m < g.rows; m++) {
    for (let n = 0; n < g.cols; n++) {
      const v = t[m][n];
      const dx = v[0] / s.tscale * reach, dy = -v[1] / s.tscale * reach;  // y up on screen
      const cx = X(m * g.dx), cy = Y(n * g.dy);
      ctx.moveTo(cx, cy);
      ctx.lineTo(cx + dx, cy + dy);
      ticks.push([m, n, +dx.toFixed(2), +dy.toFixed(2)]);
    }
  }
  ctx.stroke();
  ctx.restore();
  s.canvas.dataset.taxels = JSON.stringify({seq: f.seq, scale: s.tscale, ticks});
}

const SLIP_COLOURS = {stick: "#39c5cf", partial: "#e3b341", slip: "#f85149"};

// A 3-axis contact's tangential-force arrow in canvas px from its centre (null: no shear).
function shearArrow(e, X, Y, cx, cy, k) {
  const sh = e.shear;
  if (!sh || typeof sh.fx_n !== "number" || typeof sh.fy_n !== "number") return null;
  const q = Math.hypot(sh.fx_n, sh.fy_n);
  if (!(q > 0) || typeof sh.q_over_p !== "number") return null;
  const len = Math.max(10 * sh.q_over_p, 12 / k);  // mm; at least 12 px
  return {dx: X(e.x_mm + sh.fx_n / q * len) - cx, dy: Y(e.y_mm + sh.fy_n / q * len) - cy,
          state: (e.slip && e.slip.state) || "stick"};
}

// Each contact's ellipse (green) or line, its curvature axis (dashed blue), centre and id; the
// followed one ringed in white.  What was drawn is kept (s.drawn, and data-contacts on the
// overlay: canvas px) for clicks and for anyone measuring the page.
function drawContacts(s, target) {
  const c = s.overlay, ctx = c.getContext("2d");
  const {k, X, Y, w, h} = mapFrame(s);
  ctx.clearRect(0, 0, c.width, c.height);
  s.drawn = [];
  for (const e of contactsOf(s.est)) {
    if (e.x_mm === null || e.x_mm === undefined || e.y_mm === null || e.y_mm === undefined) continue;
    const id = e.contact_id === undefined ? null : e.contact_id;
    const followed = target && target.sensor === s.name && target.mode === "contact" && target.id === id;
    const cx = X(e.x_mm), cy = Y(e.y_mm);
    const ell = e.ellipse || null;
    ctx.save();
    ctx.translate(cx, cy);
    if (ell) {
      ctx.save();
      ctx.rotate(-ell.theta_deg * Math.PI / 180);  // y is up on screen
      ctx.beginPath();
      ctx.ellipse(0, 0, ell.a_mm * k, ell.b_mm * k, 0, 0, 2 * Math.PI);
      if (followed) { ctx.strokeStyle = "#fff"; ctx.lineWidth = 5; ctx.stroke(); }
      ctx.strokeStyle = "#39d353";
      ctx.lineWidth = 2;
      ctx.stroke();
      ctx.restore();
    }
    const angle = e.angle_deg === null || e.angle_deg === undefined ? null : -e.angle_deg * Math.PI / 180;
    const segment = (len) => {
      ctx.beginPath();
      ctx.moveTo(-len * Math.cos(angle), -len * Math.sin(angle));
      ctx.lineTo(len * Math.cos(angle), len * Math.sin(angle));
    };
    if (e.line && angle !== null) {
      // A line contact (a cylinder on a flat array): the line, across the whole array.
      ctx.save();
      ctx.beginPath();
      ctx.rect(MAP_PAD - cx, MAP_PAD - cy, w * k, h * k);
      ctx.clip();
      segment(Math.hypot(w, h) * k);
      if (followed) { ctx.strokeStyle = "#fff"; ctx.lineWidth = 6; ctx.stroke(); }
      ctx.strokeStyle = "#39d353";
      ctx.lineWidth = 3;
      ctx.stroke();
      ctx.restore();
    }
    if (angle !== null) {
      // The curvature axis: the R2 direction (a cylinder's axis).
      segment(Math.max(ell ? ell.a_mm * 1.6 : 0, 6) * k);
      ctx.setLineDash([6, 4]);
      ctx.strokeStyle = "#58a6ff";
      ctx.lineWidth = 2;
      ctx.stroke();
      ctx.setLineDash([]);
    }
    const arrow = shearArrow(e, X, Y, cx, cy, k);
    if (arrow) {
      // The tangential force on a 3-axis array: along Q, 10 mm per unit Q/P, coloured by
      // the slip state (stick cyan, partial yellow, slip red).
      ctx.beginPath();
      ctx.moveTo(0, 0);
      ctx.lineTo(arrow.dx, arrow.dy);
      const a = Math.atan2(arrow.dy, arrow.dx);
      for (const s2 of [-1, 1]) {
        ctx.moveTo(arrow.dx, arrow.dy);
        ctx.lineTo(arrow.dx - 8 * Math.cos(a + s2 * 0.45), arrow.dy - 8 * Math.sin(a + s2 * 0.45));
      }
      ctx.strokeStyle = SLIP_COLOURS[arrow.state] || "#58a6ff";
      ctx.lineWidth = 3;
      ctx.stroke();
    }
    ctx.fillStyle = "#fff";
    ctx.beginPath();
    ctx.arc(0, 0, 3, 0, 2 * Math.PI);
    ctx.fill();
    if (id !== null) {
      const r = ell ? Math.min(ell.b_mm * k, 18) : 4;
      ctx.font = "bold 12px sans-serif";
      ctx.lineWidth = 3;
      ctx.strokeStyle = "#000";
      ctx.strokeText(String(id), r * 0.7 + 3, -r * 0.7 - 3);
      ctx.fillStyle = "#fff";
      ctx.fillText(String(id), r * 0.7 + 3, -r * 0.7 - 3);
    }
    ctx.restore();
    s.drawn.push({id, x: +cx.toFixed(1), y: +cy.toFixed(1),
                  a: ell ? +(ell.a_mm * k).toFixed(1) : null,
                  b: ell ? +(ell.b_mm * k).toFixed(1) : null,
                  theta_deg: ell ? ell.theta_deg : null, line: !!e.line,
                  shear: arrow ? {dx: +arrow.dx.toFixed(1), dy: +arrow.dy.toFixed(1),
                                  state: arrow.state, fx_n: e.shear.fx_n, fy_n: e.shear.fy_n}
                               : null});
  }
  c.dataset.contacts = JSON.stringify(s.drawn);
}

function drawReadouts(root, e) {
  if (!e) return;
  const std = e.std || {};
  const sd = (k) => std[k] ?? e[k + "_std"];
  const set = (k, text) => { const td = $(`[data-k="${k}"]`, root); if (td) td.textContent = text; };
  const n = contactsOf(e).length;
  set("contact", !e.contact ? "no" : Array.isArray(e.contacts) && n > 1 ? `${n} contacts` : "yes");
  set("model", e.model || "—");
  set("r1_mm", fmt(e.r1_mm, sd("r1_mm"), "mm", 2));
  set("r2_mm", e.contact && e.r2_mm === null && e.model ? "∞" : fmt(e.r2_mm, sd("r2_mm"), "mm", 2));
  set("angle_deg", fmt(e.angle_deg, sd("angle_deg"), "°", 1));
  // a line contact has no total force: its load per length stands in the force's cell
  set("force_n", e.line && e.force_n === null
      ? `line: ${fmt(e.line.load_n_per_mm, e.line.load_n_per_mm_std, "N/mm", 4)}`
      : fmt(e.force_n, sd("force_n"), "N", 3));
  set("x_mm", fmt(e.x_mm, sd("x_mm"), "mm", 2));
  set("y_mm", fmt(e.y_mm, sd("y_mm"), "mm", 2));
  set("ellipse", e.ellipse ? `${e.ellipse.a_mm.toFixed(2)} × ${e.ellipse.b_mm.toFixed(2)} mm @ ` +
                             `${e.ellipse.theta_deg.toFixed(0)}°` : "—");
  set("frames_used", e.frames_used === undefined ? "—" : String(e.frames_used));
  // each component on its own line with its own 1-sigma: no doubt which value a sigma is of
  set("vx_mm_s", fmt(e.vx_mm_s, sd("vx_mm_s"), "mm/s", 2));
  set("vy_mm_s", fmt(e.vy_mm_s, sd("vy_mm_s"), "mm/s", 2));
  set("angle_rate_deg_s", fmt(e.angle_rate_deg_s, sd("angle_rate_deg_s"), "°/s", 1));
  set("force_rate_n_s", fmt(e.force_rate_n_s, sd("force_rate_n_s"), "N/s", 3));
  const sh = e.shear;
  set("shear", sh && typeof sh.fx_n === "number"
      ? `${sh.fx_n.toFixed(3)}, ${sh.fy_n.toFixed(3)} N; ${typeof sh.torque_nmm === "number" ? sh.torque_nmm.toFixed(2) : "—"} N·mm` : "—");
  set("slip", e.slip ? e.slip.state : "—");
  set("gate", e.gate);
  set("seq", String(e.seq));
  set("latency_ms", fmt(e.latency_ms, null, "ms", 2));
  set("peak", e.peak === null || e.peak === undefined ? "—" : (e.peak * 100).toFixed(3) + " %");
  const label = $(".model-label", root);
  if (label) label.textContent = e.label ? `(${e.label})` : "";
}

// -- following one contact -------------------------------------------------------------------
function clickSensor(s, ev) {
  let id = null;
  if (ev.target === s.overlay) {
    const r = s.overlay.getBoundingClientRect();
    const x = (ev.clientX - r.left) * s.overlay.width / r.width;
    const y = (ev.clientY - r.top) * s.overlay.height / r.height;
    let best = Infinity;
    for (const d of s.drawn) {  // the nearest contact whose ellipse (or 14 px) holds the click
      const dist = Math.hypot(x - d.x, y - d.y);
      if (d.id !== null && dist <= Math.max(14, d.a || 0) && dist < best) { best = dist; id = d.id; }
    }
  }
  followThis(id === null ? {mode: "sensor", sensor: s.name, id: null}
                         : {mode: "contact", sensor: s.name, id});
}

function followThis(f) {
  state.follow = f;
  state.note = "";
  if (f.mode === "auto") state.auto = null;
}

// What the panel shows now: {mode, sensor, id, ring, est, src}.  A followed contact that is no
// longer listed has ended: the panel goes back to the strongest and says so.
function resolveTarget(now) {
  const f = state.follow;
  if (f.mode === "contact") {
    const s = state.sensors.get(f.sensor);
    const c = s ? contactsOf(s.est).find((x) => x.contact_id === f.id) : undefined;
    if (c) return {mode: "contact", sensor: s.name, id: f.id, ring: `${s.name}#${f.id}`,
                   est: withEnvelope(s.est, c), src: s.est};
    state.note = `contact ${f.id} on ${f.sensor} ended`;
    state.noteUntil = now + 5000;
    state.follow = {mode: "auto", sensor: null, id: null};
    state.auto = null;
  } else if (f.mode === "sensor") {
    const s = state.sensors.get(f.sensor);
    if (s) return {mode: "sensor", sensor: s.name, id: topId(s.est), ring: s.name, est: s.est,
                   src: s.est};
  }
  state.auto = strongest();
  const s = state.auto === null ? null : state.sensors.get(state.auto);
  return {mode: "auto", sensor: state.auto, id: s ? topId(s.est) : null, ring: state.auto,
          est: s ? s.est : null, src: s ? s.est : null};
}

// The sensor whose strongest contact has the largest force; the one followed so far unless
// another is SWITCH times stronger (no flapping between two equal presses); with no contact
// anywhere, the one followed so far (or the first).
function strongest() {
  let best = null;
  for (const s of state.sensors.values()) {
    if (s.est && s.est.contact && (!best || forceOf(s.est) > forceOf(best.est))) best = s;
  }
  const cur = state.auto === null ? null : state.sensors.get(state.auto);
  if (cur && cur.est && cur.est.contact && best !== cur &&
      forceOf(best.est) < SWITCH * forceOf(cur.est)) return cur.name;
  if (best) return best.name;
  if (cur) return cur.name;
  return state.sensors.size ? state.sensors.keys().next().value : null;
}

function showTarget(t, now) {
  const panel = $("#follow-panel");
  const key = `${t.mode}|${t.sensor}|${t.id}`;
  if (key !== state.shown.key) {
    const was = state.shown.key ? state.shown.key.split("|")[1] : null;
    for (const name of [was, t.sensor]) { const s = name && state.sensors.get(name); if (s) s.dirty = true; }
    for (const s of state.sensors.values()) s.el.classList.toggle("followed", s.name === t.sensor);
    panel.dataset.mode = t.mode;
    panel.dataset.sensor = t.sensor || "";
    panel.dataset.contactId = t.id === null || t.id === undefined ? "" : String(t.id);
    state.strip.drawn = 0;  // redraw now, from the new ring
    state.shown.key = key;
    state.shown.src = null;
  }
  const who = t.sensor === null ? "no sensor" :
    t.id === null || t.id === undefined ? t.sensor : `${t.sensor} · contact ${t.id}`;
  const why = t.mode === "contact" ? "clicked contact" : t.mode === "sensor" ? "clicked sensor" :
    t.est && t.est.contact ? "the strongest contact" : "the strongest contact: none now";
  const note = state.note && now < state.noteUntil ? ` · ${state.note}` : "";
  const label = `${who} (${why})${note}`;
  if (label !== state.shown.label) { $("#follow").textContent = label; state.shown.label = label; }
  if (t.src !== state.shown.src) {
    state.shown.src = t.src;
    if (t.est) drawReadouts(panel, t.est);
  }
}

// -- strip-chart rings: one per sensor (its strongest contact) and one per listed contact ----
function newRing() { return {buf: new Array(STRIP_CAP), start: 0, len: 0, last: 0}; }

function ringFor(key) {
  let ring = state.rings.get(key);
  if (ring) return ring;
  ring = newRing();
  ring.last = performance.now();
  state.rings.set(key, ring);
  if (key.includes("#")) {  // a contact's: keep at most CONTACT_RINGS, the latest updated
    const contacts = [...state.rings.entries()].filter(([k]) => k.includes("#"));
    if (contacts.length > CONTACT_RINGS) {
      contacts.sort((a, b) => a[1].last - b[1].last);
      for (const [k] of contacts.slice(0, contacts.length - CONTACT_RINGS)) state.rings.delete(k);
    }
  }
  return ring;
}

// -- strip chart: the last STRIP_S seconds of force, R1 and angle --------------------------
// One sample per estimate (or listed contact) received (time = when it arrived here), kept in
// a fixed ring.  Each lane draws the value as a line over its 1-sigma band; a null value
// (withheld, or no contact) breaks the line, and a withheld one is marked under the lane;
// hovering shows the value with its sigma, or why it is missing (the estimate's `reasons`).
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
  const strip = {canvas, tip, drawn: 0, mouse: null};
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

function stripAt(ring, i) { return ring.buf[(ring.start + i) % STRIP_CAP]; }

function ringAdd(ring, e) {
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
  ring.last = sample.t;
  if (ring.len < STRIP_CAP) {
    ring.buf[(ring.start + ring.len) % STRIP_CAP] = sample;
    ring.len++;
  } else {  // full: the oldest sample makes room
    ring.buf[ring.start] = sample;
    ring.start = (ring.start + 1) % STRIP_CAP;
  }
}

function laneRange(ring, k, lane, from) {
  if (lane.fixed) return lane.fixed;
  const tops = [];
  for (let i = 0; i < ring.len; i++) {
    const p = stripAt(ring, i);
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

function drawStrip(strip, ring, now) {
  const c = strip.canvas, ctx = c.getContext("2d");
  c.dataset.follows = state.shown.key || "";
  const P = STRIP_PAD, from = now - STRIP_S * 1000;
  while (ring.len && stripAt(ring, 0).t < from - 1000) {  // forget what scrolled off
    ring.buf[ring.start] = undefined;
    ring.start = (ring.start + 1) % STRIP_CAP;
    ring.len--;
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
    const [lo, hi] = laneRange(ring, k, lane, from);
    const Y = (v) => bottom - (Math.min(Math.max(v, lo), hi) - lo) / (hi - lo) * laneH;
    ctx.strokeStyle = "#2a333c";
    ctx.strokeRect(P.left + 0.5, top + 0.5, w, laneH);
    // runs of consecutive samples with a value: a line, and a band where sigma is known
    const runs = [];
    let run = [];
    for (let i = 0; i < ring.len; i++) {
      const p = stripAt(ring, i);
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
    const last = ring.len ? stripAt(ring, ring.len - 1) : null;
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
    if (m && m.y >= top && m.y <= bottom && m.x >= P.left && ring.len) {
      // the sample nearest the pointer in time (samples are in time order: bisect)
      const t = from + (m.x - P.left) / w * STRIP_S * 1000;
      let a = 0, b = ring.len - 1;
      while (a < b) { const mid = (a + b) >> 1; if (stripAt(ring, mid).t < t) a = mid + 1; else b = mid; }
      let best = stripAt(ring, a);
      if (a > 0 && Math.abs(stripAt(ring, a - 1).t - t) < Math.abs(best.t - t)) best = stripAt(ring, a - 1);
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
  const t = resolveTarget(now);
  showTarget(t, now);
  const st = state.strip, ring = (t.ring !== null && state.rings.get(t.ring)) || EMPTY_RING;
  // the strip scrolls, so it is redrawn while it shows anything (or is hovered), ~30 Hz
  if ((ring.len || st.mouse || !st.drawn) && now - st.drawn >= STRIP_MIN_DT) {
    st.drawn = now;
    drawStrip(st, ring, performance.now());
  }
  for (const s of state.sensors.values()) {
    if (!s.dirty) continue;
    s.dirty = false;
    drawMap(s);
    drawContacts(s, t);
    drawReadouts(s.el, s.est);
    $('[data-k="scale"]', s.el).textContent = `${(s.scale * 100).toFixed(2)} % strain`;
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
        (x.tracked_rate_hz ?? 0).toFixed(0),
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

const EMPTY_RING = newRing();
state.strip = newStrip($("#follow-panel canvas.strip"), $("#follow-panel .strip-tip"));
$("#follow-auto").addEventListener("click", () => followThis({mode: "auto", sensor: null, id: null}));
window.addEventListener("resize", layout);
loadSensors();
connect();
pollHealth();
requestAnimationFrame(render);
