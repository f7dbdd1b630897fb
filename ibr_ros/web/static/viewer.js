// SPDX-FileCopyrightText: the ibr_ros developers
// SPDX-License-Identifier: BSD-3-Clause
// The web viewer page: sends key/mouse input, shows each view as it arrives (then says so, so that
// the server sends the next), draws the keyframe map and the readout. The flying itself (speed,
// turns, the newest-only gates) is done by the server (ibr_ros.core.navigation).
'use strict';

const KEYS = {
  KeyW: ['forward', 1], KeyS: ['forward', -1], KeyD: ['right', 1], KeyA: ['right', -1],
  KeyE: ['up', 1], KeyQ: ['up', -1], ArrowLeft: ['yaw', 1], ArrowRight: ['yaw', -1],
  ArrowUp: ['pitch', 1], ArrowDown: ['pitch', -1],
};
const WINDOW_MS = 2000; // the readout's window

const view = document.getElementById('view');
const ctx = view.getContext('2d');
const mapCanvas = document.getElementById('map');
const mapCtx = mapCanvas.getContext('2d');
const readout = document.getElementById('readout');
const statusBox = document.getElementById('status');
const poseBox = document.getElementById('pose');

const state = {
  seq: 0, sentAt: new Map(), held: new Set(), fast: false, drag: [0, 0], dragging: false,
  shownAt: [], latencies: [], header: null, frames: 0, keyframes: [], mapPx: 256,
  status: null, saved: null, errors: 0, rate: 0, latency: null, lastTick: null,
};
window.ibrViewer = state; // for tests and the console

const ws = new WebSocket(`ws://${location.host}/ws`);
ws.binaryType = 'arraybuffer';
ws.onopen = () => { statusBox.textContent = 'connected'; };
ws.onclose = () => { statusBox.textContent = 'disconnected (reload to reconnect)'; };
ws.onmessage = (ev) => (typeof ev.data === 'string' ? onText(JSON.parse(ev.data)) : onFrame(ev.data));

function send(msg) { if (ws.readyState === WebSocket.OPEN) ws.send(JSON.stringify(msg)); }

function onText(msg) {
  if (msg.type === 'hello' || msg.type === 'map') {
    state.keyframes = msg.keyframes; state.mapPx = msg.map_px; state.speed = msg.speed_mps;
    mapCanvas.width = mapCanvas.height = msg.map_px;
    if (!msg.keyframes.length) statusBox.textContent = 'waiting for keyframes';
    drawMap();
  } else if (msg.type === 'status') {
    state.status = msg;
    statusBox.textContent = `${msg.result}: ${msg.reason} ${msg.message || ''}`;
  } else if (msg.type === 'saved') {
    state.saved = msg.path; statusBox.textContent = `saved ${msg.path}`;
  } else if (msg.type === 'error') {
    state.errors += 1; statusBox.textContent = `error: ${msg.message}`;
  }
}

async function onFrame(data) {
  const n = new DataView(data).getUint32(0);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(data, 4, n)));
  const bitmap = await createImageBitmap(new Blob([new Uint8Array(data, 4 + n)], { type: 'image/jpeg' }));
  if (view.width !== bitmap.width || view.height !== bitmap.height) {
    view.width = bitmap.width; view.height = bitmap.height;
  }
  ctx.drawImage(bitmap, 0, 0);
  bitmap.close();
  send({ type: 'shown', stamp: header.stamp });
  const now = performance.now();
  state.header = header; state.frames += 1;
  state.shownAt.push(now);
  if (state.sentAt.has(header.seq)) state.latencies.push([now, now - state.sentAt.get(header.seq)]);
  for (const s of state.sentAt.keys()) if (s <= header.seq) state.sentAt.delete(s);
  if (header.result === 'answered') statusBox.textContent = 'answered';
  updateReadout(now);
  drawMap();
  const p = header.pose;
  poseBox.textContent = `x ${p[0][3].toFixed(2)} y ${p[1][3].toFixed(2)} z ${p[2][3].toFixed(2)} m\n`
    + `rendered ${(100 * header.valid_fraction).toFixed(1)} %, render ${header.render_ms} ms\n`
    + `superseded: ${header.stats.superseded_queries} queries, ${header.stats.superseded_views} views`;
}

function median(xs) {
  if (!xs.length) return null;
  const s = [...xs].sort((a, b) => a - b);
  return s[Math.floor(s.length / 2)];
}

function updateReadout(now) {
  state.shownAt = state.shownAt.filter((t) => now - t <= WINDOW_MS);
  state.latencies = state.latencies.filter(([t]) => now - t <= WINDOW_MS);
  const span = state.shownAt.length > 1 ? state.shownAt[state.shownAt.length - 1] - state.shownAt[0] : 0;
  state.rate = span > 0 ? (1000 * (state.shownAt.length - 1)) / span : 0;
  state.latency = median(state.latencies.map(([, l]) => l));
  const h = state.header;
  const size = h ? `${h.width}x${h.height}` : '';
  const lat = state.latency === null ? '-' : `${state.latency.toFixed(0)} ms`;
  readout.textContent = `${state.rate.toFixed(1)} views/s | latency ${lat} | ${size}`;
}

function drawMap() {
  const c = mapCtx;
  c.clearRect(0, 0, mapCanvas.width, mapCanvas.height);
  const arrow = (u, v, heading, len) => {
    c.beginPath(); c.moveTo(u, v); c.lineTo(u + len * Math.cos(heading), v + len * Math.sin(heading)); c.stroke();
  };
  c.strokeStyle = '#8fb3ff'; c.fillStyle = '#8fb3ff'; c.lineWidth = 1;
  for (const k of state.keyframes) {
    c.beginPath(); c.arc(k.u, k.v, 4, 0, 2 * Math.PI); c.fill();
    arrow(k.u, k.v, k.heading, 10);
  }
  if (state.header) { // the camera; kept on the map's edge (hollow) when it flew off the map
    const [mu, mv, heading] = state.header.map;
    const u = Math.max(5, Math.min(mapCanvas.width - 5, mu));
    const v = Math.max(5, Math.min(mapCanvas.height - 5, mv));
    c.strokeStyle = '#ff6b4a'; c.fillStyle = '#ff6b4a'; c.lineWidth = 2;
    c.beginPath(); c.arc(u, v, 5, 0, 2 * Math.PI);
    if (u === mu && v === mv) c.fill(); else c.stroke();
    arrow(u, v, heading, 16);
  }
}

function tick(now) {
  const dt = state.lastTick === null ? 0 : Math.min((now - state.lastTick) / 1000, 0.25);
  state.lastTick = now;
  const msg = { type: 'fly', forward: 0, right: 0, up: 0, yaw: 0, pitch: 0, drag: state.drag, dt, fast: state.fast };
  for (const code of state.held) { const [axis, sign] = KEYS[code]; msg[axis] = Math.max(-1, Math.min(1, msg[axis] + sign)); }
  const moving = state.held.size > 0 || state.drag[0] !== 0 || state.drag[1] !== 0;
  if (moving && dt > 0) {
    state.seq += 1; msg.seq = state.seq; state.sentAt.set(state.seq, now);
    send(msg);
    state.drag = [0, 0];
  }
  if (state.shownAt.length) updateReadout(now);
  requestAnimationFrame(tick);
}
requestAnimationFrame(tick);

window.addEventListener('keydown', (ev) => {
  state.fast = ev.shiftKey;
  if (KEYS[ev.code]) { state.held.add(ev.code); ev.preventDefault(); }
});
window.addEventListener('keyup', (ev) => {
  state.fast = ev.shiftKey;
  state.held.delete(ev.code);
});
window.addEventListener('blur', () => state.held.clear());
view.addEventListener('mousedown', (ev) => { state.dragging = true; view.focus(); ev.preventDefault(); });
window.addEventListener('mouseup', () => { state.dragging = false; });
window.addEventListener('mousemove', (ev) => {
  if (state.dragging) { state.drag[0] += ev.movementX; state.drag[1] += ev.movementY; }
});
mapCanvas.addEventListener('click', (ev) => {
  const r = mapCanvas.getBoundingClientRect();
  state.seq += 1; state.sentAt.set(state.seq, performance.now());
  send({ type: 'jump', seq: state.seq,
    u: ((ev.clientX - r.left) * mapCanvas.width) / r.width, v: ((ev.clientY - r.top) * mapCanvas.height) / r.height });
});
document.getElementById('save').addEventListener('click', () => send({ type: 'save' }));
