// ProcTex studio: pick a family, move its parameters, edit part textures, see the textured shape,
// and say which part is which (hover a part: its group and word; click it: give it a clause of the
// prompt). Talks to the API of workers/http/ on the same origin. Test hooks:
// document.body.dataset.state ("loading" | "idle" | "error"), .busy ("1" while a request is
// pending), .requests (completed transfers), .hover / .selected (group under the pointer / clicked),
// .words ("saved" after the part words were stored) and window.studio.
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { OrbitControls } from 'three/addons/controls/OrbitControls.js';
import { RoomEnvironment } from 'three/addons/environments/RoomEnvironment.js';

const DEBOUNCE_MS = 120;
const $ = (id) => document.getElementById(id);
const body = document.body;

const studio = {
  family: null, // the family's description (GET /v1/families/{name}?look=...)
  look: null, // the look on screen (null: the family's build look)
  params: {}, // current parameter values
  edits: {}, // {group index: {hue, prompt, roughness, metallic}} not yet saved to the family
  mesh: null, // an uploaded File (families of meshes)
  parts: null, // which group took which word of the look's prompt (GET .../parts)
  words: {}, // {group index: word} chosen here, not yet saved ('' clears a stored word)
  photos: {}, // {group index: File} photos for the next look (sent as multipart with "add look")
  seq: 0, // sequence number of the latest transfer request
  controller: null,
  timer: null,
  pending: false, // values changed while a transfer was in flight: the latest go when it lands
  requests: 0,
  lastGlbBytes: null, // Uint8Array of the shape on screen (its textures linked: fetched once, then cached)
  lastDownloadBytes: null, // Uint8Array of the last download (self-contained: textures embedded)
  downloadReady: false,
  lastParams: null,
  lastEdits: null,
  lastLatencyMs: null,
  lastServerSeconds: null,
  glbUrl: null,
};
window.studio = studio;

// ------------------------------------------------------------------------------------ 3D view
const canvas = $('canvas');
const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
renderer.outputColorSpace = THREE.SRGBColorSpace;
renderer.toneMapping = THREE.ACESFilmicToneMapping;
const scene = new THREE.Scene();
scene.background = new THREE.Color(0x16191e);
// PBR materials (roughness, metalness, normal maps) need something to reflect: an environment light
// (three's room, pre-filtered once), a soft fill and a key light for shape.
const pmrem = new THREE.PMREMGenerator(renderer);
scene.environment = pmrem.fromScene(new RoomEnvironment(), 0.04).texture;
studio.scene = scene; // test hook
scene.add(new THREE.HemisphereLight(0xffffff, 0x444455, 0.6));
const sun = new THREE.DirectionalLight(0xffffff, 1.4);
sun.position.set(2, 3, 2.5);
scene.add(sun);
const camera = new THREE.PerspectiveCamera(40, 1, 0.001, 1000);
camera.position.set(1, 0.8, 1.4);
const controls = new OrbitControls(camera, canvas);
controls.addEventListener('change', render);
const loader = new GLTFLoader();
let model = null;
let framed = false;

function render() {
  renderer.render(scene, camera);
}

function resize() {
  const { clientWidth: w, clientHeight: h } = canvas.parentElement;
  if (!w || !h) return;
  renderer.setSize(w, h, false);
  camera.aspect = w / h;
  camera.updateProjectionMatrix();
  render();
}
new ResizeObserver(resize).observe(canvas.parentElement);

function dispose(object) {
  object.traverse((o) => {
    if (o.geometry) o.geometry.dispose();
    for (const m of [].concat(o.material || [])) {
      if (m.map) m.map.dispose();
      m.dispose();
    }
  });
}

// Look at the whole object from the front-right-above, whatever the canvas' aspect.
function frame(object) {
  object.updateMatrixWorld(true);
  const sphere = new THREE.Box3().setFromObject(object).getBoundingSphere(new THREE.Sphere());
  const radius = sphere.radius || 1;
  const vfov = THREE.MathUtils.degToRad(camera.fov);
  const hfov = 2 * Math.atan(Math.tan(vfov / 2) * camera.aspect);
  const distance = (radius / Math.sin(Math.min(vfov, hfov) / 2)) * 1.05;
  controls.target.copy(sphere.center);
  camera.position.copy(sphere.center).add(new THREE.Vector3(0.55, 0.4, 0.75).normalize().multiplyScalar(distance));
  camera.near = distance / 100;
  camera.far = distance * 100;
  camera.updateProjectionMatrix();
  controls.update();
}

// ------------------------------------------------------------------------ picking parts
// Each material of the service's GLBs carries its part group (extras.group -> userData.group).
const raycaster = new THREE.Raycaster();
function groupAt(event) {
  if (!model) return null;
  const rect = canvas.getBoundingClientRect();
  const ndc = new THREE.Vector2(((event.clientX - rect.left) / rect.width) * 2 - 1, -((event.clientY - rect.top) / rect.height) * 2 + 1);
  raycaster.setFromCamera(ndc, camera);
  const hit = raycaster.intersectObject(model, true)[0];
  const g = hit && hit.object.material ? hit.object.material.userData.group : undefined;
  return Number.isInteger(g) ? g : null;
}

function partRow(g) {
  return studio.parts ? studio.parts.groups.find((r) => r.group === g) : null;
}

function describePart(g) {
  const fam = studio.family;
  if (!fam || g >= fam.groups.length) return `a new part (group ${g}): painted from the prompt on its own`;
  const row = partRow(g);
  const name = fam.groups[g].label || `group ${g}`;
  if (!row) return name;
  const score = typeof row.score === 'number' ? ` ${row.score.toFixed(2)}` : '';
  const word = row.word ? `${row.word} (${row.how}${score})` : 'no word: the rest of the prompt';
  return `group ${g}${fam.groups[g].label ? ` “${name}”` : ''}: ${word} — “${row.text}”`;
}

function showHover(event) {
  const g = groupAt(event);
  const tip = $('hover');
  body.dataset.hover = g === null ? '' : String(g);
  if (g === null) {
    tip.hidden = true;
    return;
  }
  tip.textContent = describePart(g);
  const rect = canvas.getBoundingClientRect();
  tip.style.left = `${event.clientX - rect.left + 14}px`;
  tip.style.top = `${event.clientY - rect.top + 14}px`;
  tip.hidden = false;
}

function selectGroup(g) {
  body.dataset.selected = g === null ? '' : String(g);
  for (const box of document.querySelectorAll('.group')) box.classList.toggle('selected', box.dataset.group === String(g));
  const box = document.querySelector(`.group[data-group="${g}"]`);
  if (box) {
    box.scrollIntoView({ block: 'nearest' });
    const select = box.querySelector('select.assign');
    if (select && !select.disabled) select.focus();
  }
}

// A photo per part for the next look (POST .../looks as multipart: image.<group> files): chosen in a
// part's panel or dropped on the part in the view; "add look" sends them with its name (its prompt
// is then optional: the build's covers the parts without a photo).
function setPhoto(g, file) {
  if (file) studio.photos[g] = file;
  else delete studio.photos[g];
  const box = document.querySelector(`.group[data-group="${g}"]`);
  if (box) box.querySelector('.photo-note').textContent = file ? `${file.name}: sent with the next look` : '';
  const n = Object.keys(studio.photos).length;
  $('look-prompt').required = n === 0;
  $('look-prompt').placeholder = n ? `prompt (optional: ${n} photo${n > 1 ? 's' : ''})` : 'prompt, e.g. white oak';
  body.dataset.photos = String(n);
}

canvas.addEventListener('dragover', (ev) => { if (studio.family && studio.family.edits_enabled) ev.preventDefault(); });
canvas.addEventListener('drop', (ev) => {
  ev.preventDefault();
  const g = groupAt(ev);
  if (g !== null && ev.dataTransfer.files.length && studio.family.edits_enabled) {
    setPhoto(g, ev.dataTransfer.files[0]);
    selectGroup(g);
  }
});

let pressed = null;
canvas.addEventListener('pointermove', showHover);
canvas.addEventListener('pointerleave', () => { $('hover').hidden = true; body.dataset.hover = ''; });
canvas.addEventListener('pointerdown', (ev) => { pressed = [ev.clientX, ev.clientY]; });
canvas.addEventListener('pointerup', (ev) => {
  // a click, not an orbit drag: the part under it is selected (its word can be given in its panel)
  if (pressed && Math.hypot(ev.clientX - pressed[0], ev.clientY - pressed[1]) < 5) selectGroup(groupAt(ev));
  pressed = null;
});

function clearModel() {
  if (model) {
    scene.remove(model);
    dispose(model);
    model = null;
  }
  framed = false;
  render();
}

// Parse a GLB and put it on screen unless `current()` says it is stale by then. `base` is the
// transfer route's folder: the GLB's linked textures (textures/<g>.png?v=<digest>) resolve there,
// and the browser keeps them (immutable for that digest), so a slider move fetches geometry only.
function showGlb(buffer, current, base) {
  return new Promise((resolve, reject) => {
    loader.parse(buffer, base, (gltf) => {
      const next = gltf.scene;
      if (!current()) {
        dispose(next);
        resolve();
        return;
      }
      // The service's GLBs are already +Y up (a z-up family gets a node rotation in the file).
      if (model) {
        scene.remove(model);
        dispose(model);
      }
      model = next;
      scene.add(model);
      if (!framed) {
        frame(model);
        framed = true;
      }
      render();
      resolve();
    }, reject);
  });
}

// ------------------------------------------------------------------------------------ requests
function editToken() {
  return new URLSearchParams(window.location.hash.slice(1)).get('token') || '';
}

async function api(path, options = {}) {
  const response = await fetch(path, options);
  if (!response.ok) {
    let message = `${response.status} ${response.statusText}`;
    try {
      message = (await response.json()).error || message;
    } catch (_) { /* not JSON */ }
    throw new Error(message);
  }
  return response;
}

function setBusy(on) {
  body.dataset.busy = on ? '1' : '0';
  $('busy').hidden = !on;
}

function showError(message) {
  if (message) body.dataset.state = 'error';
  $('error').textContent = message;
  $('error').hidden = !message;
}

function editsBody() {
  const out = {};
  for (const [g, e] of Object.entries(studio.edits)) {
    const edit = {};
    if (e.hue) edit.hue = e.hue;
    if (e.prompt) edit.prompt = e.prompt;
    if (e.roughness !== undefined) edit.roughness = e.roughness;
    if (e.metallic !== undefined) edit.metallic = e.metallic;
    if (Object.keys(edit).length) out[g] = edit;
  }
  return out;
}

// Changes are batched: the first change of a burst starts a ~120 ms timer and the request takes the
// values of the moment it fires, so a dragged slider sends a request every ~120 ms and the view
// follows. The latest request wins: it aborts the one in flight, and a response whose sequence
// number is not the latest is dropped.
function scheduleTransfer(delay = DEBOUNCE_MS) {
  body.dataset.state = 'loading';
  setBusy(true);
  if (studio.timer !== null && delay > 0) return; // the pending request will take the new values
  if (studio.controller !== null && delay > 0) {
    // One in flight: let it land (a slow machine's view still follows a drag), then send the
    // latest values; cancelling it would show nothing until the hand stops.
    studio.pending = true;
    return;
  }
  clearTimeout(studio.timer);
  studio.timer = setTimeout(() => {
    studio.timer = null;
    transfer();
  }, delay);
}

function cancelInFlight() {
  studio.seq += 1;
  if (studio.controller) studio.controller.abort();
  studio.controller = null;
}

function settled(seq) {
  // The latest request is done and no other is scheduled.
  return seq === studio.seq && studio.timer === null && !studio.pending;
}

function familyPath(fam) {
  return `/v1/families/${encodeURIComponent(fam.name)}/`;
}

function lookQuery(prefix = '&') {
  // The look on screen, as the routes take it (?look=NAME); nothing for the build's look.
  return studio.look ? `${prefix}look=${encodeURIComponent(studio.look)}` : '';
}

function transferRequest(fam, params, edits, signal, textures = 'linked') {
  // A multiplexed service routes by the family in the path (workers/ingress.py): no header needed.
  const options = { method: 'POST', signal, headers: {} };
  if (fam.inputs.includes('params')) {
    options.headers['content-type'] = 'application/json';
    options.body = JSON.stringify({ params, seed: 0, edits });
  } else {
    options.body = new FormData();
    options.body.append('mesh', studio.mesh, studio.mesh.name);
    options.body.append('edits', JSON.stringify(edits));
  }
  return api(`${familyPath(fam)}transfer?textures=${textures}${lookQuery()}`, options);
}

async function transfer() {
  const fam = studio.family;
  cancelInFlight();
  studio.pending = false; // this one takes the latest values
  const seq = studio.seq;
  if (!fam || (!fam.inputs.includes('params') && !studio.mesh)) {
    // nothing to show yet (a family of meshes before an upload)
    setBusy(false);
    body.dataset.state = 'idle';
    return;
  }
  const controller = new AbortController();
  studio.controller = controller;
  const params = fam.inputs.includes('params') ? { ...studio.params } : { mesh: studio.mesh.name };
  const edits = editsBody();
  const t0 = performance.now();
  try {
    const response = await transferRequest(fam, params, edits, controller.signal);
    const buffer = await response.arrayBuffer();
    if (seq !== studio.seq) return; // a newer request owns the view
    const ms = performance.now() - t0;
    await showGlb(buffer, () => seq === studio.seq, familyPath(fam));
    if (seq !== studio.seq) return;
    studio.controller = null;
    studio.lastGlbBytes = new Uint8Array(buffer);
    studio.lastParams = params;
    studio.lastEdits = edits;
    studio.lastLatencyMs = ms;
    studio.lastServerSeconds = parseFloat(response.headers.get('X-ProcTex-Seconds'));
    updateDownload();
    showStats(ms, studio.lastServerSeconds, buffer.byteLength, params, edits, response.headers.get('X-ProcTex-Notes'));
    studio.requests += 1;
    body.dataset.requests = String(studio.requests);
    showError('');
    if (settled(seq)) body.dataset.state = 'idle';
  } catch (err) {
    if (err.name === 'AbortError' || seq !== studio.seq) return;
    showError(err.message);
  } finally {
    if (seq === studio.seq) studio.controller = null;
    if (seq === studio.seq && studio.pending) transfer(); // values changed while it was in flight
    else if (settled(seq)) setBusy(false);
  }
}

function resetDownload() {
  if (studio.glbUrl) URL.revokeObjectURL(studio.glbUrl);
  studio.glbUrl = null;
  const link = $('download');
  link.removeAttribute('href');
  link.classList.add('disabled');
  link.setAttribute('aria-disabled', 'true');
}

function updateDownload() {
  // The shape on screen refers to its textures; the download is asked for self-contained, on click.
  const link = $('download');
  link.download = `${studio.family.name}.glb`;
  link.classList.remove('disabled');
  link.removeAttribute('aria-disabled');
}

async function download(event) {
  const link = $('download');
  if (studio.downloadReady) {
    studio.downloadReady = false; // the click below: the browser saves the file
    return;
  }
  event.preventDefault();
  if (link.classList.contains('disabled') || !studio.lastParams) return;
  try {
    const response = await transferRequest(studio.family, studio.lastParams, studio.lastEdits, undefined, 'embedded');
    const buffer = await response.arrayBuffer();
    studio.lastDownloadBytes = new Uint8Array(buffer);
    if (studio.glbUrl) URL.revokeObjectURL(studio.glbUrl);
    studio.glbUrl = URL.createObjectURL(new Blob([buffer], { type: 'model/gltf-binary' }));
    link.href = studio.glbUrl;
    studio.downloadReady = true;
    link.click();
  } catch (err) {
    showError(err.message);
  }
}

function showStats(ms, seconds, bytes, params, edits, notes) {
  $('latency').textContent = `${ms.toFixed(0)} ms round trip`;
  $('server').textContent = Number.isFinite(seconds) ? `${(seconds * 1000).toFixed(0)} ms (X-ProcTex-Seconds)` : '–';
  $('bytes').textContent = `${(bytes / 1024).toFixed(0)} KiB`;
  const shown = { ...params };
  if (Object.keys(edits).length) shown.edits = edits;
  $('current').textContent = JSON.stringify(shown, null, 1);
  const list = $('notes');
  list.replaceChildren();
  for (const note of notes ? JSON.parse(notes) : []) {
    const li = document.createElement('li');
    li.textContent = note;
    list.append(li);
  }
}

// ------------------------------------------------------------------------------- parameters
function decimals(step) {
  const s = String(step);
  return s.includes('e-') ? Number(s.split('e-')[1]) : (s.split('.')[1] || '').length;
}

function niceStep(spec) {
  if (spec.kind === 'integer') return 1;
  const raw = (spec.high - spec.low) / 200 || 0.001;
  const p = 10 ** Math.floor(Math.log10(raw));
  return [1, 2, 5, 10].map((m) => m * p).find((s) => s >= raw);
}

function paramControl(spec) {
  const row = document.createElement('div');
  row.className = 'param';
  const label = document.createElement('label');
  const name = document.createElement('span');
  name.textContent = spec.name + (spec.unit ? ` (${spec.unit})` : '');
  if (spec.description) row.title = spec.description;
  const out = document.createElement('output');
  label.append(name, out);
  let input;
  if (spec.kind === 'choice') {
    input = document.createElement('select');
    for (const option of spec.options) input.add(new Option(String(option), String(option)));
    input.value = String(spec.default);
    studio.params[spec.name] = spec.default;
    out.textContent = input.value;
    input.addEventListener('change', () => {
      const option = spec.options.find((o) => String(o) === input.value);
      studio.params[spec.name] = option;
      out.textContent = input.value;
      scheduleTransfer();
    });
  } else {
    const step = niceStep(spec);
    const digits = decimals(step);
    input = document.createElement('input');
    input.type = 'range';
    input.min = spec.low;
    input.max = spec.high;
    input.step = step;
    input.value = spec.default;
    const update = () => {
      const v = spec.kind === 'integer' ? Math.round(Number(input.value)) : Number(input.value);
      studio.params[spec.name] = v;
      out.textContent = v.toFixed(digits);
    };
    update();
    input.addEventListener('input', () => {
      update();
      scheduleTransfer();
    });
  }
  input.name = spec.name;
  input.setAttribute('aria-label', spec.name);
  if (isFixed(spec)) {
    // held at the model file's value: shown, never changed
    input.disabled = true;
    row.classList.add('fixed');
    name.textContent += ' (fixed)';
    row.title = spec.description || 'held at the file\'s value';
  }
  row.append(label, input);
  return row;
}

// A parameter the build holds at one value (a one-value range or a choice of one option).
function isFixed(spec) {
  return spec.kind === 'choice' ? spec.options.length === 1 : spec.low === spec.high;
}

// ------------------------------------------------------------------------------------- parts
function thumbUrl(g, size = 128) {
  const fam = studio.family;
  const q = new URLSearchParams({ size: String(size), stamp: fam.stamp });
  const e = studio.edits[g] || {};
  if (e.hue) q.set('hue', String(e.hue));
  if (e.prompt) q.set('prompt', e.prompt);
  if (studio.look) q.set('look', studio.look);
  return `/v1/families/${encodeURIComponent(fam.name)}/groups/${g}/texture.png?${q}`;
}

function groupPanel(group) {
  const g = group.group;
  const box = document.createElement('div');
  box.className = 'group';
  box.dataset.group = String(g);
  box.innerHTML = `
    <header><img alt="texture"><div><b></b><div class="muted prompt"></div></div></header>
    <div class="word muted"></div>
    <label class="assign-row">part <select class="assign" aria-label="part word"></select></label>
    <label>hue <output>0°</output><input type="range" min="-180" max="180" step="1" value="0" aria-label="hue"></label>
    <label class="pbr">roughness <output class="rough-out"></output><input class="roughness" type="range" min="0" max="1" step="0.01" aria-label="roughness"></label>
    <label class="pbr">metallic <output class="metal-out"></output><input class="metallic" type="range" min="0" max="1" step="0.01" aria-label="metallic"></label>
    <div class="row"><input type="text" placeholder="new prompt" aria-label="prompt"><button class="secondary repaint">re-paint</button></div>
    <div class="row"><button class="save" disabled>save to family</button><button class="secondary reset" disabled>reset</button></div>
    <label class="photo-row">photo <input class="photo" type="file" accept="image/png,image/jpeg,image/webp,image/tiff,image/bmp" aria-label="photo"></label>
    <div class="photo-note muted"></div>`;
  const img = box.querySelector('img');
  const hue = box.querySelector('input[type=range]');
  const hueOut = box.querySelector('output');
  const prompt = box.querySelector('input[type=text]');
  const material = { roughness: box.querySelector('input.roughness'), metallic: box.querySelector('input.metallic') };
  const materialOut = { roughness: box.querySelector('.rough-out'), metallic: box.querySelector('.metal-out') };
  const painted = { roughness: group.roughness, metallic: group.metallic }; // the maps' means as painted
  const showMaterial = () => {
    const e = studio.edits[g] || {};
    for (const key of ['roughness', 'metallic']) {
      const v = e[key] !== undefined ? e[key] : painted[key];
      material[key].value = String(v ?? 0);
      materialOut[key].textContent = Number(v ?? 0).toFixed(2);
    }
  };
  for (const el of box.querySelectorAll('.pbr')) el.hidden = !group.pbr;
  prompt.maxLength = studio.family.limits.max_prompt;
  const save = box.querySelector('.save');
  const reset = box.querySelector('.reset');
  box.querySelector('b').textContent = group.label || `group ${g}`;
  // every name the group's parts carry (a model's own names are untrusted: text, never HTML)
  if ((group.names || []).length > 1) box.querySelector('b').title = group.names.join(', ');
  box.querySelector('.prompt').textContent = group.prompt || studio.family.prompt || '';
  const photo = box.querySelector('input.photo');
  photo.disabled = !studio.family.edits_enabled;
  photo.addEventListener('change', () => setPhoto(g, photo.files[0] || null));
  box.addEventListener('dragover', (ev) => { if (studio.family.edits_enabled) ev.preventDefault(); });
  box.addEventListener('drop', (ev) => {
    ev.preventDefault();
    if (studio.family.edits_enabled && ev.dataTransfer.files.length) setPhoto(g, ev.dataTransfer.files[0]);
  });
  const assign = box.querySelector('select.assign');
  assign.disabled = !studio.family.edits_enabled;
  assign.addEventListener('change', () => {
    studio.words[g] = assign.value;
    $('save-words').disabled = !studio.family.edits_enabled;
    body.dataset.words = 'changed';
  });
  let thumbTimer = null;
  const changed = () => {
    const e = studio.edits[g] || {};
    const dirty = Boolean(e.hue || e.prompt || e.roughness !== undefined || e.metallic !== undefined);
    save.disabled = !dirty || !studio.family.edits_enabled;
    reset.disabled = !dirty;
    clearTimeout(thumbTimer);
    thumbTimer = setTimeout(() => { img.src = thumbUrl(g); }, DEBOUNCE_MS);
    scheduleTransfer();
  };
  const pending = studio.edits[g] || {}; // kept across a reload of the family (after a save)
  hue.value = String(pending.hue || 0);
  hueOut.textContent = `${hue.value}°`;
  prompt.value = pending.prompt || '';
  reset.disabled = !(pending.hue || pending.prompt || pending.roughness !== undefined || pending.metallic !== undefined);
  showMaterial();
  save.disabled = reset.disabled || !studio.family.edits_enabled;
  if (!studio.family.edits_enabled) save.title = 'this service is read-only (started without an edit token)';
  img.src = thumbUrl(g);
  hue.addEventListener('input', () => {
    studio.edits[g] = { ...studio.edits[g], hue: Number(hue.value) };
    hueOut.textContent = `${hue.value}°`;
    changed();
  });
  for (const key of ['roughness', 'metallic']) {
    material[key].addEventListener('input', () => {
      studio.edits[g] = { ...studio.edits[g], [key]: Number(material[key].value) };
      materialOut[key].textContent = Number(material[key].value).toFixed(2);
      changed();
    });
  }
  const repaint = () => {
    studio.edits[g] = { ...studio.edits[g], prompt: prompt.value.trim() };
    changed();
  };
  box.querySelector('.repaint').addEventListener('click', repaint);
  prompt.addEventListener('keydown', (ev) => { if (ev.key === 'Enter') repaint(); });
  reset.addEventListener('click', () => {
    delete studio.edits[g];
    hue.value = '0';
    hueOut.textContent = '0°';
    prompt.value = '';
    showMaterial();
    changed();
  });
  save.addEventListener('click', async () => {
    const edit = { group: g, ...editsBody()[g] };
    save.disabled = true;
    try {
      // The edit token comes from the page's fragment (#token=...), which never reaches a server log;
      // If-Match makes the save fail (409) if the family changed since this view loaded.
      await api(`/v1/families/${encodeURIComponent(studio.family.name)}/edits${lookQuery('?')}`, {
        method: 'POST',
        headers: { 'content-type': 'application/json', 'X-ProcTex-Token': editToken(), 'If-Match': studio.family.stamp },
        body: JSON.stringify(edit),
      });
      delete studio.edits[g]; // part of the family now
      await loadFamily(studio.family.name, { keepView: true, look: studio.look });
    } catch (err) {
      showError(`save failed: ${err.message}`);
      save.disabled = false;
    }
  });
  return box;
}

// ---------------------------------------------------------------------------------- families
async function loadFamily(name, { keepView = false, look = null } = {}) {
  body.dataset.state = 'loading';
  studio.look = look;
  const fam = await (await api(`/v1/families/${encodeURIComponent(name)}${lookQuery('?')}`)).json();
  const previous = studio.family && studio.family.name === name ? studio.params : {};
  studio.family = fam;
  const looks = $('look');
  looks.replaceChildren(...(fam.looks || [fam.look]).map((n) => new Option(n, n)));
  looks.value = fam.look;
  const adding = $('addlook');
  for (const el of adding.elements) el.disabled = !fam.edits_enabled;
  adding.title = fam.edits_enabled ? 'paint the family with another prompt (a new look; seconds, no rebuild)'
    : 'this service is read-only (started without an edit token)';
  if (!keepView) {
    cancelInFlight(); // nothing of the previous family may land on this one
    studio.edits = {};
    studio.mesh = null;
    $('mesh').value = '';
    clearModel();
    resetDownload();
  }
  studio.params = {};
  $('prompt').textContent = fam.prompt ? `“${fam.prompt}”` : '';
  const usesParams = fam.inputs.includes('params');
  const params = $('params');
  params.replaceChildren();
  if (usesParams) {
    for (const spec of fam.parameters) {
      if (keepView && spec.name in previous) spec.default = previous[spec.name];
      params.append(paramControl(spec));
    }
  }
  $('upload').hidden = usesParams;
  if (!keepView) studio.photos = {};
  $('groups').replaceChildren(...fam.groups.map(groupPanel));
  for (const g of Object.keys(studio.photos)) setPhoto(Number(g), studio.photos[g]);
  studio.words = {};
  $('save-words').disabled = true;
  const url = new URL(window.location);
  url.searchParams.set('family', name);
  if (studio.look) url.searchParams.set('look', studio.look);
  else url.searchParams.delete('look');
  window.history.replaceState(null, '', url);
  scheduleTransfer(0);
  await loadParts(); // beside the first transfer: which part took which word
}

// Which group took which word of the look's prompt, and the choices of each group's "part" menu:
// as the prompt reads (no word of yours), each clause of the prompt that names a part, or none (the
// rest of the prompt).
async function loadParts() {
  body.dataset.parts = 'loading';
  try {
    studio.parts = await (await api(`${familyPath(studio.family)}parts${lookQuery('?')}`)).json();
  } catch (err) {
    studio.parts = null;
    $('words-note').textContent = `part words unavailable: ${err.message}`;
    body.dataset.parts = 'error';
    return;
  }
  const parts = studio.parts;
  const stored = parts.assigned || {};
  const clauses = [];
  for (const c of parts.clauses || []) if (!clauses.some((x) => x.word === c.word)) clauses.push(c);
  for (const box of document.querySelectorAll('.group')) {
    const g = Number(box.dataset.group);
    const row = partRow(g);
    box.querySelector('.word').textContent = row ? describePart(g).replace(/^group \d+( “[^”]*”)?: /, '') : '';
    const select = box.querySelector('select.assign');
    const options = [new Option('as the prompt reads', '')];
    for (const c of clauses) options.push(new Option(`${c.name}: “${c.text}”`, c.word));
    const mine = stored[String(g)];
    if (mine && !clauses.some((c) => c.word === mine) && mine !== 'rest') options.push(new Option(mine, mine));
    options.push(new Option('no part word (the rest)', 'rest'));
    select.replaceChildren(...options);
    select.value = studio.words[g] !== undefined ? studio.words[g] : (mine || '');
  }
  const n = Object.keys(stored).length;
  $('words-note').textContent = n ? `your words: ${Object.entries(stored).map(([g, w]) => `${g}=${w}`).join(', ')}; new looks follow them`
    : 'hover a part to see its word; click it to give it another';
  body.dataset.parts = 'ready';
}

async function saveWords() {
  // PUT .../parts with the edit token: the family keeps the words; every look painted afterwards follows them.
  const button = $('save-words');
  button.disabled = true;
  try {
    await api(`${familyPath(studio.family)}parts`, {
      method: 'PUT',
      headers: { 'content-type': 'application/json', 'X-ProcTex-Token': editToken() },
      body: JSON.stringify({ groups: studio.words }),
    });
    studio.words = {};
    await loadParts();
    body.dataset.words = 'saved';
  } catch (err) {
    showError(`saving the part words failed: ${err.message}`);
    button.disabled = false;
  }
}

async function addLook(event) {
  // A new look of the family (POST .../looks, the edit token): painted by the service in seconds, then shown.
  event.preventDefault();
  const form = $('addlook');
  const name = $('look-name').value.trim();
  const prompt = $('look-prompt').value.trim();
  const photos = Object.entries(studio.photos);
  const glb = $('look-glb').files[0] || null;
  if (!name || (!prompt && !photos.length && !glb)) return;
  for (const el of form.elements) el.disabled = true;
  setBusy(true);
  try {
    const look = prompt ? { name, prompt } : { name };
    let request;
    if (glb) { // the family's template GLB painted elsewhere: its textures read back into the atlases
      const data = new FormData();
      data.append('look', JSON.stringify($('look-member').checked ? { name, member: true } : { name }));
      data.append('glb', glb, glb.name);
      request = { method: 'POST', headers: { 'X-ProcTex-Token': editToken() }, body: data };
    } else if (photos.length) { // multipart: the look's JSON and a file per photographed group
      const data = new FormData();
      data.append('look', JSON.stringify(look));
      for (const [g, file] of photos) data.append(`image.${g}`, file, file.name);
      request = { method: 'POST', headers: { 'X-ProcTex-Token': editToken() }, body: data };
    } else {
      request = { method: 'POST', headers: { 'content-type': 'application/json', 'X-ProcTex-Token': editToken() }, body: JSON.stringify(look) };
    }
    await api(`${familyPath(studio.family)}looks`, request);
    $('look-name').value = '';
    $('look-prompt').value = '';
    $('look-glb').value = '';
    $('look-member').checked = false;
    $('look-prompt').required = true;
    for (const g of Object.keys(studio.photos)) setPhoto(Number(g), null);
    await loadFamily(studio.family.name, { keepView: true, look: name });
  } catch (err) {
    showError(err.message);
    for (const el of form.elements) el.disabled = false;
    setBusy(false);
  }
}

async function start() {
  try {
    const { families } = await (await api('/v1/families')).json();
    const select = $('family');
    for (const name of families) select.add(new Option(name, name));
    if (!families.length) throw new Error('no built families under the store root');
    const wanted = new URL(window.location).searchParams.get('family');
    select.value = families.includes(wanted) ? wanted : families[0];
    select.addEventListener('change', () => loadFamily(select.value).catch((e) => showError(e.message)));
    $('look').addEventListener('change', (ev) => {
      const look = ev.target.value === studio.family.looks[0] ? null : ev.target.value; // the first is the build's
      loadFamily(studio.family.name, { keepView: true, look }).catch((e) => showError(e.message));
    });
    $('addlook').addEventListener('submit', addLook);
    $('look-glb').addEventListener('change', (ev) => { // a GLB needs no prompt
      const file = ev.target.files[0];
      $('look-prompt').required = !file && !Object.keys(studio.photos).length;
      $('look-prompt').placeholder = file ? `from ${file.name}` : 'prompt, e.g. white oak';
    });
    $('save-words').addEventListener('click', saveWords);
    $('download').addEventListener('click', download);
    $('mesh').addEventListener('change', (ev) => {
      studio.mesh = ev.target.files[0] || null;
      framed = false;
      scheduleTransfer(0);
    });
    resize();
    await loadFamily(select.value, { look: new URL(window.location).searchParams.get('look') });
  } catch (err) {
    showError(err.message);
  }
}

studio.schedule = scheduleTransfer;
start();
