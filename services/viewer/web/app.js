// The viewer's page (docs/viewer.md): the rig's 3D scene, each camera's monitor, the services'
// health. Data comes over one WebSocket from the viewer service; the scene's fixed parts
// (cameras, bodies, models' links) from /api/rig. World frame: z up, metres.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';

THREE.Object3D.DEFAULT_UP.set(0, 0, 1);

const TRAIL_POINTS = 90;       // 1.5 s at 60 Hz
const FORGET_MS = 1000;        // an object not seen for this long leaves the scene
const ALIVE_MS = 3000;         // a service without a health report for this long is shown dead
const COVERAGE_SHOWN_MS = 10000; // a wand calibration's coverage stays drawn this long after its last report
const CAMERA_COLOUR = 0x4fc3f7;
const $ = (id) => document.getElementById(id);

// What tests read (tests/clients/viewer_check.py): counts, the newest frame drawn, the view.
const state = window.stereoscope = {
  connects: 0, poseFrames: 0, lastPoseSequence: null, truthFrames: 0, previews: 0, healthReports: 0, coverageReports: 0, errors: [],
  drawnCoverage: {},
  socketOpen: false, frozen: false, drawnFrame: null, drawnChains: [],
  freeze(on) { state.frozen = on; },
  health(key) { return health.get(key)?.h ?? null; },
  healthAgeMs(key) { const e = health.get(key); return e ? performance.now() - e.at : null; },
  view() {
    const r = (renderer ? renderer.domElement : view).getBoundingClientRect();
    return {
      position: camera.position.toArray(), quaternion: camera.quaternion.toArray(),
      fov_deg: camera.fov, aspect: camera.aspect, near: camera.near,
      rect: [r.left, r.top, r.width, r.height], dpr: window.devicePixelRatio,
    };
  },
};

const single = location.pathname.startsWith('/camera/')
  ? decodeURIComponent(location.pathname.slice('/camera/'.length)) : null;
if (single) document.body.classList.add('single');

// ---- 3D scene -------------------------------------------------------------------------------
const view = $('view');
// A browser without WebGL still gets every camera's monitor and the services' table: the 3D
// view says it is unavailable instead of the whole page waiting.
let renderer = null;
try {
  renderer = new THREE.WebGLRenderer({ antialias: true, preserveDrawingBuffer: true });
  renderer.setPixelRatio(window.devicePixelRatio);
  view.prepend(renderer.domElement);
} catch (e) {
  state.noWebGL = String(e && e.message || e);
  const note = document.createElement('div');
  note.id = 'nogl';
  note.textContent = '3D view unavailable: this browser cannot create a WebGL context. ' +
    'The camera monitors and the services below still update.';
  view.prepend(note);
}
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x15171a);
const camera = new THREE.PerspectiveCamera(50, 1, 0.01, 200);
const controls = new OrbitControls(camera, renderer ? renderer.domElement : view);
controls.enableDamping = false;

function resize() {
  const w = Math.max(1, view.clientWidth), h = Math.max(1, view.clientHeight);
  if (renderer) renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
}
window.addEventListener('resize', resize);

function label(text, colour = '#d8dde3', height = 0.06) {
  const c = document.createElement('canvas');
  const g = c.getContext('2d');
  g.font = '28px sans-serif';
  c.width = Math.ceil(g.measureText(text).width) + 8; c.height = 36;
  g.font = '28px sans-serif'; g.fillStyle = colour; g.fillText(text, 4, 28);
  const s = new THREE.Sprite(new THREE.SpriteMaterial({ map: new THREE.CanvasTexture(c), depthTest: false }));
  s.scale.set(height * c.width / c.height, height, 1);
  return s;
}

let rig = null, home = null, markerRadius = 0.01;
function buildRig(r) {
  rig = r;
  $('rig').textContent = r.rig;
  const lo = new THREE.Vector3(...r.extent_m.min), hi = new THREE.Vector3(...r.extent_m.max);
  const span = Math.max(0.5, lo.distanceTo(hi));
  markerRadius = Math.min(0.03, Math.max(0.006, span / 120));
  const size = Math.ceil(span * 1.5);
  const grid = new THREE.GridHelper(size, size * 10, 0x555a60, 0x2c3036);
  grid.rotation.x = Math.PI / 2;   // into the xy plane: the floor of a z-up world
  scene.add(grid);
  scene.add(new THREE.AxesHelper(Math.min(0.5, span / 4)));
  for (const c of r.cameras) {
    const o = new THREE.Vector3(...c.centre_m);
    const k = c.frustum_m.map((p) => new THREE.Vector3(...p));
    const pts = [];
    for (let i = 0; i < 4; i++) pts.push(o, k[i], k[i], k[(i + 1) % 4]);
    const g = new THREE.BufferGeometry().setFromPoints(pts);
    scene.add(new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: CAMERA_COLOUR })));
    const l = label(c.id, '#4fc3f7', markerRadius * 1.5);
    l.position.copy(o).add(new THREE.Vector3(0, 0, markerRadius * 2));
    scene.add(l);
  }
  // Looking at the middle of the volume, from the floor to the cameras.
  const centre = lo.clone().add(hi).multiplyScalar(0.5);
  // From the top: above the highest camera, far enough to see the cameras' spread.
  const across = Math.max(hi.x - lo.x, hi.y - lo.y);
  home = { target: centre, floor: new THREE.Vector3(centre.x, centre.y, 0), span,
           topHeight: hi.z + Math.max(1.5, 1.2 * across) };
  resetView();
}

function resetView() {
  if (!home) return;
  controls.target.copy(home.target);
  camera.position.copy(home.target).add(new THREE.Vector3(-0.9, -1.3, 1.0).multiplyScalar(home.span * 0.9));
  controls.update();
}

function topView() {
  if (!home) return;
  controls.target.copy(home.floor);
  // Straight down, +y up on the screen (a hair off the pole so the orbit keeps its bearing).
  camera.position.copy(home.floor).add(new THREE.Vector3(0, -1e-3, home.topHeight));
  controls.update();
}

// Markers with trails, coloured by residual; bodies with axes and names; truth as rings.
const sphere = new THREE.SphereGeometry(1, 16, 12);
const objects = new Map();   // object_id -> {mesh, trail, points, seen}
const bodies = new Map();    // name -> {group, seen}
const chains = new Map();    // model name -> {lines, joints, label, seen}
const CHAIN_COLOUR = 0xff00ff, CHAIN_HELD_COLOUR = 0x8a4f8a;
const ghosts = [];
let showTrails = true, showTruth = true;

function residualColour(px) {
  const t = Math.min(1, Math.max(0, px / 2));
  return new THREE.Color().setHSL((1 - t) * 0.33, 1, 0.5);
}

function objectFor(id) {
  let o = objects.get(id);
  if (!o) {
    const mesh = new THREE.Mesh(sphere, new THREE.MeshBasicMaterial());
    mesh.scale.setScalar(markerRadius);
    const geo = new THREE.BufferGeometry();
    geo.setAttribute('position', new THREE.BufferAttribute(new Float32Array(TRAIL_POINTS * 3), 3));
    const trail = new THREE.Line(geo, new THREE.LineBasicMaterial({ color: 0x9e9e9e, transparent: true, opacity: 0.6 }));
    scene.add(mesh, trail);
    o = { mesh, trail, points: [], seen: 0 };
    objects.set(id, o);
  }
  return o;
}

function bodyFor(name) {
  let b = bodies.get(name);
  if (!b) {
    const group = new THREE.Group();
    group.add(new THREE.AxesHelper(0.12));
    const l = label(name, '#ffffff', 0.05);
    l.position.set(0, 0, 0.08);
    group.add(l);
    scene.add(group);
    b = { group, seen: 0 };
    bodies.set(name, b);
  }
  return b;
}

// A kinematic model as its chain: a sphere at each link's origin and a line from each link's
// parent to it (parents from /api/rig), drawn over everything else; magenta while the fit is
// valid, dull while the frame carries the last values.
function chainFor(m) {
  let c = chains.get(m.name);
  const def = rig?.models?.find((d) => d.name === m.name);
  if (!c && def) {
    const pairs = def.links.filter((l) => l.parent !== null).length;
    const geo = new THREE.BufferGeometry();
    geo.setAttribute('position', new THREE.BufferAttribute(new Float32Array(pairs * 6), 3));
    const material = new THREE.LineBasicMaterial({ color: CHAIN_COLOUR, depthTest: false });
    const lines = new THREE.LineSegments(geo, material);
    lines.renderOrder = 2;
    const jointMaterial = new THREE.MeshBasicMaterial({ color: CHAIN_COLOUR, depthTest: false });
    const joints = def.links.map(() => {
      const s = new THREE.Mesh(sphere, jointMaterial);
      s.scale.setScalar(markerRadius * 0.8);
      s.renderOrder = 2;
      scene.add(s);
      return s;
    });
    const l = label(m.name, '#ff80ff', 0.05);
    scene.add(lines, l);
    c = { def, lines, material, jointMaterial, joints, label: l, seen: 0 };
    chains.set(m.name, c);
  }
  return c;
}

function drawChains(f, now) {
  const drawn = [];
  for (const m of f.models || []) {
    const c = chainFor(m);
    if (!c || m.links.length !== c.def.links.length) continue;
    c.seen = now;
    const colour = m.valid ? CHAIN_COLOUR : CHAIN_HELD_COLOUR;
    c.material.color.setHex(colour);
    c.jointMaterial.color.setHex(colour);
    const a = c.lines.geometry.attributes.position;
    let k = 0;
    c.def.links.forEach((l, i) => {
      c.joints[i].position.set(...m.links[i].position_m);
      c.joints[i].visible = true;
      if (l.parent === null) return;
      a.setXYZ(k++, ...m.links[l.parent].position_m);
      a.setXYZ(k++, ...m.links[i].position_m);
    });
    a.needsUpdate = true;
    c.lines.geometry.computeBoundingSphere();
    c.lines.visible = true;
    c.label.position.set(...m.links[0].position_m).add(new THREE.Vector3(0, 0, 0.1));
    c.label.visible = true;
    drawn.push({ name: m.name, valid: m.valid, links: m.links.map((l) => l.position_m),
                 parents: c.def.links.map((l) => l.parent) });
  }
  for (const [, c] of chains) {
    if (now - c.seen > FORGET_MS) {
      c.lines.visible = c.label.visible = false;
      c.joints.forEach((s) => { s.visible = false; });
    }
  }
  state.drawnChains = drawn;
}

function drawFrame(f, now) {
  for (const p of f.poses) {
    const o = objectFor(p.object_id);
    o.seen = now;
    o.mesh.position.set(...p.position_m);
    o.mesh.material.color = residualColour(p.residual_px);
    o.points.push(p.position_m);
    if (o.points.length > TRAIL_POINTS) o.points.shift();
    const a = o.trail.geometry.attributes.position;
    o.points.forEach((q, i) => a.setXYZ(i, q[0], q[1], q[2]));
    a.needsUpdate = true;
    o.trail.geometry.setDrawRange(0, o.points.length);
  }
  for (const [id, o] of objects) {
    if (now - o.seen > FORGET_MS) { scene.remove(o.mesh, o.trail); o.trail.geometry.dispose(); o.mesh.material.dispose(); objects.delete(id); }
    o.trail.visible = showTrails;
  }
  for (const b of f.bodies) {
    const g = bodyFor(b.name);
    g.seen = now;
    g.group.position.set(...b.position_m);
    g.group.quaternion.set(...b.orientation_xyzw);
    g.group.visible = true;
  }
  for (const [, b] of bodies) if (now - b.seen > FORGET_MS) b.group.visible = false;
  drawChains(f, now);
  state.drawnFrame = f;
}

// The truth (the synthetic scene's) as white rings round where each target really is.
const ringTexture = (() => {
  const c = document.createElement('canvas');
  c.width = c.height = 64;
  const g = c.getContext('2d');
  g.strokeStyle = '#ffffff'; g.lineWidth = 8;
  g.beginPath(); g.arc(32, 32, 27, 0, 2 * Math.PI); g.stroke();
  return new THREE.CanvasTexture(c);
})();

function drawTruth(t) {
  const targets = t.targets;
  while (ghosts.length < targets.length) {
    const m = new THREE.Sprite(new THREE.SpriteMaterial({ map: ringTexture, transparent: true, opacity: 0.85, depthTest: false }));
    m.scale.setScalar(markerRadius * 4);
    scene.add(m);
    ghosts.push(m);
  }
  ghosts.forEach((m, i) => {
    m.visible = showTruth && i < targets.length;
    if (i < targets.length) m.position.set(...targets[i].position_m);
  });
  state.drawnTruth = t;
}

let pendingFrame = null, pendingTruth = null;
function render() {
  const now = performance.now();
  // Objects are sized from the rig: nothing is drawn before it is known.
  if (!state.frozen && rig) {
    if (pendingFrame) { drawFrame(pendingFrame, now); pendingFrame = null; }
    if (pendingTruth) { drawTruth(pendingTruth); pendingTruth = null; }
  }
  controls.update();
  if (renderer) renderer.render(scene, camera);
  requestAnimationFrame(render);
}

// ---- monitors -------------------------------------------------------------------------------
const monitors = new Map();
function monitorFor(id) {
  let m = monitors.get(id);
  if (!m) {
    const div = document.createElement('div');
    div.className = 'monitor';
    div.innerHTML = `<div><b></b> <span class="caption"></span></div><canvas class="image"></canvas><canvas class="hist" width="256" height="48"></canvas><div class="cov"><div class="bar"></div><span></span></div>`;
    div.querySelector('b').textContent = id;
    $('monitors').append(div);
    m = { div, image: div.querySelector('.image'), hist: div.querySelector('.hist'), caption: div.querySelector('.caption'),
          cov: div.querySelector('.cov'), covBar: div.querySelector('.cov .bar'), covText: div.querySelector('.cov span') };
    monitors.set(id, m);
  }
  return m;
}

function drawPreview(buf) {
  const n = new DataView(buf).getUint32(0, true);
  const head = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, n)));
  if (single && head.camera !== single) return;
  if (state.frozen) return;
  const px = new Uint8Array(buf, 4 + n);
  const m = monitorFor(head.camera);
  const { preview_width_px: w, preview_height_px: h, scale: s } = head;
  // Drawn at twice the preview's size so the overlays' lines stay thin.
  const k = 2;
  if (m.image.width !== w * k) { m.image.width = w * k; m.image.height = h * k; }
  const img = new ImageData(w, h);
  for (let i = 0; i < w * h; i++) {
    const v = px[i];
    img.data[4 * i] = v; img.data[4 * i + 1] = v; img.data[4 * i + 2] = v; img.data[4 * i + 3] = 255;
  }
  const g = m.image.getContext('2d');
  const tmp = new OffscreenCanvas(w, h);
  tmp.getContext('2d').putImageData(img, 0, 0);
  g.imageSmoothingEnabled = false;
  g.drawImage(tmp, 0, 0, w * k, h * k);
  const f = k / s;   // frame pixels -> canvas pixels
  g.lineWidth = 1;
  for (const b of head.blobs) {
    const [wx0, wy0, wx1, wy1] = b.window_px;
    g.strokeStyle = '#ffb300'; g.setLineDash([4, 3]);
    g.strokeRect(wx0 * f, wy0 * f, (wx1 - wx0 + 1) * f, (wy1 - wy0 + 1) * f);
    g.setLineDash([]);
    if (b.status === 'lost') continue;
    const [bx0, by0, bx1, by1] = b.bbox_px;
    g.strokeStyle = b.merged ? '#ef5350' : '#66bb6a';
    g.strokeRect(bx0 * f, by0 * f, (bx1 - bx0 + 1) * f, (by1 - by0 + 1) * f);
    // The orientation cross: the major axis (Eq. 3.44) long, the minor short.
    const r = Math.max(6, Math.sqrt(b.area_px) * f);
    const a = -b.orientation_deg * Math.PI / 180;   // counter-clockwise on screen, y down
    const cx = (b.x_px + 0.5) * f, cy = (b.y_px + 0.5) * f;
    g.strokeStyle = '#ff4081';
    g.beginPath();
    g.moveTo(cx - r * Math.cos(a), cy - r * Math.sin(a)); g.lineTo(cx + r * Math.cos(a), cy + r * Math.sin(a));
    const q = r * Math.max(0.3, b.roundness);
    g.moveTo(cx + q * Math.sin(a), cy - q * Math.cos(a)); g.lineTo(cx - q * Math.sin(a), cy + q * Math.cos(a));
    g.stroke();
    g.fillStyle = '#ffb300'; g.font = '11px sans-serif';
    g.fillText(String(b.track_id), wx0 * f + 2, wy0 * f + 11);
  }
  // A live wand calibration's coverage: the cells the wand has been seen in, green.
  const cov = coverage.get(head.camera);
  state.drawnCoverage[head.camera] = null;
  if (cov && performance.now() - cov.at < COVERAGE_SHOWN_MS) {
    state.drawnCoverage[head.camera] = { cols: cov.cols, rows: cov.rows, counts: cov.counts.slice(), scale: k };
    const cw = (w * k) / cov.cols, ch = (h * k) / cov.rows;
    cov.counts.forEach((n, i) => {
      g.fillStyle = n > 0 ? 'rgba(102, 187, 106, 0.30)' : 'rgba(239, 83, 80, 0.10)';
      g.fillRect((i % cov.cols) * cw, Math.floor(i / cov.cols) * ch, cw - 1, ch - 1);
    });
  }
  // Histogram, log counts, with the threshold.
  const hg = m.hist.getContext('2d');
  hg.clearRect(0, 0, 256, 48);
  const top = Math.log1p(Math.max(...head.histogram));
  hg.fillStyle = '#8a939d';
  head.histogram.forEach((c, i) => { const y = 48 * Math.log1p(c) / top; hg.fillRect(i, 48 - y, 1, y); });
  const t = head.threshold >> head.level_shift;
  hg.fillStyle = '#ef5350'; hg.fillRect(t, 0, 1, 48);
  m.caption.textContent = `frame ${head.sequence} · ${head.width_px}×${head.height_px} ÷${s} · threshold ${head.threshold}${head.dark ? ' (dark)' : ''} · ${head.blobs.length} blobs`;
  state.previews++;
  state.lastPreview = head;
}

// ---- a live wand calibration's coverage (stereoscope calibrate wand --live) ------------------
const coverage = new Map();   // camera -> {cols, rows, counts, at}
function drawCoverage(c) {
  for (const cam of c.cameras) {
    coverage.set(cam.camera, { ...cam, at: performance.now() });
    const m = monitors.get(cam.camera);
    if (!m) continue;
    m.cov.style.display = 'block';
    m.covBar.style.width = `${Math.round(100 * cam.coverage)}%`;
    m.covBar.className = cam.coverage >= c.target ? 'bar done' : 'bar';
    m.covText.textContent = `wand coverage ${Math.round(100 * cam.coverage)} % of ${Math.round(100 * c.target)} % · ${cam.samples} samples${c.done ? ' · collected' : ''}`;
  }
  state.coverageReports++;
}

// ---- status ---------------------------------------------------------------------------------
const health = new Map();   // "host/service" -> {h, at}
function drawStatus() {
  const now = performance.now();
  const body = $('status').tBodies[0];
  body.replaceChildren();
  for (const [, { h, at }] of [...health].sort()) {
    const tr = body.insertRow();
    if (now - at > ALIVE_MS) tr.className = 'dead';
    const p99 = h.detail.latency_p99_us ?? '';
    for (const v of [h.service, h.host, h.rate_hz.toFixed(1), h.dropped, h.rejected, p99]) tr.insertCell().textContent = v;
    if (h.last_error) {
      const e = body.insertRow().insertCell();
      e.colSpan = 6; e.className = 'err'; e.textContent = h.last_error;
    }
  }
}

// ---- the socket -----------------------------------------------------------------------------
let rateCount = 0;
function connect() {
  const ws = new WebSocket(`ws://${location.host}/ws`);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => {
    state.socketOpen = true; state.connects++;
    $('link').textContent = 'live'; $('link').className = 'up';
    if (single) ws.send(JSON.stringify({ type: 'monitor', cameras: [single] }));
  };
  ws.onclose = () => {
    state.socketOpen = false;
    $('link').textContent = 'reconnecting…'; $('link').className = 'down';
    setTimeout(connect, 250);
  };
  ws.onmessage = (ev) => {
    if (ev.data instanceof ArrayBuffer) { drawPreview(ev.data); return; }
    const m = JSON.parse(ev.data);
    if (m.type === 'poses') { pendingFrame = m.frame; state.poseFrames++; state.lastPoseSequence = m.frame.sequence; rateCount++; }
    else if (m.type === 'truth') { pendingTruth = m.truth; state.truthFrames++; }
    else if (m.type === 'health') { health.set(`${m.health.host}/${m.health.service}`, { h: m.health, at: performance.now() }); state.healthReports++; }
    else if (m.type === 'hello') { if (!rig) loadRig(); }
    else if (m.type === 'coverage') drawCoverage(m.coverage);
    else if (m.type === 'error') state.errors.push(m.message);
  };
}

async function loadRig() {
  const r = await (await fetch('/api/rig')).json();
  if (rig) return;
  buildRig(r);
  for (const c of r.cameras) if (!single || c.id === single) monitorFor(c.id);
  if (single && !r.cameras.some((c) => c.id === single)) {
    const m = monitorFor(single);
    m.div.classList.add('missing');
    m.caption.textContent = 'is not a camera of this rig';
  }
}

setInterval(() => {
  $('rate').textContent = `${rateCount} pose frames/s`;
  rateCount = 0;
  const f = state.drawnFrame;
  if (f) $('counts').textContent = `${f.poses.length} markers · ${f.bodies.length} bodies · cameras ${f.cameras.join(', ')}`;
  drawStatus();
}, 1000);

$('reset').onclick = resetView;
$('top').onclick = topView;
$('trails').onclick = (e) => { showTrails = !showTrails; e.target.classList.toggle('on', showTrails); };
$('truth').onclick = (e) => { showTruth = !showTruth; e.target.classList.toggle('on', showTruth); };
resize();
connect();
requestAnimationFrame(render);
state.resetView = resetView;
state.topView = topView;
