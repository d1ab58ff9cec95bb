// crokf viewer page: draws the displayed node set streamed by the server (server-sent events,
// positions in metres as little-endian float32, base64), shades it by displacement magnitude
// |u| = |x - X| or by the read-out standard deviation σ, draws the markers (sensors), and sends
// load-group forces (N, world frame) and play/pause/reset to POST /control.
import * as THREE from 'three';
import { OrbitControls } from 'three/addons/OrbitControls.js';

const state = window.crokf;

function decodeFloat32(b64) {
  const bin = atob(b64);
  const bytes = new Uint8Array(bin.length);
  for (let i = 0; i < bin.length; i++) bytes[i] = bin.charCodeAt(i);
  return new Float32Array(bytes.buffer);
}

// Turbo-like colour ramp, t in [0, 1].
const STOPS = [[0x30, 0x12, 0x3b], [0x46, 0x86, 0xfb], [0x1a, 0xe4, 0xb6], [0xa2, 0xfc, 0x3c],
  [0xfa, 0xbb, 0x39], [0xe4, 0x46, 0x0a], [0x7a, 0x04, 0x03]];
function ramp(t, out, o) {
  const x = Math.min(Math.max(t, 0), 1) * (STOPS.length - 1);
  const i = Math.min(Math.floor(x), STOPS.length - 2);
  const f = x - i;
  for (let c = 0; c < 3; c++) out[o + c] = (STOPS[i][c] * (1 - f) + STOPS[i + 1][c] * f) / 255;
}

async function post(body) {
  const r = await fetch('/control', { method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body) });
  if (!r.ok) throw new Error('control: ' + (await r.text()));
}

async function main() {
  const model = await (await fetch('/model.json')).json();
  const rest = new Float32Array(model.rest_positions);
  const n = rest.length / 3;

  // Bounding box of the rest geometry, for the camera and marker size.
  const box = new THREE.Box3();
  for (let i = 0; i < n; i++) box.expandByPoint(new THREE.Vector3(rest[3 * i], rest[3 * i + 1], rest[3 * i + 2]));
  const centre = box.getCenter(new THREE.Vector3());
  const diag = box.getSize(new THREE.Vector3()).length();

  const renderer = new THREE.WebGLRenderer({ antialias: true });
  renderer.setPixelRatio(window.devicePixelRatio);
  const view = document.getElementById('view');
  view.appendChild(renderer.domElement);
  const scene = new THREE.Scene();
  scene.background = new THREE.Color(0x1d2026);
  const camera = new THREE.PerspectiveCamera(35, 1, diag * 1e-3, diag * 100);
  camera.up.set(0, 0, 1);
  camera.position.copy(centre).add(new THREE.Vector3(1.15 * diag, -0.25 * diag, 0.95 * diag));
  const controls = new OrbitControls(camera, renderer.domElement);
  controls.target.copy(centre);
  controls.update();
  scene.add(new THREE.HemisphereLight(0xffffff, 0x404050, 1.6));
  const sun = new THREE.DirectionalLight(0xffffff, 1.8);
  sun.position.set(1, -1, 2);
  scene.add(sun);

  const geometry = new THREE.BufferGeometry();
  const positions = new Float32Array(rest);
  const colours = new Float32Array(3 * n);
  geometry.setAttribute('position', new THREE.BufferAttribute(positions, 3));
  geometry.setAttribute('color', new THREE.BufferAttribute(colours, 3));
  geometry.setIndex(new THREE.BufferAttribute(new Uint32Array(model.triangles), 1));
  geometry.computeVertexNormals();
  const material = new THREE.MeshPhongMaterial({ vertexColors: true, side: THREE.DoubleSide, shininess: 20 });
  scene.add(new THREE.Mesh(geometry, material));
  // Mesh lines share the surface's position attribute, so they follow the deformation.
  scene.add(new THREE.Mesh(geometry, new THREE.MeshBasicMaterial({ color: 0x000000, wireframe: true, transparent: true, opacity: 0.1 })));

  const markers = model.sensors.map((s) => {
    const m = new THREE.Mesh(new THREE.SphereGeometry(0.018 * diag, 16, 12), new THREE.MeshPhongMaterial({ color: 0xffffff, emissive: 0x333333 }));
    m.position.set(...s.position);
    scene.add(m);
    return m;
  });

  // One slider per world force component of each load group.
  const forces = model.loads.map(() => [0, 0, 0]);
  const loadsDiv = document.getElementById('loads');
  model.loads.forEach((load, g) => {
    const fs = document.createElement('fieldset');
    fs.innerHTML = `<legend>load '${load.name}', N (world)</legend>`;
    load.components.forEach((c) => {
      const label = document.createElement('label');
      const slider = document.createElement('input');
      Object.assign(slider, { type: 'range', min: -model.force_range, max: model.force_range, step: model.force_range / 200, value: 0 });
      slider.dataset.load = load.name;
      slider.dataset.component = 'xyz'[c];
      slider.id = `force-${load.name}-${'xyz'[c]}`;
      const value = document.createElement('span');
      value.textContent = '0.000';
      slider.addEventListener('input', () => {
        forces[g][c] = Number(slider.value);
        value.textContent = forces[g][c].toFixed(3);
        post({ forces: { [load.name]: forces[g] } }).catch((e) => state.errors.push(String(e)));
      });
      label.append('xyz'[c], slider, value);
      fs.appendChild(label);
    });
    loadsDiv.appendChild(fs);
  });

  let playing = true;
  const playButton = document.getElementById('play');
  playButton.addEventListener('click', () => {
    playing = !playing;
    post({ playing }).catch((e) => state.errors.push(String(e)));
  });
  document.getElementById('reset').addEventListener('click', () => post({ reset: true }).catch((e) => state.errors.push(String(e))));
  const shade = document.getElementById('shade');

  let latest = null;
  let dirty = false;
  let colourScale = 0;
  const events = new EventSource('/events');
  events.onmessage = (e) => {
    latest = JSON.parse(e.data);
    state.framesReceived++;
    dirty = true;
  };
  events.onerror = () => { document.getElementById('stats').textContent = 'connection lost; retrying…'; };

  function applyFrame(f) {
    const p = decodeFloat32(f.positions);
    const sigma = decodeFloat32(f.std);
    positions.set(p);
    const bySigma = shade.value === 'sigma';
    let max = 0;
    let sum = 0;
    const value = new Float32Array(n);
    for (let i = 0; i < n; i++) {
      const dx = p[3 * i] - rest[3 * i], dy = p[3 * i + 1] - rest[3 * i + 1], dz = p[3 * i + 2] - rest[3 * i + 2];
      const u = Math.sqrt(dx * dx + dy * dy + dz * dz);
      sum += u;
      value[i] = bySigma ? sigma[i] : u;
      if (value[i] > max) max = value[i];
    }
    // Colour scale: the largest value seen, decaying slowly so that it follows the load.
    colourScale = Math.max(max, colourScale * 0.995, 1e-12);
    for (let i = 0; i < n; i++) ramp(value[i] / colourScale, colours, 3 * i);
    geometry.attributes.position.needsUpdate = true;
    geometry.attributes.color.needsUpdate = true;
    geometry.computeVertexNormals();
    f.markers.forEach((_, k) => { if (k % 3 === 0 && markers[k / 3]) markers[k / 3].position.set(f.markers[k], f.markers[k + 1], f.markers[k + 2]); });
    document.getElementById('legend-title').textContent = bySigma ? 'σ (read-out std), mm' : '|u|, mm';
    document.getElementById('hi').textContent = (colourScale * 1e3).toPrecision(3);
    state.displacementSum = sum;
    state.maxDisplacement = max;
    state.step = f.step;
    playing = f.stats.playing;
    playButton.textContent = playing ? 'pause' : 'play';
    document.getElementById('error').textContent = f.error || '';
  }

  let fpsWindowStart = performance.now();
  let fpsFrames = 0;
  let receivedAtWindowStart = 0;
  function resize() {
    const w = view.clientWidth, h = view.clientHeight;
    renderer.setSize(w, h, false);
    camera.aspect = w / h;
    camera.updateProjectionMatrix();
  }
  window.addEventListener('resize', resize);
  resize();

  function draw(now) {
    if (dirty && latest) {
      applyFrame(latest);
      dirty = false;
    }
    controls.update();
    renderer.render(scene, camera);
    state.framesDrawn++;
    fpsFrames++;
    if (now - fpsWindowStart >= 1000) {
      state.drawnFps = (1000 * fpsFrames) / (now - fpsWindowStart);
      state.receivedFps = (1000 * (state.framesReceived - receivedAtWindowStart)) / (now - fpsWindowStart);
      fpsWindowStart = now;
      fpsFrames = 0;
      receivedAtWindowStart = state.framesReceived;
    }
    if (latest) {
      const s = latest.stats;
      document.getElementById('stats').textContent =
        `t ${latest.time.toFixed(3)} s   step ${latest.step}\n` +
        `stepping ${s.step_rate_hz.toFixed(0)} Hz (Δt ${(model.dt * 1e3).toFixed(2)} ms, r = ${model.order})\n` +
        `step time ${s.step_time_median_us.toFixed(2)} µs (median)\n` +
        `read-out ${s.readout_time_median_us.toFixed(0)} µs / frame\n` +
        `frames ${s.frame_rate_hz.toFixed(0)} Hz sent, ${(state.receivedFps || 0).toFixed(0)} Hz received, ${(state.drawnFps || 0).toFixed(0)} fps drawn\n` +
        `dropped steps ${s.dropped_steps}`;
    }
    requestAnimationFrame(draw);
  }
  requestAnimationFrame(draw);
  state.ready = true;
}

main().catch((e) => {
  state.errors.push(String(e && e.stack ? e.stack : e));
  document.getElementById('error').textContent = String(e);
});
