// smarts viz: draws recorded or live episodes on a canvas; no libraries, no network beyond this server.
"use strict";

// Role 6 is the page's own: a vehicle an agent follows (its lead), whatever drives it.
const ROLE_NAMES = ["none", "agent", "social agent", "traffic", "replay", "pedestrian", "lead"];
const ROLE_COLOURS = ["#aaaaaa", "#e63c32", "#f0a028", "#4682e6", "#a05adc", "#fafafa", "#1de9b6"];
const FOLLOW_SCALE = 5;  // pixels per metre at least, once the camera follows an agent
const SIGNAL_COLOURS = [null, "#e53935", "#fdd835", "#43a047"];
const TRAIL_STEPS = 30;
const LIVE_FRAMES = 20000;  // most steps of a live episode kept in the page

const $ = (id) => document.getElementById(id);

// Every text from an episode (names, ids, metadata, file names) goes in as textContent, never as
// markup: recordings and live envs are untrusted input.
function el(tag, text, attrs) {
  const e = document.createElement(tag);
  if (text !== undefined && text !== null) e.textContent = String(text);
  if (attrs) for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
  return e;
}
const canvas = $("canvas");
const ctx = canvas.getContext("2d");

const state = {
  ep: null,           // {kind, meta, scene, frames, metrics}
  cur: 0,             // frame index
  playing: false,
  follow: true,       // live: stay on the newest frame
  view: { cx: 0, cy: 0, scale: 2 },  // world centre and pixels per metre
  selectedAgent: null,
  selectedVehicle: null,  // a road user that is not an agent
  selectedLane: null,
  roles: new Set([0, 1, 2, 3, 4, 5, 6]),
  trails: true,
  followCam: true,    // keep the selected agent in the middle of the view
  dirty: true,
  stats: { draws: 0, drawMs: 0, lastDrawMs: 0 },
  lanes: [],          // lanes with boundary polylines
  indexCache: new Map(),
};
window.viz = state;

// ------------------------------------------------------------------------- geometry
function boundaries(points, width) {
  const left = [], right = [];
  for (let i = 0; i < points.length; i++) {
    const a = points[Math.max(i - 1, 0)], b = points[Math.min(i + 1, points.length - 1)];
    let dx = b[0] - a[0], dy = b[1] - a[1];
    const n = Math.hypot(dx, dy) || 1;
    dx /= n; dy /= n;
    const h = width / 2;
    left.push([points[i][0] - dy * h, points[i][1] + dx * h]);
    right.push([points[i][0] + dy * h, points[i][1] - dx * h]);
  }
  return { left, right };
}

function toScreen(x, y) {
  const v = state.view;
  return [canvas.width / 2 + (x - v.cx) * v.scale, canvas.height / 2 - (y - v.cy) * v.scale];
}

function toWorld(px, py) {
  const v = state.view;
  return [v.cx + (px - canvas.width / 2) / v.scale, v.cy - (py - canvas.height / 2) / v.scale];
}

function distToSegment(p, a, b) {
  const dx = b[0] - a[0], dy = b[1] - a[1];
  const len2 = dx * dx + dy * dy;
  let t = len2 > 0 ? ((p[0] - a[0]) * dx + (p[1] - a[1]) * dy) / len2 : 0;
  t = Math.max(0, Math.min(1, t));
  return Math.hypot(p[0] - a[0] - t * dx, p[1] - a[1] - t * dy);
}

function vehicleCorners(f, i) {
  const x = f.x[i], y = f.y[i], h = f.h[i], l = f.length[i] / 2, w = f.width[i] / 2;
  const c = Math.cos(h), s = Math.sin(h);
  return [[l, w], [l, -w], [-l, -w], [-l, w]].map(([u, v]) => [x + c * u - s * v, y + s * u + c * v]);
}

function frameIndex(k) {  // vehicle id -> position in frame k's lists
  let m = state.indexCache.get(k);
  if (!m) {
    m = new Map();
    state.ep.frames[k].ids.forEach((id, i) => m.set(id, i));
    state.indexCache.set(k, m);
    if (state.indexCache.size > 4 * TRAIL_STEPS) state.indexCache.delete(state.indexCache.keys().next().value);
  }
  return m;
}

// ------------------------------------------------------------------------- loading
function setEpisode(ep) {
  state.ep = ep;
  state.cur = 0;
  state.indexCache.clear();
  state.selectedAgent = null;
  state.selectedVehicle = null;
  state.selectedLane = null;
  state.lanes = ep.scene.lanes.map((lane, i) => ({ ...lane, i, ...boundaries(lane.points, lane.width) }));
  fitView();
  const events = new Set();
  for (const f of ep.frames) for (const a of Object.values(f.agents)) a.events.forEach((e) => events.add(e));
  const sel = $("event");
  const names = ["collision", "off_road", "wrong_way", "reached_goal", ...events, ...(ep.meta.events || [])];
  sel.replaceChildren(...[...new Set(names)].map((e) => el("option", e)));
  updateSeek();
  showEpisode();
  showPanels();
  state.dirty = true;
}

function fitView() {
  const [x0, y0, x1, y1] = state.ep.scene.bounds;
  resize();
  state.view.cx = (x0 + x1) / 2;
  state.view.cy = (y0 + y1) / 2;
  state.view.scale = 0.92 * Math.min(canvas.width / Math.max(x1 - x0, 1), canvas.height / Math.max(y1 - y0, 1));
}

async function loadEpisode(id) {
  $("status").textContent = "loading episode…";
  const r = await fetch(`/api/episodes/${id}`);
  const body = await r.json();
  if (!r.ok) { $("status").textContent = body.error; return; }
  closeLive();
  setEpisode(body);
  $("status").textContent = `${body.kind}: ${body.meta.scenario} (${body.frames.length} steps)`;
}

let liveSocket = null;
function closeLive() { if (liveSocket) { liveSocket.onclose = null; liveSocket.close(); liveSocket = null; } }

function connectLive() {
  closeLive();
  $("status").textContent = "live: waiting for an env…";
  const ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws/live`);
  liveSocket = ws;
  ws.onmessage = (msg) => {
    const data = JSON.parse(msg.data);
    if (data.type === "episode") {
      setEpisode({ kind: "live", meta: data.meta, scene: data.scene, frames: [] });
      state.follow = true;
      $("status").textContent = `live: ${data.meta.scenario} (seed ${data.meta.seed})`;
    } else if (data.type === "frame" && state.ep) {
      const frames = state.ep.frames;
      frames.push(data.frame);
      if (frames.length > LIVE_FRAMES) {  // a long live episode keeps its newest steps
        const removed = frames.length - LIVE_FRAMES + 1000;
        frames.splice(0, removed);
        state.indexCache.clear();
        state.cur = Math.max(0, state.cur - removed);
      }
      if (state.follow) state.cur = frames.length - 1;
      updateSeek();
      showPanels();
      state.dirty = true;
    }
  };
  ws.onclose = () => { liveSocket = null; $("status").textContent = "live: disconnected; retrying…"; setTimeout(connectLive, 2000); };
}

async function start() {
  const r = await fetch("/api/episodes");
  const list = await r.json();
  const sel = $("episode");
  sel.replaceChildren(...list.episodes.map((e) => el("option", `${e.name} (${e.kind})`, { value: e.id })),
    el("option", "live", { value: "live" }));
  const want = new URLSearchParams(location.search).get("episode");
  const choice = want !== null ? want : list.episodes.length ? "0" : "live";
  sel.value = choice;
  sel.onchange = () => (sel.value === "live" ? connectLive() : loadEpisode(sel.value));
  if (choice === "live") connectLive(); else await loadEpisode(choice);
}

// ------------------------------------------------------------------------- drawing
function resize() {
  const r = canvas.getBoundingClientRect();
  const w = Math.max(Math.round(r.width), 1), h = Math.max(Math.round(r.height), 1);
  if (canvas.width !== w || canvas.height !== h) { canvas.width = w; canvas.height = h; state.dirty = true; }
}

function path(points, close) {
  ctx.beginPath();
  points.forEach((p, i) => { const [x, y] = toScreen(p[0], p[1]); if (i) ctx.lineTo(x, y); else ctx.moveTo(x, y); });
  if (close) ctx.closePath();
}

function drawMap() {
  const scene = state.ep.scene;
  ctx.fillStyle = "#2e5e38";
  ctx.fillRect(0, 0, canvas.width, canvas.height);
  ctx.fillStyle = "#4a4a4f";
  for (const j of scene.junctions) { path(j, true); ctx.fill(); }
  for (const lane of state.lanes) {  // road surface
    path([...lane.left, ...[...lane.right].reverse()], true);
    ctx.fillStyle = lane.internal ? "#505056" : "#46464a";
    ctx.fill();
  }
  ctx.lineWidth = 1;
  for (const lane of state.lanes) {  // boundaries and centre lines
    if (lane.internal) continue;
    ctx.strokeStyle = "#d8d8d8"; ctx.setLineDash([]);
    path(lane.left); ctx.stroke();
    path(lane.right); ctx.stroke();
    ctx.strokeStyle = "#77777c"; ctx.setLineDash([4, 6]);
    path(lane.points); ctx.stroke();
  }
  ctx.setLineDash([]);
  const sel = state.selectedLane;
  if (sel !== null) {
    const lane = state.lanes[sel];
    const mark = (i, colour) => { const l = state.lanes[i]; path([...l.left, ...[...l.right].reverse()], true); ctx.fillStyle = colour; ctx.fill(); };
    lane.successors.forEach((i) => mark(i, "rgba(80,200,255,0.45)"));
    lane.predecessors.forEach((i) => mark(i, "rgba(255,150,60,0.45)"));
    mark(sel, "rgba(255,255,0,0.5)");
  }
}

function drawSignals(f) {
  const signals = state.ep.scene.signals;
  if (!signals.length || !f || !f.signals.length) return;
  const best = new Map();  // incoming lane -> most permissive colour
  signals.forEach((s, k) => {
    const c = f.signals[k] || 0;
    best.set(s.from_lane, Math.max(best.get(s.from_lane) || 0, c));
    if (s.via_lane >= 0 && SIGNAL_COLOURS[c]) {
      const p = state.ep.scene.lanes[s.via_lane].points;
      const [x, y] = toScreen(p[Math.min(1, p.length - 1)][0], p[Math.min(1, p.length - 1)][1]);
      ctx.fillStyle = SIGNAL_COLOURS[c];
      ctx.beginPath(); ctx.arc(x, y, Math.max(2, 0.6 * state.view.scale), 0, 2 * Math.PI); ctx.fill();
    }
  });
  ctx.lineWidth = Math.max(2, 0.5 * state.view.scale);
  for (const [laneIndex, c] of best) {
    if (!SIGNAL_COLOURS[c]) continue;
    const lane = state.lanes[laneIndex];
    ctx.strokeStyle = SIGNAL_COLOURS[c];
    path([lane.left[lane.left.length - 1], lane.right[lane.right.length - 1]]);
    ctx.stroke();
  }
  ctx.lineWidth = 1;
}

function visible(f, i) { return state.roles.has(f.role[i]); }

function drawTrails(k) {
  const f = state.ep.frames[k];
  ctx.lineWidth = 1.5;
  for (let i = 0; i < f.ids.length; i++) {
    if (!visible(f, i)) continue;
    const pts = [];
    for (let j = Math.max(0, k - TRAIL_STEPS); j <= k; j++) {
      const idx = frameIndex(j).get(f.ids[i]);
      if (idx !== undefined) pts.push([state.ep.frames[j].x[idx], state.ep.frames[j].y[idx]]);
    }
    if (pts.length < 2) continue;
    ctx.strokeStyle = ROLE_COLOURS[f.role[i]] + "88";
    path(pts); ctx.stroke();
  }
}

function drawObservation(f) {
  const a = state.selectedAgent && f.agents[state.selectedAgent];
  if (!a) return;
  ctx.lineWidth = 1.5;
  for (const wpPath of a.waypoints || []) {
    const pts = wpPath.filter((p) => p && p[0] !== null);
    ctx.fillStyle = "#8ef";
    for (const p of pts) { const [x, y] = toScreen(p[0], p[1]); ctx.fillRect(x - 1.5, y - 1.5, 3, 3); }
  }
  for (const n of a.neighbours || []) {  // ring per observed neighbour; colour = how visible it is
    const [x, y] = toScreen(n[0], n[1]);
    const vis = n[2] === null ? 1 : n[2];
    ctx.strokeStyle = vis >= 0.999 ? "#00e5ff" : vis > 0 ? "#ff9800" : "#9e9e9e";
    ctx.setLineDash(vis > 0 ? [] : [3, 3]);
    ctx.beginPath(); ctx.arc(x, y, Math.max(6, 3 * state.view.scale), 0, 2 * Math.PI); ctx.stroke();
  }
  ctx.setLineDash([]);
}

function drawVehicles(f) {
  const selected = state.selectedAgent && f.agents[state.selectedAgent] ? f.agents[state.selectedAgent].vehicle : state.selectedVehicle;
  for (let i = 0; i < f.ids.length; i++) {
    if (!visible(f, i)) continue;
    path(vehicleCorners(f, i), true);
    ctx.fillStyle = ROLE_COLOURS[f.role[i]] || "#ccc";
    ctx.fill();
    ctx.lineWidth = f.ids[i] === selected ? 3 : 1;
    ctx.strokeStyle = f.ids[i] === selected ? "#ffeb3b" : "#111";
    ctx.stroke();
    const [fx, fy] = toScreen(f.x[i] + Math.cos(f.h[i]) * f.length[i] / 2, f.y[i] + Math.sin(f.h[i]) * f.length[i] / 2);
    const [cx, cy] = toScreen(f.x[i], f.y[i]);
    ctx.strokeStyle = "#111"; ctx.lineWidth = 1;
    ctx.beginPath(); ctx.moveTo(cx, cy); ctx.lineTo(fx, fy); ctx.stroke();
  }
}

// The follow camera: the view's centre on the selected agent's vehicle in the frame shown.
function followSelected(f) {
  if (!state.followCam || !state.selectedAgent || !f) return;
  const a = f.agents[state.selectedAgent];
  const i = a ? frameIndex(state.cur).get(a.vehicle) : undefined;
  if (i === undefined) return;
  state.view.cx = f.x[i]; state.view.cy = f.y[i];
}

function draw() {
  const t0 = performance.now();
  resize();
  if (!state.ep) { ctx.fillStyle = "#1d1f22"; ctx.fillRect(0, 0, canvas.width, canvas.height); return; }
  followSelected(state.ep.frames[state.cur]);
  drawMap();
  const f = state.ep.frames[state.cur];
  if (f) {
    drawSignals(f);
    if (state.trails) drawTrails(state.cur);
    drawVehicles(f);
    drawObservation(f);
  }
  const ms = performance.now() - t0;
  state.stats.draws += 1; state.stats.drawMs += ms; state.stats.lastDrawMs = ms;
}

// ------------------------------------------------------------------------- panels
const fmt = (v, d = 2) => (v === null || v === undefined ? "–" : typeof v === "number" ? (Number.isInteger(v) ? String(v) : v.toFixed(d)) : Array.isArray(v) ? v.map((x) => fmt(x, d)).join(", ") : String(v));

function rows(table, entries) {
  table.replaceChildren(...entries.map(([k, v]) => {
    const tr = el("tr");
    tr.append(el("td", k), el("td", v, { "data-field": k }));
    return tr;
  }));
}

function showEpisode() {
  const m = state.ep.meta;
  const entries = [["scenario", m.scenario], ["seed", fmt(m.seed)], ["kind", state.ep.kind], ["agents", (m.agent_ids || []).join(", ")]];
  if (m.note) entries.push(["note", m.note]);
  if (m.failure) entries.push(["failure", m.failure]);
  if (state.ep.metrics && state.ep.metrics.episode) {
    for (const [k, v] of Object.entries(state.ep.metrics.episode)) if (!k.startsWith("cost.")) entries.push([k, fmt(v, 3)]);
  }
  rows($("episode-table"), entries);
}

function showPanels() {
  const f = state.ep && state.ep.frames[state.cur];
  const panel = $("agent-panel");
  const id = state.selectedAgent;
  panel.hidden = id === null;
  if (id !== null) {
    $("agent-id").textContent = id;
    const a = f && f.agents[id];
    const entries = [];
    if (!a) entries.push(["state", "not on the road at this step"]);
    else {
      const i = frameIndex(state.cur).get(a.vehicle);
      const lane = f.lane[i] >= 0 ? state.ep.scene.lanes[f.lane[i]] : null;
      entries.push(["vehicle", a.vehicle], ["speed", `${fmt(f.speed[i])} m/s`], ["position", `${fmt(f.x[i], 1)}, ${fmt(f.y[i], 1)}`],
        ["heading", `${fmt(f.h[i], 3)} rad`], ["lane", lane ? lane.id : "–"]);
      // The action's fields by name and unit (the env says them per agent), not a bare list of numbers.
      const fields = (state.ep.meta.action_fields || {})[id];
      if (a.action && fields && fields.length === a.action.length) fields.forEach((name, j) => entries.push([`action ${name}`, fmt(a.action[j], 3)]));
      else entries.push(["action", fmt(a.action, 3)]);
      const leads = state.ep.meta.leads || {};
      if (leads[id]) entries.push(["lead", leads[id]]);
      entries.push(["reward", fmt(a.reward, 4)], ["events", a.events.length ? a.events.join(", ") : "none"],
        ["neighbours", String((a.neighbours || []).length)]);
      if (a.log) for (const [k, v] of Object.entries(a.log)) if (!["x", "y", "heading", "speed", "time"].includes(k)) entries.push([k, fmt(v, 3)]);
    }
    rows($("agent-table"), entries);
    const costs = state.ep.metrics && state.ep.metrics.agents && state.ep.metrics.agents[id];
    const metrics = $("agent-metrics");
    metrics.replaceChildren();
    if (costs) {
      const table = el("table");
      rows(table, Object.entries(costs).map(([k, v]) => [k, fmt(v, 3)]));
      metrics.append(el("h3", "Benchmark costs (lower is better)"), table);
    }
  }
  const vp = $("vehicle-panel");
  const vid = state.selectedVehicle;
  vp.hidden = vid === null;
  if (vid !== null) {
    $("vehicle-id").textContent = vid;
    const i = f ? frameIndex(state.cur).get(vid) : undefined;
    if (i === undefined) rows($("vehicle-table"), [["state", "not on the road at this step"]]);
    else {
      const lane = f.lane[i] >= 0 ? state.ep.scene.lanes[f.lane[i]] : null;
      rows($("vehicle-table"), [["role", ROLE_NAMES[f.role[i]] || "?"], ["speed", `${fmt(f.speed[i])} m/s`],
        ["position", `${fmt(f.x[i], 1)}, ${fmt(f.y[i], 1)}`], ["heading", `${fmt(f.h[i], 3)} rad`],
        ["lane", lane ? lane.id : "–"], ["size", `${fmt(f.length[i], 1)} x ${fmt(f.width[i], 1)} m`]]);
    }
  }
  const lp = $("lane-panel");
  lp.hidden = state.selectedLane === null;
  if (state.selectedLane !== null) {
    const l = state.ep.scene.lanes[state.selectedLane];
    const names = (ids) => ids.map((i) => state.ep.scene.lanes[i].id).join(", ") || "none";
    $("lane-id").textContent = l.id;
    rows($("lane-table"), [["id", l.id], ["road", l.road], ["index", l.index], ["junction", l.internal ? "yes" : "no"],
      ["length", `${fmt(l.length)} m`], ["width", `${fmt(l.width)} m`], ["speed limit", `${fmt(l.speed_limit)} m/s`],
      ["successors", names(l.successors)], ["predecessors", names(l.predecessors)]]);
  }
}

function updateSeek() {
  const n = state.ep ? state.ep.frames.length : 0;
  const seek = $("seek");
  seek.max = Math.max(n - 1, 0);
  seek.value = state.cur;
  const f = state.ep && state.ep.frames[state.cur];
  $("time").textContent = f ? `t = ${f.t.toFixed(1)} s · step ${f.step}` : "t = –";
}

function goTo(k) {
  if (!state.ep || !state.ep.frames.length) return;
  state.cur = Math.max(0, Math.min(state.ep.frames.length - 1, k));
  state.follow = state.cur === state.ep.frames.length - 1;
  updateSeek(); showPanels(); state.dirty = true;
}

// ------------------------------------------------------------------------- picking
function pickVehicle(w) {
  const f = state.ep.frames[state.cur];
  if (!f) return null;
  for (let i = f.ids.length - 1; i >= 0; i--) {
    if (!visible(f, i)) continue;
    const dx = w[0] - f.x[i], dy = w[1] - f.y[i], c = Math.cos(f.h[i]), s = Math.sin(f.h[i]);
    const u = c * dx + s * dy, v = -s * dx + c * dy;
    const pad = 3 / state.view.scale;
    if (Math.abs(u) <= f.length[i] / 2 + pad && Math.abs(v) <= f.width[i] / 2 + pad) return f.ids[i];
  }
  return null;
}

function pickLane(w) {
  let best = null, bestScore = Infinity;
  for (const lane of state.lanes) {
    for (let j = 0; j + 1 < lane.points.length; j++) {
      const d = distToSegment(w, lane.points[j], lane.points[j + 1]);
      const score = d + (lane.internal ? 0.5 : 0);  // a road lane wins where it overlaps a junction lane
      if (d <= lane.width / 2 && score < bestScore) { best = lane.i; bestScore = score; }
    }
  }
  return best;
}

function click(px, py) {
  const w = toWorld(px, py);
  const vid = pickVehicle(w);
  const f = state.ep.frames[state.cur];
  const agent = vid === null ? null : Object.keys(f.agents).find((a) => f.agents[a].vehicle === vid);
  state.selectedAgent = agent || null;
  state.selectedVehicle = vid !== null && !agent ? vid : null;
  state.selectedLane = vid === null ? pickLane(w) : null;
  if (state.selectedAgent && state.followCam) state.view.scale = Math.max(state.view.scale, FOLLOW_SCALE);
  showPanels(); state.dirty = true;
}

// For tests and scripts: where a vehicle or a lane point is on the canvas (CSS pixels).
state.screenOf = (vehicleId) => {
  const f = state.ep.frames[state.cur];
  const i = frameIndex(state.cur).get(vehicleId);
  if (i === undefined) return null;
  const [x, y] = toScreen(f.x[i], f.y[i]);
  const r = canvas.getBoundingClientRect();
  return [x * r.width / canvas.width, y * r.height / canvas.height];
};
state.screenOfPoint = (x, y) => {
  const [sx, sy] = toScreen(x, y);
  const r = canvas.getBoundingClientRect();
  return [sx * r.width / canvas.width, sy * r.height / canvas.height];
};
state.goTo = goTo;

// ------------------------------------------------------------------------- input
let drag = null;
canvas.addEventListener("mousedown", (e) => { drag = { x: e.offsetX, y: e.offsetY, moved: false }; });
canvas.addEventListener("mousemove", (e) => {
  if (!drag) return;
  const dx = e.offsetX - drag.x, dy = e.offsetY - drag.y;
  if (Math.abs(dx) + Math.abs(dy) > 3 || drag.moved) {
    if (!drag.moved && state.followCam && state.selectedAgent) { state.followCam = false; $("follow-cam").checked = false; }
    drag.moved = true;
    state.view.cx -= dx / state.view.scale; state.view.cy += dy / state.view.scale;
    drag.x = e.offsetX; drag.y = e.offsetY; state.dirty = true;
  }
});
canvas.addEventListener("mouseup", (e) => {
  if (drag && !drag.moved && state.ep) click(e.offsetX * canvas.width / canvas.clientWidth, e.offsetY * canvas.height / canvas.clientHeight);
  drag = null;
});
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  const before = toWorld(e.offsetX, e.offsetY);
  state.view.scale *= Math.exp(-e.deltaY * 0.0015);
  const after = toWorld(e.offsetX, e.offsetY);
  state.view.cx += before[0] - after[0]; state.view.cy += before[1] - after[1];
  state.dirty = true;
}, { passive: false });

$("play").onclick = () => {
  state.playing = !state.playing;
  if (state.playing && state.ep && state.cur >= state.ep.frames.length - 1 && state.ep.kind !== "live") goTo(0);
  $("play").textContent = state.playing ? "⏸" : "▶";
  lastTick = performance.now();
};
$("step").onclick = () => goTo(state.cur + 1);
$("step-back").onclick = () => goTo(state.cur - 1);
$("seek").oninput = (e) => goTo(Number(e.target.value));
$("trails").onchange = (e) => { state.trails = e.target.checked; state.dirty = true; };
$("follow-cam").onchange = (e) => {
  state.followCam = e.target.checked;
  if (state.followCam && state.selectedAgent) state.view.scale = Math.max(state.view.scale, FOLLOW_SCALE);
  state.dirty = true;
};
state.selectAgent = (id) => {  // for tests and scripts: what clicking the agent does
  state.selectedAgent = id; state.selectedVehicle = null; state.selectedLane = null;
  if (state.followCam) state.view.scale = Math.max(state.view.scale, FOLLOW_SCALE);
  showPanels(); state.dirty = true;
};
document.querySelectorAll("[data-role]").forEach((box) => {
  box.onchange = () => { const r = Number(box.dataset.role); if (box.checked) state.roles.add(r); else state.roles.delete(r); state.dirty = true; };
});
$("next-event").onclick = () => {
  const name = $("event").value;
  const frames = state.ep ? state.ep.frames : [];
  for (let k = state.cur + 1; k < frames.length; k++) {
    for (const [id, a] of Object.entries(frames[k].agents)) {
      if (a.events.includes(name)) { state.selectedAgent = id; state.selectedVehicle = null; state.selectedLane = null; goTo(k); $("status").textContent = `${name}: ${id} at step ${frames[k].step}`; return; }
    }
  }
  $("status").textContent = `no ${name} after this step`;
};
document.addEventListener("keydown", (e) => {
  if (e.target.tagName === "SELECT" || e.target.tagName === "INPUT") return;
  if (e.key === " ") { e.preventDefault(); $("play").click(); }
  if (e.key === "ArrowRight") goTo(state.cur + 1);
  if (e.key === "ArrowLeft") goTo(state.cur - 1);
});
window.addEventListener("resize", () => { state.dirty = true; });

// ------------------------------------------------------------------------- loop
let lastTick = performance.now();
let carry = 0;
function tick(now) {
  if (state.playing && state.ep && state.ep.frames.length) {
    const dt = (state.ep.meta.dt || 0.1) / Number($("speed").value);
    carry += now - lastTick;
    const steps = Math.floor(carry / (1000 * dt));
    if (steps > 0) {
      carry -= steps * 1000 * dt;
      const last = state.ep.frames.length - 1;
      if (state.cur < last) goTo(state.cur + steps);
      else if (state.ep.kind !== "live") { state.playing = false; $("play").textContent = "▶"; }
    }
  } else carry = 0;
  lastTick = now;
  if (state.dirty) { state.dirty = false; draw(); }
  requestAnimationFrame(tick);
}
requestAnimationFrame(tick);
start().catch((err) => { $("status").textContent = `error: ${err}`; });
