// The crossline live view: follows the daemon's WebSocket (`/ws`, protocol version 1,
// documented in src/serve/web/protocol.rs) and draws the cloud (three.js), the status
// and the coverage map. It only reads; it sends the daemon nothing.

import * as THREE from 'three';
import { OrbitControls } from '/vendor/three/OrbitControls.js';

const PROTOCOL_VERSION = 1;
const HEADER_BYTES = 8;
const RECORD_BYTES = 20;
const NO_PIXEL = 0xffff;
const BACKGROUND = 0x101418;
// Coverage cells across the map: coarse enough that one sweep shows as a band.
const COVERAGE_CELLS_ACROSS = 240;
const COVERAGE_EMPTY = [24, 32, 40];

// What the page holds, readable from the console (and by the browser test).
const view = {
  version: PROTOCOL_VERSION, connected: false, epoch: 0, count: 0, ended: false,
  coveredCells: 0, cells: 0, status: null, webgl: false,
};
window.crosslineView = view;

const $ = (id) => document.getElementById(id);

// ---- the cloud, in growable arrays (camera frame, OpenCV axes)
let capacity = 0;
let xyz = new Float32Array(0);
let rgb = new Uint8Array(0);
let shown = new Uint8Array(0); // the colours drawn: rgb or the depth map
let sum = [0, 0, 0];
let zMin = Infinity;
let zMax = -Infinity;
let colourMode = 'rgb';

// ---- 3D
const canvas = $('cloud');
// The colours are the camera's sRGB bytes and the page's CSS colours: draw them as
// they are, with no conversion to linear light and back.
THREE.ColorManagement.enabled = false;
let renderer = null;
try {
  renderer = new THREE.WebGLRenderer({ canvas, antialias: false, preserveDrawingBuffer: true });
  renderer.outputColorSpace = THREE.LinearSRGBColorSpace;
  renderer.setClearColor(BACKGROUND);
  view.webgl = true;
} catch (e) {
  $('nogl').hidden = false;
  console.warn('no WebGL:', e);
}
const scene = new THREE.Scene();
const camera = new THREE.PerspectiveCamera(50, 1, 0.001, 1e4);
// OpenCV (x right, y down, z forward) to three.js (y up, looking down -z).
const cloudGroup = new THREE.Group();
cloudGroup.scale.set(1, -1, -1);
scene.add(cloudGroup);
const geometry = new THREE.BufferGeometry();
const material = new THREE.PointsMaterial({ size: 2, sizeAttenuation: false, vertexColors: true });
const points = new THREE.Points(geometry, material);
points.frustumCulled = false;
cloudGroup.add(points);
const controls = renderer ? new OrbitControls(camera, canvas) : null;
let userMoved = false;
let dirty = true;
let geometryDirty = false;
let coverageDirty = false;
if (controls) {
  controls.addEventListener('start', () => { userMoved = true; });
  controls.addEventListener('change', () => { dirty = true; });
}

function grow(need) {
  if (need <= capacity) return;
  let cap = Math.max(capacity, 1 << 16);
  while (cap < need) cap *= 2;
  const x = new Float32Array(cap * 3); x.set(xyz); xyz = x;
  const c = new Uint8Array(cap * 3); c.set(rgb); rgb = c;
  const s = new Uint8Array(cap * 3); s.set(shown); shown = s;
  capacity = cap;
  geometry.setAttribute('position', new THREE.BufferAttribute(xyz, 3));
  geometry.setAttribute('color', new THREE.BufferAttribute(shown, 3, true));
}

// Depth as hue: near red, through yellow and green, far blue (0..1 to bytes).
function depthColour(t, out, at) {
  const h = 4 * Math.min(1, Math.max(0, t)); // sextants 0..4 of the hue circle
  const x = 1 - Math.abs((h % 2) - 1);
  const [r, g, b] = h < 1 ? [1, x, 0] : h < 2 ? [x, 1, 0] : h < 3 ? [0, 1, x] : [0, x, 1];
  out[at] = 255 * r; out[at + 1] = 255 * g; out[at + 2] = 255 * b;
}

function paint(from, to) {
  if (colourMode === 'rgb') {
    shown.set(rgb.subarray(from * 3, to * 3), from * 3);
    return;
  }
  const span = zMax > zMin ? zMax - zMin : 1;
  for (let i = from; i < to; i++) depthColour((xyz[3 * i + 2] - zMin) / span, shown, 3 * i);
}

// ---- coverage map: cells of the camera's image that have points
const coverage = $('coverage');
const coverageCtx = coverage.getContext('2d');
let cell = 1;
let gridW = 1;
let gridH = 1;
let counts = new Uint32Array(1);
let coverageImage = coverageCtx.createImageData(1, 1);

function initCoverage(width, height) {
  cell = Math.max(1, Math.ceil(width / COVERAGE_CELLS_ACROSS));
  gridW = Math.ceil(width / cell);
  gridH = Math.ceil(height / cell);
  coverage.width = gridW;
  coverage.height = gridH;
  counts = new Uint32Array(gridW * gridH);
  coverageImage = coverageCtx.createImageData(gridW, gridH);
  clearCoverage();
}

function clearCoverage() {
  counts.fill(0);
  const d = coverageImage.data;
  for (let i = 0; i < d.length; i += 4) {
    d[i] = COVERAGE_EMPTY[0]; d[i + 1] = COVERAGE_EMPTY[1]; d[i + 2] = COVERAGE_EMPTY[2]; d[i + 3] = 255;
  }
  view.coveredCells = 0;
  view.cells = gridW * gridH;
  coverageDirty = true;
}

function mark(u, v) {
  const i = Math.floor(v / cell) * gridW + Math.floor(u / cell);
  if (i < 0 || i >= counts.length) return;
  const n = ++counts[i];
  if (n === 1) view.coveredCells++;
  // Brighter with more points: one sweep is visible, a dense patch stands out.
  const level = Math.min(1, 0.35 + 0.13 * Math.log2(n));
  const d = coverageImage.data;
  d[4 * i] = 40 * level; d[4 * i + 1] = 230 * level; d[4 * i + 2] = 120 * level;
}

// ---- messages
function clearCloud() {
  view.count = 0;
  sum = [0, 0, 0];
  zMin = Infinity;
  zMax = -Infinity;
  geometry.setDrawRange(0, 0);
  clearCoverage();
  geometryDirty = true;
}

function onPoints(buffer) {
  const d = new DataView(buffer);
  if (buffer.byteLength < HEADER_BYTES) return;
  const epoch = d.getUint32(0, true);
  const n = d.getUint32(4, true);
  if (epoch !== view.epoch || buffer.byteLength !== HEADER_BYTES + n * RECORD_BYTES) return;
  const first = view.count;
  grow(first + n);
  let oldMin = zMin, oldMax = zMax;
  for (let k = 0; k < n; k++) {
    const at = HEADER_BYTES + k * RECORD_BYTES;
    const i = first + k;
    const x = d.getFloat32(at, true), y = d.getFloat32(at + 4, true), z = d.getFloat32(at + 8, true);
    xyz[3 * i] = x; xyz[3 * i + 1] = y; xyz[3 * i + 2] = z;
    rgb[3 * i] = d.getUint8(at + 12); rgb[3 * i + 1] = d.getUint8(at + 13); rgb[3 * i + 2] = d.getUint8(at + 14);
    sum[0] += x; sum[1] += y; sum[2] += z;
    if (z < zMin) zMin = z;
    if (z > zMax) zMax = z;
    const u = d.getUint16(at + 16, true), v = d.getUint16(at + 18, true);
    if (u !== NO_PIXEL) mark(u, v);
  }
  view.count = first + n;
  // A wider depth range recolours everything in depth mode; otherwise only the new points.
  if (colourMode === 'depth' && (zMin !== oldMin || zMax !== oldMax)) paint(0, view.count);
  else paint(first, view.count);
  geometryDirty = true;
  coverageDirty = true;
}

function onText(m) {
  switch (m.type) {
    case 'hello':
      if (m.version !== PROTOCOL_VERSION) {
        $('conn').textContent = `the daemon speaks live view protocol ${m.version}, this page ${PROTOCOL_VERSION}`;
        return;
      }
      $('scan').textContent = `scan ${m.scan} · ${m.daemon} · ${m.width}×${m.height}`;
      // The 3D view starts with the camera's own field of view.
      camera.fov = 2 * Math.atan(m.height / 2 / m.fy) * 180 / Math.PI;
      camera.updateProjectionMatrix();
      initCoverage(m.width, m.height);
      view.epoch = 0;
      view.ended = false;
      clearCloud();
      break;
    case 'epoch':
      view.epoch = m.epoch;
      view.ended = false;
      clearCloud();
      break;
    case 'end':
      view.ended = true;
      $('event').textContent = `scan finished: ${m.total} points in the final cloud (epoch ${m.epoch})`;
      break;
    case 'bye':
      $('event').textContent = `the daemon dropped this page: ${m.reason}`;
      break;
    case 'status':
      showStatus(m);
      break;
    case 'event':
      $('event').textContent = `${m.event}: ${m.detail}`;
      break;
  }
}

function showStatus(s) {
  view.status = s;
  const set = (id, v) => { $(`st-${id}`).textContent = v; };
  set('device', s.device);
  set('frames_in', s.frames_in);
  set('dropped', s.frames_dropped + s.frames_dropped_driver);
  set('frames_processed', s.frames_processed);
  set('planes', `${s.planes_solved} / ${s.planes}`);
  set('epoch', s.epoch);
  set('points', s.points);
  set('stream_clients', s.stream_clients);
}

function connect() {
  const proto = location.protocol === 'https:' ? 'wss' : 'ws';
  const ws = new WebSocket(`${proto}://${location.host}/ws`);
  ws.binaryType = 'arraybuffer';
  ws.onopen = () => {
    view.connected = true;
    $('conn').textContent = 'live';
    $('conn').className = 'live';
  };
  ws.onmessage = (ev) => {
    if (typeof ev.data === 'string') onText(JSON.parse(ev.data));
    else onPoints(ev.data);
  };
  ws.onclose = () => {
    view.connected = false;
    $('conn').className = '';
    // What was received stays on screen; a restarted daemon is picked up again.
    $('conn').textContent = view.ended ? 'scan finished; daemon gone (retrying)' : 'disconnected (retrying)';
    setTimeout(connect, 2000);
  };
}

// ---- drawing
for (const r of document.querySelectorAll('input[name=colour]')) {
  r.addEventListener('change', () => {
    colourMode = r.value;
    paint(0, view.count);
    geometryDirty = true;
  });
}

function fit() {
  // Until the user moves the view, look from the camera at the cloud's centre.
  if (userMoved || view.count === 0 || !controls) return;
  const c = new THREE.Vector3(sum[0], sum[1], sum[2]).divideScalar(view.count);
  cloudGroup.localToWorld(c);
  controls.target.copy(c);
  camera.position.copy(c).multiplyScalar(-0.1);
  controls.update();
}

function resize() {
  if (!renderer) return;
  const w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== w || canvas.height !== h) {
    renderer.setSize(w, h, false);
    camera.aspect = w / Math.max(1, h);
    camera.updateProjectionMatrix();
    dirty = true;
  }
}

function frame() {
  resize();
  if (geometryDirty) {
    geometryDirty = false;
    geometry.setDrawRange(0, view.count);
    const p = geometry.getAttribute('position');
    const c = geometry.getAttribute('color');
    if (p) p.needsUpdate = true;
    if (c) c.needsUpdate = true;
    const range = colourMode === 'depth' && view.count > 0 ? `${zMin.toFixed(2)} (red) – ${zMax.toFixed(2)} (blue)` : '';
    $('depth-range').textContent = range;
    fit();
    dirty = true;
  }
  if (coverageDirty) {
    coverageDirty = false;
    coverageCtx.putImageData(coverageImage, 0, 0);
    $('coverage-text').textContent = view.cells > 0 && view.count > 0
      ? `${(100 * view.coveredCells / view.cells).toFixed(1)} % of the view has points (cells of ${cell}×${cell} px); dark: sweep there`
      : 'no points yet';
  }
  if (dirty && renderer) {
    dirty = false;
    renderer.render(scene, camera);
  }
  requestAnimationFrame(frame);
}

connect();
requestAnimationFrame(frame);
