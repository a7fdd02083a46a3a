// sylva view: the page. It sends the controls as view requests over the WebSocket and draws
// the frames that come back (docs/view.md). While the user drags, one request is in flight at
// a time (the next goes when its frame arrives) and the server answers with previews; on
// release it sends the view once more, not interacting, and the refined frames follow.
"use strict";

const $ = (id) => document.getElementById(id);
const token = new URLSearchParams(location.search).get("token") || "";
const canvas = $("frame");
const ctx = canvas.getContext("2d");
const compass = $("compass");
const cctx = compass.getContext("2d");

const state = {
  ws: null,
  hello: null,
  camera: null,
  sun: { by: "angles", elevation: 45, azimuth: 180 },
  sunShown: { elevation: 45, azimuth: 180 },
  mode: "full",
  gather: 8,
  exposure: 0,
  seq: 0,
  inflight: null, // seq of the request awaiting its frame while dragging
  dirty: false,
  interacting: false,
  frameTimes: [],
  lastHeader: null,
};

// ---- connection -------------------------------------------------------------------------

function status(text) {
  $("status").textContent = text;
  $("overlay").classList.toggle("hidden", !text);
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  const ws = new WebSocket(`${proto}//${location.host}/ws?token=${encodeURIComponent(token)}`);
  ws.binaryType = "arraybuffer";
  state.ws = ws;
  ws.onmessage = (e) => (typeof e.data === "string" ? onText(JSON.parse(e.data)) : onFrame(e.data));
  ws.onclose = () => {
    status("disconnected from the server: reload the page once it runs again");
    state.ws = null;
  };
}

function onText(m) {
  if (m.type === "status") {
    status("preparing the scene…\n" + m.line);
  } else if (m.type === "hello") {
    state.hello = m;
    state.camera = { ...m.camera };
    state.sun = { by: "angles", elevation: m.sun.elevation, azimuth: m.sun.azimuth };
    state.sunShown = { elevation: m.sun.elevation, azimuth: m.sun.azimuth };
    state.gather = m.gather_rays;
    $("scene-name").textContent = m.scene;
    $("light-name").textContent = m.light + " · " + m.device;
    $("gather").max = Math.min(m.max_gather_rays, 64);
    $("gather").value = m.gather_rays;
    $("gather-label").textContent = m.gather_rays;
    $("lat").value = m.lat.toFixed(1);
    $("lon").value = m.lon.toFixed(1);
    $("sun-note").textContent = m.sun_moves ? "" : "this scene was prepared without base solutions: the sun is fixed";
    status("");
    drawCompass();
    request(false);
  } else if (m.type === "error") {
    if (m.seq !== null && m.seq === state.inflight) state.inflight = null;
    $("sun-note").textContent = m.message;
    if (!state.hello) status(m.message);
    pump();
  } else if (m.type === "saved") {
    $("saved").textContent = `saved ${m.path} (${m.samples} samples per pixel)`;
  }
}

async function onFrame(buffer) {
  const view = new DataView(buffer);
  const len = view.getUint32(0, true);
  const header = JSON.parse(new TextDecoder().decode(new Uint8Array(buffer, 4, len)));
  const jpeg = new Blob([new Uint8Array(buffer, 4 + len)], { type: "image/jpeg" });
  if (state.inflight !== null && header.seq >= state.inflight) state.inflight = null;
  pump();
  const bitmap = await createImageBitmap(jpeg);
  ctx.imageSmoothingEnabled = true;
  ctx.drawImage(bitmap, 0, 0, canvas.width, canvas.height);
  bitmap.close();
  state.lastHeader = header;
  const now = performance.now();
  state.frameTimes.push(now);
  while (state.frameTimes.length && now - state.frameTimes[0] > 1000) state.frameTimes.shift();
  state.sunShown = { elevation: header.sun_elevation, azimuth: header.sun_azimuth };
  $("stat-fps").textContent = `${state.frameTimes.length} fps`;
  const ms = header.render_ms;
  $("stat-ms").textContent = ms < 10000 ? `${ms.toFixed(0)} ms` : `${(ms / 1000).toFixed(1)} s`;
  $("stat-samples").textContent = `${header.samples} spp${header.refined ? "" : " preview"}`;
  $("stat-size").textContent = `${header.width}×${header.height}`;
  $("stat-solves").textContent = `LB solves ${header.lb_solves}`;
  canvas.dataset.frames = String(Number(canvas.dataset.frames || 0) + 1);
  canvas.dataset.solves = String(header.lb_solves);
  if (state.sun.by === "clock") $("sun-note").textContent = "";
  drawCompass();
}

// ---- requests ---------------------------------------------------------------------------

function frameSize() {
  const dpr = Math.min(window.devicePixelRatio || 1, 2);
  let w = Math.max(16, Math.round(canvas.clientWidth * dpr));
  let h = Math.max(16, Math.round(canvas.clientHeight * dpr));
  const max = state.hello ? state.hello.max_pixels : 1 << 20;
  const k = Math.min(1, Math.sqrt(max / (w * h)));
  w = Math.max(16, Math.floor(w * k));
  h = Math.max(16, Math.floor(h * k));
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
  return [w, h];
}

function request(interacting) {
  state.interacting = interacting;
  state.dirty = true;
  pump();
}

// Sends the controls unless a request is in flight while dragging (then the frame that
// answers it sends the next). Releases always go at once: they start the refinement.
function pump() {
  const ws = state.ws;
  if (!ws || ws.readyState !== WebSocket.OPEN || !state.hello || !state.dirty) return;
  if (state.interacting && state.inflight !== null) return;
  const [width, height] = frameSize();
  state.seq += 1;
  const m = {
    type: "view",
    seq: state.seq,
    sun: state.sun,
    camera: state.camera,
    mode: state.mode,
    gather_rays: state.gather,
    exposure: state.exposure,
    width,
    height,
    interacting: state.interacting,
  };
  ws.send(JSON.stringify(m));
  state.dirty = false;
  state.inflight = state.interacting ? state.seq : null;
}

// ---- the camera: orbit, pan, zoom ---------------------------------------------------------

const pointers = new Map();
let pinch = null;

function orbitBy(dx, dy) {
  const c = state.camera;
  c.yaw_deg += dx * 0.3;
  c.pitch_deg = Math.max(-89, Math.min(89, c.pitch_deg + dy * 0.3));
}

function panBy(dx, dy) {
  const c = state.camera;
  const y = (c.yaw_deg * Math.PI) / 180, p = (c.pitch_deg * Math.PI) / 180;
  const back = [Math.cos(p) * Math.cos(y), Math.sin(p), Math.cos(p) * Math.sin(y)];
  // right = forward × up with forward = -back; up' = right × forward.
  const right = norm([back[2], 0, -back[0]]);
  const up = cross(right, back.map((v) => -v));
  const k = (c.distance * 0.0015) * (2 / (window.devicePixelRatio || 1));
  for (let i = 0; i < 3; i++) c.target[i] += (-dx * right[i] + dy * up[i]) * k;
}

function zoomBy(factor) {
  const c = state.camera;
  c.distance = Math.max(0.1, Math.min(1e5, c.distance * factor));
}

const norm = (v) => {
  const l = Math.hypot(v[0], v[1], v[2]) || 1;
  return v.map((x) => x / l);
};
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];

canvas.addEventListener("contextmenu", (e) => e.preventDefault());
canvas.addEventListener("pointerdown", (e) => {
  canvas.setPointerCapture(e.pointerId);
  pointers.set(e.pointerId, { x: e.clientX, y: e.clientY, pan: e.shiftKey || e.button === 2 });
  canvas.classList.add("dragging");
});
canvas.addEventListener("pointermove", (e) => {
  const p = pointers.get(e.pointerId);
  if (!p || !state.camera) return;
  const dx = e.clientX - p.x, dy = e.clientY - p.y;
  p.x = e.clientX;
  p.y = e.clientY;
  if (pointers.size === 2) {
    const [a, b] = [...pointers.values()];
    const d = Math.hypot(a.x - b.x, a.y - b.y);
    if (pinch) zoomBy(pinch / Math.max(d, 1));
    pinch = d;
    panBy(dx / 2, dy / 2);
  } else if (p.pan) {
    panBy(dx, dy);
  } else {
    orbitBy(dx, dy);
  }
  request(true);
});
const release = (e) => {
  if (!pointers.delete(e.pointerId)) return;
  if (pointers.size < 2) pinch = null;
  if (pointers.size === 0) {
    canvas.classList.remove("dragging");
    request(false);
  }
};
canvas.addEventListener("pointerup", release);
canvas.addEventListener("pointercancel", release);
let wheelTimer = null;
canvas.addEventListener("wheel", (e) => {
  e.preventDefault();
  if (!state.camera) return;
  zoomBy(Math.exp(e.deltaY * 0.0015));
  request(true);
  clearTimeout(wheelTimer);
  wheelTimer = setTimeout(() => request(false), 200);
}, { passive: false });
canvas.addEventListener("dblclick", () => resetView());

function resetView() {
  if (!state.hello) return;
  state.camera = { ...state.hello.camera, target: [...state.hello.camera.target] };
  request(false);
}

// ---- the sun: compass and time of day ----------------------------------------------------

function compassPoint(elevation, azimuth) {
  const r = (compass.width / 2 - 14) * (1 - elevation / 90);
  const a = (azimuth * Math.PI) / 180;
  return [compass.width / 2 + r * Math.sin(a), compass.height / 2 - r * Math.cos(a)];
}

function drawCompass() {
  const w = compass.width, c = w / 2, R = c - 14;
  cctx.clearRect(0, 0, w, w);
  const sky = cctx.createRadialGradient(c, c, 0, c, c, R);
  sky.addColorStop(0, "#3f6f9f");
  sky.addColorStop(1, "#182a3a");
  cctx.fillStyle = sky;
  cctx.beginPath();
  cctx.arc(c, c, R, 0, 2 * Math.PI);
  cctx.fill();
  cctx.strokeStyle = "rgba(255,255,255,0.18)";
  for (const e of [30, 60]) {
    cctx.beginPath();
    cctx.arc(c, c, R * (1 - e / 90), 0, 2 * Math.PI);
    cctx.stroke();
  }
  cctx.fillStyle = "#8fa197";
  cctx.font = "11px system-ui";
  cctx.textAlign = "center";
  cctx.textBaseline = "middle";
  cctx.fillText("N", c, 6);
  cctx.fillText("S", c, w - 6);
  cctx.fillText("E", w - 6, c);
  cctx.fillText("W", 6, c);
  const [x, y] = compassPoint(state.sunShown.elevation, state.sunShown.azimuth);
  cctx.fillStyle = "#f2c14e";
  cctx.beginPath();
  cctx.arc(x, y, 8, 0, 2 * Math.PI);
  cctx.fill();
  $("sun-elev").textContent = `${state.sunShown.elevation.toFixed(1)}°`;
  $("sun-azim").textContent = `${state.sunShown.azimuth.toFixed(1)}°`;
}

function sunFromCompass(e) {
  const rect = compass.getBoundingClientRect();
  const k = compass.width / rect.width;
  const x = (e.clientX - rect.left) * k - compass.width / 2;
  const y = (e.clientY - rect.top) * k - compass.height / 2;
  const R = compass.width / 2 - 14;
  const r = Math.min(Math.hypot(x, y), R);
  const elevation = Math.max(0.5, 90 * (1 - r / R));
  const azimuth = ((Math.atan2(x, -y) * 180) / Math.PI + 360) % 360;
  state.sun = { by: "angles", elevation, azimuth };
  state.sunShown = { elevation, azimuth };
  drawCompass();
}

let sunDrag = false;
compass.addEventListener("pointerdown", (e) => {
  compass.setPointerCapture(e.pointerId);
  sunDrag = true;
  sunFromCompass(e);
  request(true);
});
compass.addEventListener("pointermove", (e) => {
  if (!sunDrag) return;
  sunFromCompass(e);
  request(true);
});
const sunRelease = () => {
  if (!sunDrag) return;
  sunDrag = false;
  request(false);
};
compass.addEventListener("pointerup", sunRelease);
compass.addEventListener("pointercancel", sunRelease);

function clockSun() {
  const minutes = Number($("time").value);
  const hh = String(Math.floor(minutes / 60)).padStart(2, "0");
  const mm = String(minutes % 60).padStart(2, "0");
  $("time-label").textContent = `${hh}:${mm}`;
  const utc = $("utc").value.trim();
  state.sun = {
    by: "clock",
    lat: Number($("lat").value),
    lon: Number($("lon").value),
    date: $("date").value,
    time: `${hh}:${mm}`,
    utc_offset: utc === "" ? null : utc,
  };
}

$("time").addEventListener("input", () => { clockSun(); request(true); });
$("time").addEventListener("change", () => { clockSun(); request(false); });
for (const id of ["date", "lat", "lon", "utc"]) {
  $(id).addEventListener("change", () => { clockSun(); request(false); });
}

// ---- light, exposure, saving -------------------------------------------------------------

for (const b of document.querySelectorAll(".segmented button")) {
  b.addEventListener("click", () => {
    for (const o of document.querySelectorAll(".segmented button")) o.classList.toggle("on", o === b);
    state.mode = b.dataset.mode;
    request(false);
  });
}
$("gather").addEventListener("input", () => {
  state.gather = Number($("gather").value);
  $("gather-label").textContent = state.gather;
});
$("gather").addEventListener("change", () => request(false));
$("exposure").addEventListener("input", () => {
  state.exposure = Number($("exposure").value);
  $("exposure-label").textContent = state.exposure.toFixed(1);
  request(true);
});
$("exposure").addEventListener("change", () => request(false));
for (const [id, format] of [["save-png", "png"], ["save-exr", "exr"]]) {
  $(id).addEventListener("click", () => {
    if (state.ws && state.ws.readyState === WebSocket.OPEN) {
      state.ws.send(JSON.stringify({ type: "save", format }));
    }
  });
}
$("reset").addEventListener("click", resetView);

let resizeTimer = null;
window.addEventListener("resize", () => {
  clearTimeout(resizeTimer);
  resizeTimer = setTimeout(() => request(false), 150);
});

drawCompass();
connect();
