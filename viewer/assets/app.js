// crokf viewer page: draws the displayed node set streamed by the server (server-sent events,
// positions in metres as little-endian float32, base64), shades it by displacement magnitude
// |u| = |x - X| or by the read-out standard deviation σ, draws the markers (sensors), and sends
// load-group forces (N, world frame) and play/pause/reset to POST /control. On a model with a
// contact region, a tool sphere the user drags (POST /control {"tool": [x, y, z]}, m) and the
// force of the body on it, as an arrow and in newtons.
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
  const surface = new THREE.Mesh(geometry, material);
  scene.add(surface);
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

  const tool = model.contact ? setupTool(model.contact, { scene, camera, controls, view, surface, diag }) : null;
  document.getElementById('tool').hidden = !tool;

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
    if (tool) tool.onFrame(f);
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

// The tool: a sphere of the contact region's radius (m, model frame = the drawn frame).
// "place tool" puts it just off the middle of the region and turns the view to look at it
// along the region's normal; a double click on the body puts it there. Dragging the sphere
// (or Shift + drag anywhere) moves it on the plane through its centre facing the camera; the
// wheel over the sphere (or Shift + wheel) and the W / S keys move it along the view
// direction (W pushes into the scene). Everything else goes to the orbit controls.
function setupTool(contact, { scene, camera, controls, view, surface, diag }) {
  const state = window.crokf;
  const radius = contact.radius;
  const step = radius / 20; // one wheel notch or key press, m
  const mesh = new THREE.Mesh(new THREE.SphereGeometry(radius, 32, 24),
    new THREE.MeshPhongMaterial({ color: 0xc8d2ff, emissive: 0x202840, transparent: true, opacity: 0.6 }));
  mesh.visible = false;
  scene.add(mesh);
  // Force arrow: |F| times a fixed scale (m per N, 1-2-5), capped at 4 radii.
  const cap = 4 * radius;
  const nice = (v) => { const e = Math.pow(10, Math.floor(Math.log10(v))); const m = v / e; return (m >= 5 ? 5 : m >= 2 ? 2 : 1) * e; };
  const scaleSelect = document.getElementById('tool-scale');
  const base = nice(cap / (contact.max_force / 50)); // the cap at 1/50 of the force bound
  [0.01, 0.1, 1, 10, 100].forEach((k) => {
    const o = document.createElement('option');
    o.value = String(base * k);
    o.textContent = `arrow ${Number((base * k * 1e3).toPrecision(3))} mm per N (cap ${(cap * 1e3).toPrecision(3)} mm)`;
    if (k === 1) o.selected = true;
    scaleSelect.appendChild(o);
  });
  const arrow = new THREE.ArrowHelper(new THREE.Vector3(0, 0, 1), new THREE.Vector3(), radius, 0xffd23f);
  for (const m of [arrow.line.material, arrow.cone.material]) { m.depthTest = false; m.transparent = true; }
  arrow.renderOrder = 10;
  arrow.visible = false;
  scene.add(arrow);
  const label = document.getElementById('tool-force');

  // The region's node nearest its centroid, with its outward normal: where "place tool" goes.
  const rp = contact.positions, rn = contact.normals, count = rp.length / 3;
  const mid = new THREE.Vector3();
  for (let i = 0; i < count; i++) mid.add(new THREE.Vector3(rp[3 * i], rp[3 * i + 1], rp[3 * i + 2]));
  mid.divideScalar(Math.max(count, 1));
  let best = 0, bestD = Infinity;
  for (let i = 0; i < count; i++) {
    const d = mid.distanceToSquared(new THREE.Vector3(rp[3 * i], rp[3 * i + 1], rp[3 * i + 2]));
    if (d < bestD) { bestD = d; best = i; }
  }
  const home = new THREE.Vector3(rp[3 * best], rp[3 * best + 1], rp[3 * best + 2]);
  const homeNormal = new THREE.Vector3(rn[3 * best], rn[3 * best + 1], rn[3 * best + 2]).normalize();

  // The tool as this page set it (null: none), and the sending of it: one request in flight,
  // the latest position queued behind it.
  let centre = null;
  let inflight = false, queued = false, lastLocal = -Infinity;
  function send() {
    lastLocal = performance.now();
    if (inflight) { queued = true; return; }
    inflight = true;
    queued = false;
    post({ tool: centre ? centre.toArray() : null })
      .catch((e) => state.errors.push(String(e)))
      .finally(() => { inflight = false; lastLocal = performance.now(); if (queued) send(); });
  }
  function setCentre(c) {
    centre = c ? c.clone() : null;
    mesh.visible = !!centre;
    if (centre) mesh.position.copy(centre);
    state.toolPosition = centre ? centre.toArray() : null;
    send();
  }

  document.getElementById('tool-place').addEventListener('click', () => {
    const c = home.clone().addScaledVector(homeNormal, 1.5 * radius);
    // Look at it along the normal (a little tilted, so that the orbit keeps its up vector).
    const side = new THREE.Vector3().crossVectors(homeNormal, camera.up);
    if (side.lengthSq() < 1e-6) side.set(1, 0, 0);
    const dir = homeNormal.clone().addScaledVector(side.normalize().cross(homeNormal), 0.25).normalize();
    controls.target.copy(c);
    camera.position.copy(c).addScaledVector(dir, 0.6 * diag);
    controls.update();
    setCentre(c);
  });
  document.getElementById('tool-remove').addEventListener('click', () => setCentre(null));

  const raycaster = new THREE.Raycaster();
  const ndc = new THREE.Vector2();
  function ray(e) {
    const r = view.getBoundingClientRect();
    ndc.set(((e.clientX - r.left) / r.width) * 2 - 1, -((e.clientY - r.top) / r.height) * 2 + 1);
    raycaster.setFromCamera(ndc, camera);
    return raycaster.ray;
  }
  const viewDirection = () => camera.getWorldDirection(new THREE.Vector3());
  const overTool = (e) => {
    if (!centre) return false;
    ray(e);
    return raycaster.intersectObject(mesh, false).length > 0;
  };

  // Capture phase on the canvas's parent: a tool gesture never reaches the orbit controls.
  let drag = null;
  view.addEventListener('pointerdown', (e) => {
    if (e.button !== 0 || !centre || !(e.shiftKey || overTool(e))) return;
    e.stopPropagation();
    e.preventDefault();
    const plane = new THREE.Plane().setFromNormalAndCoplanarPoint(viewDirection(), centre);
    const hit = ray(e).intersectPlane(plane, new THREE.Vector3());
    if (!hit) return;
    drag = { plane, offset: centre.clone().sub(hit), pointer: e.pointerId };
    view.setPointerCapture(e.pointerId);
  }, { capture: true });
  view.addEventListener('pointermove', (e) => {
    if (!drag || e.pointerId !== drag.pointer) return;
    const hit = ray(e).intersectPlane(drag.plane, new THREE.Vector3());
    if (hit) setCentre(hit.add(drag.offset));
  });
  const endDrag = (e) => { if (drag && e.pointerId === drag.pointer) { drag = null; view.releasePointerCapture(e.pointerId); } };
  view.addEventListener('pointerup', endDrag);
  view.addEventListener('pointercancel', endDrag);
  view.addEventListener('wheel', (e) => {
    if (!centre || !(e.shiftKey || overTool(e))) return;
    e.stopPropagation();
    e.preventDefault();
    // Shift turns a vertical wheel into deltaX on some systems.
    const delta = e.deltaY || e.deltaX;
    const notches = Math.min(Math.max(Math.abs(delta) / 100, 0.1), 3);
    setCentre(centre.clone().addScaledVector(viewDirection(), -Math.sign(delta) * notches * step));
  }, { capture: true, passive: false });
  window.addEventListener('keydown', (e) => {
    if (!centre || (e.target.closest && e.target.closest('input, select, textarea'))) return;
    const k = e.key.toLowerCase();
    if (k !== 'w' && k !== 's') return;
    setCentre(centre.clone().addScaledVector(viewDirection(), (k === 'w' ? 1 : -1) * (e.shiftKey ? 5 : 1) * step));
  });
  view.addEventListener('dblclick', (e) => {
    ray(e);
    const hit = raycaster.intersectObject(surface, false)[0];
    if (!hit || !hit.face) return;
    const n = hit.face.normal.clone();
    if (n.dot(camera.position.clone().sub(hit.point)) < 0) n.negate();
    setCentre(hit.point.clone().addScaledVector(n, 1.25 * radius));
  });

  // Where the sphere's centre is on the page (client pixels), for the browser test's drag.
  state.toolScreen = () => {
    if (!centre) return null;
    const v = centre.clone().project(camera);
    const r = view.getBoundingClientRect();
    return [r.left + ((v.x + 1) / 2) * r.width, r.top + ((1 - v.y) / 2) * r.height];
  };

  const dir = new THREE.Vector3();
  return {
    onFrame(f) {
      const t = f.tool;
      // Follow the server's tool (another page, a reload) unless this page just set it.
      if (!drag && !inflight && performance.now() - lastLocal > 500) {
        const server = t ? new THREE.Vector3(...t.position) : null;
        if (!!server !== !!centre || (server && !server.equals(centre))) {
          centre = server;
          mesh.visible = !!centre;
          if (centre) mesh.position.copy(centre);
          state.toolPosition = centre ? centre.toArray() : null;
        }
      }
      state.toolForce = t ? t.force_magnitude : null;
      state.toolServerPosition = t ? t.position : null;
      state.toolStatus = t ? t.status : null;
      if (!t) {
        arrow.visible = false;
        label.textContent = 'no tool';
        return;
      }
      const F = t.force_magnitude;
      const scale = Number(scaleSelect.value);
      arrow.visible = F > 0;
      if (F > 0) {
        dir.set(...t.force).divideScalar(F);
        arrow.position.set(...t.position);
        arrow.setDirection(dir);
        const length = Math.min(F * scale, cap);
        arrow.setLength(length, Math.min(0.3 * length, 0.6 * radius), Math.min(0.2 * length, 0.4 * radius));
      }
      label.textContent =
        `|F| ${F === 0 ? '0' : F.toPrecision(4)} N   (${t.force.map((v) => v.toFixed(5)).join(', ')}) N\n` +
        `${t.status}, ${t.active} pressing node${t.active === 1 ? '' : 's'}, depth ${(t.depth * 1e3).toFixed(3)} mm` +
        (F * scale > cap ? '\narrow capped' : '');
    },
  };
}

main().catch((e) => {
  state.errors.push(String(e && e.stack ? e.stack : e));
  document.getElementById('error').textContent = String(e);
});
