// The layer inspector's page: see the composite through the display LUT, regrade the layer
// stack live, manage the stack as a document (undo, redo, kept beside the render), compare
// looks, inspect the light paths of a pixel or region, make a layer, save the look and push
// light edits back into the shot. Plain ES2022 and WebGL2, no build step. The HTTP API is
// the server's (pxr_layers/view/server.py, docs/inspector-api.md); the composite rule lives in
// renderer.js's FRAGMENT_MAIN and in pxr_layers/view/composite.py (the numpy reference).

// Sibling modules carry the token too (every request must): imported with this module's query.
const QUERY = new URL(import.meta.url).search;
const { Renderer, MODES } = await import(`./renderer.js${QUERY}`);
const {
  History, newEntry, emptyDocument, freeName, moveEntry, setGroup, snapshotOf, GRADE_KEYS,
} = await import(`./document.js${QUERY}`);

// --- the server ---------------------------------------------------------------------------

// Every request carries the access token the server put in the page's URL.
const TOKEN = new URLSearchParams(location.search).get('token') ?? '';
const LAYER_NAME = /^[A-Za-z_][A-Za-z0-9_]*$/;
const LOOK_NAME = /^[A-Za-z_][A-Za-z0-9_-]*$/;

class ApiError extends Error {
  constructor(message, status, position) {
    super(message);
    this.status = status;
    this.position = position;  // an LPE error's caret, 0-based character offset
  }
}

async function api(path, { method = 'GET', body, signal, binary = false, keepalive = false } = {}) {
  const headers = { 'X-Pxr-Token': TOKEN };
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  const response = await fetch(path, {
    method, headers, signal, keepalive, body: body === undefined ? undefined : JSON.stringify(body),
  });
  if (!response.ok) {
    let message = `${response.status} ${response.statusText}`;
    let position;
    try {
      const reply = await response.json();
      message = reply.error ?? message;
      position = reply.position;
    } catch { /* not JSON: the status line says it */ }
    throw new ApiError(message, response.status, position);
  }
  return binary ? response : response.json();
}

/** A binary answer of `count` little-endian float32 values (`what` names it in the error). */
async function fetchFloats(path, count, what) {
  const data = new Float32Array(await (await api(path, { binary: true })).arrayBuffer());
  if (data.length !== count) throw new Error(`${what}: ${data.length} floats, expected ${count}`);
  return data;
}

/** An image of the stack: Float32Array of height × width × 3 linear RGB, top row first. */
function fetchImage(id, width, height) {
  const version = state.doc.denoised ? 'denoised' : 'raw';
  return fetchFloats(`/api/image/${encodeURIComponent(id)}?version=${version}`, width * height * 3, `image ${id}`);
}

/** A mask's coverage (GET /api/mask): Float32Array of height × width, top row first. */
function fetchMask(mask, width, height) {
  const query = new URLSearchParams({ kind: mask.kind });
  for (const name of mask.names) query.append('names', name);
  return fetchFloats(`/api/mask?${query}`, width * height, 'mask');
}

// --- small helpers ------------------------------------------------------------------------

const $ = (selector, root = document) => root.querySelector(selector);

/** An element with attributes (on* are listeners) and children (strings become text). */
function el(tag, attributes = {}, ...children) {
  const node = document.createElement(tag);
  for (const [key, value] of Object.entries(attributes)) {
    if (value === undefined || value === null || value === false) continue;
    if (key.startsWith('on')) node.addEventListener(key.slice(2), value);
    else if (key === 'dataset') Object.assign(node.dataset, value);
    else if (key in node && typeof value !== 'string') node[key] = value;
    else node.setAttribute(key, value === true ? '' : value);
  }
  node.append(...children.flat().filter((child) => child !== null && child !== undefined));
  return node;
}

function percent(share) {
  const value = share * 100;
  if (value > 0 && value < 0.01) return '<0.01 %';
  return `${value.toFixed(value >= 1 ? 1 : 2)} %`;
}

function shareBar(share) {
  return el('span', { class: 'share-bar' },
    el('span', { style: `width: ${Math.max(0, Math.min(1, share)) * 100}%` }));
}

const number = (value, digits = 3) => (Number.isFinite(value) ? Number(value.toPrecision(digits)).toString() : '–');

// The colour input speaks sRGB-encoded 8-bit; the tint is a linear multiplier.
const srgbToLinear = (c) => (c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4);
const linearToSrgb = (v) => (v <= 0.0031308 ? v * 12.92 : 1.055 * v ** (1 / 2.4) - 0.055);

function hexToLinear(hex) {
  return [1, 3, 5].map((at) => srgbToLinear(parseInt(hex.slice(at, at + 2), 16) / 255));
}

function linearToHex(rgb) {
  const byte = (v) => Math.round(Math.max(0, Math.min(1, linearToSrgb(v))) * 255).toString(16).padStart(2, '0');
  return `#${rgb.map(byte).join('')}`;
}

function setStatus(text, error = false) {
  const status = $('#status');
  status.textContent = text;
  status.title = text;
  status.classList.toggle('error', error);
}

function base64(bytes) {
  let text = '';
  for (let at = 0; at < bytes.length; at += 0x8000) {
    text += String.fromCharCode.apply(null, bytes.subarray(at, at + 0x8000));
  }
  return btoa(text);
}


// --- state --------------------------------------------------------------------------------

const state = {
  width: 0,
  height: 0,
  index: null,          // the session's index description, or null
  sources: new Map(),   // server layer id → {id, name, kind, share, expression, product, exposure, tint, slice, data}
  doc: emptyDocument(), // the working state (document.js); its entries are the stack, beauty first
  masks: new Map(),     // mask key → {slice, data} once fetched, {pending} while fetching
  kelvin: null,         // {min, max, step, rgb: [[r, g, b], ...]}: the blackbody colours of the Kelvin control
  cryptomattes: {},     // kind → {layer, names}: what masks can be made of
  view: { x: 0, y: 0, scale: 1, fit: true },  // device pixels, relative to the canvas (side by side: each half)
  selection: null,      // {x0, y0, x1, y1}, image pixels, exclusive end
  cursor: null,         // [x, y]: the keyboard's pixel cursor
  inspection: null,     // the last /api/inspect reply
  picked: new Set(),    // ticked class ids of that reply
  picking: null,        // the entry id whose mask a click in the image picks names for
  regrading: null,      // the entry id last regraded (renderer.js: its frames add it to a base of the rest)
  tab: 'classes',
  builder: { rows: [], anyAfter: true },
  pushable: new Map(),  // entry name → {light} or {why}
  overlaps: null,       // the last /api/overlaps reply
};
let history = null;

/** The entry of the stack with this id (entries are replaced by undo: look them up, keep ids). */
const entryById = (id) => state.doc.entries.find((entry) => entry.id === id);
const layerEntries = (entries = state.doc.entries) => entries.filter((entry) => entry.kind !== 'beauty');

const canvas = $('#canvas');
let renderer = null;
let drawPending = false;
let afterDraw = [];     // callbacks for the next frame (once drawn and finished)
let framesDrawn = 0;

function requestDraw() {
  if (drawPending || !renderer) return;
  drawPending = true;
  requestAnimationFrame(() => {
    drawPending = false;
    drawNow();
    placeSelection();
    if (afterDraw.length) {
      renderer.finish();
      const callbacks = afterDraw;
      afterDraw = [];
      for (const callback of callbacks) callback(performance.now());
    }
  });
}

/** gain · tint · blackbody(kelvin) of an entry (0 when muted is the shader's business). */
function gradeOf(entry) {
  const gain = 2 ** entry.stops;
  const colour = entry.kelvin === null || !state.kelvin ? [1, 1, 1] : kelvinRgb(entry.kelvin);
  return entry.tint.map((channel, c) => gain * channel * colour[c]);
}

function kelvinRgb(kelvin) {
  const { min, step, rgb } = state.kelvin;
  return rgb[Math.max(0, Math.min(rgb.length - 1, Math.round((kelvin - min) / step)))];
}

const maskKey = (mask) => `${mask.kind}\n${[...mask.names].sort().join('\n')}`;

/** What the renderer draws of a look: its entries (the beauty left out) and exposure. */
function lookOf(entries, exposure) {
  return {
    exposure,
    entries: layerEntries(entries).filter((entry) => state.sources.has(entry.source)).map((entry) => ({
      id: entry.id, slice: state.sources.get(entry.source).slice, grade: gradeOf(entry), mute: entry.mute, solo: entry.solo,
      maskSlice: entry.mask ? (state.masks.get(maskKey(entry.mask))?.slice ?? -1) : -1,
    })),
  };
}

/** The look compared against the current one: the raw beauty, the saved look or a snapshot. */
function comparedLook() {
  const { against } = state.doc.compare;
  if (against === 'saved' && state.doc.saved) return lookOf(state.doc.saved.entries, state.doc.saved.exposure);
  const snapshot = against.startsWith('snapshot:') ? state.doc.snapshots[Number(against.slice(9))] : null;
  if (snapshot) return lookOf(snapshot.entries, snapshot.exposure);
  return { entries: [], exposure: state.doc.exposure };  // the raw beauty, at the viewing exposure
}

function drawNow() {
  const { mode, wipe } = state.doc.compare;
  const looks = [lookOf(state.doc.entries, state.doc.exposure)];
  if (mode !== 'one') looks.push(comparedLook());
  const split = mode === 'wipe' ? state.view.x + wipe * state.width * state.view.scale : 0;
  const active = looks[0].entries.findIndex((entry) => entry.id === state.regrading);
  renderer.draw(looks, state.view, MODES[mode], split, active);
  framesDrawn += 1;
}

/** Resolves once the next frame is drawn and finished on the GPU, with its time. */
function nextFrame() {
  return new Promise((resolve) => { afterDraw.push(resolve); requestDraw(); });
}

// --- the view: fit, 1:1, zoom, pan, the keyboard's cursor, the wipe -------------------------

const dpr = () => window.devicePixelRatio || 1;
/** Device pixels across one view of the image: the canvas, or half of it side by side. */
const panelWidth = () => (state.doc.compare.mode === 'side' ? Math.floor(canvas.width / 2) : canvas.width);

function resizeCanvas() {
  const box = canvas.getBoundingClientRect();
  const width = Math.max(1, Math.round(box.width * dpr()));
  const height = Math.max(1, Math.round(box.height * dpr()));
  if (canvas.width !== width || canvas.height !== height) {
    canvas.width = width;
    canvas.height = height;
  }
  if (state.width) restoreView();
  requestDraw();
}

let restoring = false;  // showing the document's view: not a change of it

function setView(x, y, scale, fitted = false) {
  Object.assign(state.view, { x, y, scale, fit: fitted });
  const shown = scale * 100 / dpr();
  $('#zoom').textContent = `${shown >= 10 ? Math.round(shown) : shown.toFixed(1)} %`;
  if (state.width && !restoring) {  // kept in the document as the image point at the centre: the canvas may change size
    state.doc.view = {
      fit: fitted, scale,
      cx: (panelWidth() / 2 - x) / scale / state.width, cy: (canvas.height / 2 - y) / scale / state.height,
    };
    schedulePersist();
  }
  placeWipe();
  requestDraw();
}

/** The view the document holds (on reload): fitted, or its scale around its centre. */
function restoreView() {
  const { fit: fitted, scale, cx, cy } = state.doc.view;
  restoring = true;
  if (fitted) fit();
  else setView(Math.round(panelWidth() / 2 - cx * state.width * scale), Math.round(canvas.height / 2 - cy * state.height * scale), scale);
  restoring = false;
}

/** The whole image; enlarged by a whole factor only, so that pixels stay equal squares. */
function fit() {
  if (!state.width) return;
  let scale = Math.min(panelWidth() / state.width, canvas.height / state.height);
  if (scale >= 1) scale = Math.floor(scale);
  setView(Math.round((panelWidth() - state.width * scale) / 2), Math.round((canvas.height - state.height * scale) / 2),
    scale, true);
}

/** One image pixel per device pixel, centred, on whole pixels. */
function oneToOne() {
  setView(Math.round((panelWidth() - state.width) / 2), Math.round((canvas.height - state.height) / 2), 1);
}

function zoomAt(deviceX, deviceY, factor) {
  const { x, y, scale } = state.view;
  const next = Math.min(256, Math.max(1 / 64, scale * factor));
  const imageX = (deviceX - x) / scale;
  const imageY = (deviceY - y) / scale;
  setView(deviceX - imageX * next, deviceY - imageY * next, next);
}

/** The device point of a pointer event, in the view's frame (side by side: either half). */
function deviceAt(event) {
  const box = canvas.getBoundingClientRect();
  let x = (event.clientX - box.left) * dpr();
  if (state.doc.compare.mode === 'side' && x >= panelWidth()) x -= panelWidth();
  return [x, (event.clientY - box.top) * dpr()];
}

/** Image coordinates (fractional pixels) under a device pixel. */
function imageAt(deviceX, deviceY) {
  return [(deviceX - state.view.x) / state.view.scale, (deviceY - state.view.y) / state.view.scale];
}

function placeBox(box, rect) {
  if (!rect) { box.hidden = true; return; }
  const { x, y, scale } = state.view;
  const ratio = dpr();
  Object.assign(box.style, {
    left: `${(x + rect.x0 * scale) / ratio}px`,
    top: `${(y + rect.y0 * scale) / ratio}px`,
    width: `${(rect.x1 - rect.x0) * scale / ratio}px`,
    height: `${(rect.y1 - rect.y0) * scale / ratio}px`,
  });
  box.hidden = false;
}

function placeSelection() {
  placeBox($('#selection'), state.selection);
  const cursor = state.cursor && document.activeElement === canvas
    ? { x0: state.cursor[0], y0: state.cursor[1], x1: state.cursor[0] + 1, y1: state.cursor[1] + 1 } : null;
  placeBox($('#cursor'), cursor);
}

/** The pixel rectangle between two image points, clipped to the image; null if empty. */
function pixelRect([ax, ay], [bx, by]) {
  const x0 = Math.max(0, Math.floor(Math.min(ax, bx)));
  const y0 = Math.max(0, Math.floor(Math.min(ay, by)));
  const x1 = Math.min(state.width, Math.floor(Math.max(ax, bx)) + 1);
  const y1 = Math.min(state.height, Math.floor(Math.max(ay, by)) + 1);
  return x1 > x0 && y1 > y0 ? { x0, y0, x1, y1 } : null;
}

let spaceHeld = false;
let gesture = null;  // {kind: 'pan' | 'select', start: device point, last: device point}
const CLICK_SLOP = 3;  // device pixels a click may move and stay a click

function setupView() {
  new ResizeObserver(resizeCanvas).observe(canvas);
  canvas.addEventListener('wheel', (event) => {
    event.preventDefault();
    const [dx, dy] = deviceAt(event);
    const lines = event.deltaMode === WheelEvent.DOM_DELTA_LINE ? 33 : 1;
    zoomAt(dx, dy, 2 ** (-event.deltaY * lines / 300));
  }, { passive: false });
  canvas.addEventListener('pointerdown', (event) => {
    const pan = event.button === 1 || (event.button === 0 && spaceHeld);
    if (!pan && event.button !== 0) return;
    event.preventDefault();
    canvas.focus({ preventScroll: true });
    canvas.setPointerCapture(event.pointerId);
    const point = deviceAt(event);
    gesture = { kind: pan ? 'pan' : 'select', start: point, last: point };
  });
  canvas.addEventListener('pointermove', (event) => {
    const point = deviceAt(event);
    showReadout(point);
    if (!gesture) return;
    if (gesture.kind === 'pan') {
      setView(state.view.x + point[0] - gesture.last[0], state.view.y + point[1] - gesture.last[1], state.view.scale);
    } else if (Math.hypot(point[0] - gesture.start[0], point[1] - gesture.start[1]) > CLICK_SLOP) {
      placeBox($('#band'), pixelRect(imageAt(...gesture.start), imageAt(...point)));
    }
    gesture.last = point;
  });
  const end = (event) => {
    if (!gesture) return;
    const { kind, start } = gesture;
    gesture = null;
    $('#band').hidden = true;
    if (kind !== 'select' || event.type === 'pointercancel') return;
    const point = deviceAt(event);
    const click = Math.hypot(point[0] - start[0], point[1] - start[1]) <= CLICK_SLOP;
    const rect = pixelRect(imageAt(...start), imageAt(...(click ? start : point)));
    if (!rect) return;
    state.cursor = [rect.x0, rect.y0];
    if (click && state.picking) pickMaskName(rect.x0, rect.y0);
    else inspect(rect);
  };
  canvas.addEventListener('pointerup', end);
  canvas.addEventListener('pointercancel', end);
  canvas.addEventListener('auxclick', (event) => event.preventDefault());  // no paste or autoscroll on middle
  canvas.addEventListener('pointerleave', () => { $('#readout').textContent = ''; });
  canvas.addEventListener('keydown', cursorKey);
  canvas.addEventListener('focus', () => {
    state.cursor ??= [Math.floor(state.width / 2), Math.floor(state.height / 2)];
    placeSelection();
  });
  canvas.addEventListener('blur', placeSelection);
  $('#fit').addEventListener('click', fit);
  $('#one-to-one').addEventListener('click', oneToOne);
  setupWipe();
}

/** The image with the keyboard: arrows move a pixel cursor (shift: 10 pixels), Enter lists
 *  its light paths (or picks its mask name), + and − zoom around it. */
function cursorKey(event) {
  if (event.ctrlKey || event.metaKey || event.altKey || !state.cursor) return;
  const step = event.shiftKey ? 10 : 1;
  const moves = { ArrowLeft: [-step, 0], ArrowRight: [step, 0], ArrowUp: [0, -step], ArrowDown: [0, step] };
  const [x, y] = state.cursor;
  if (moves[event.key]) {
    const [dx, dy] = moves[event.key];
    state.cursor = [Math.max(0, Math.min(state.width - 1, x + dx)), Math.max(0, Math.min(state.height - 1, y + dy))];
    const { view } = state;
    showReadout([view.x + (state.cursor[0] + 0.5) * view.scale, view.y + (state.cursor[1] + 0.5) * view.scale]);
    placeSelection();
  } else if (event.key === 'Enter') {
    if (state.picking) pickMaskName(x, y);
    else inspect({ x0: x, y0: y, x1: x + 1, y1: y + 1 });
  } else if (event.key === '+' || event.key === '=' || event.key === '-') {
    const { view } = state;
    zoomAt(view.x + (x + 0.5) * view.scale, view.y + (y + 0.5) * view.scale, event.key === '-' ? 0.5 : 2);
  } else return;
  event.preventDefault();
  event.stopPropagation();
}

function showReadout(point) {
  const [ix, iy] = imageAt(...point).map(Math.floor);
  const beauty = state.sources.get('beauty')?.data;
  if (!beauty || ix < 0 || iy < 0 || ix >= state.width || iy >= state.height) {
    $('#readout').textContent = '';
    return;
  }
  const at = (iy * state.width + ix) * 3;
  const rgb = Array.from(beauty.subarray(at, at + 3), (v) => number(v, 4));
  $('#readout').textContent = `${ix}, ${iy}  beauty ${rgb.join(' ')}`;
}

/** The wipe line: dragged, or moved with the arrow keys when focused (a slider). */
function placeWipe() {
  const handle = $('#wipe');
  if (!handle) return;
  const { mode, wipe } = state.doc.compare;
  handle.hidden = mode !== 'wipe' || !state.width;
  if (handle.hidden) return;
  handle.style.left = `${(state.view.x + wipe * state.width * state.view.scale) / dpr()}px`;
  handle.setAttribute('aria-valuenow', String(Math.round(wipe * 100)));
  handle.setAttribute('aria-valuetext', `${Math.round(wipe * 100)} % of the image shows the current look`);
}

function setWipe(fraction) {
  state.doc.compare.wipe = Math.max(0, Math.min(1, fraction));
  placeWipe();
  schedulePersist();
  requestDraw();
}

function setupWipe() {
  const handle = $('#wipe');
  handle.addEventListener('pointerdown', (event) => {
    event.preventDefault();
    handle.setPointerCapture(event.pointerId);
    handle.focus();
    const move = (moved) => {
      const box = canvas.getBoundingClientRect();
      setWipe(((moved.clientX - box.left) * dpr() - state.view.x) / (state.width * state.view.scale));
    };
    handle.addEventListener('pointermove', move);
    handle.addEventListener('pointerup', () => handle.removeEventListener('pointermove', move), { once: true });
  });
  handle.addEventListener('keydown', (event) => {
    const steps = { ArrowLeft: -0.02, ArrowRight: 0.02, Home: -1, End: 1, PageDown: -0.1, PageUp: 0.1 };
    if (!(event.key in steps)) return;
    event.preventDefault();
    event.stopPropagation();
    setWipe(state.doc.compare.wipe + steps[event.key]);
  });
}

// --- the document: edits, undo and redo, persistence --------------------------------------

/** Every change of the working state goes through here (one undo step each; `key` names the
 *  control, so that a slider's drag is one step). */
function edit(label, change, options = {}) {
  history.edit(label, change, options);
}

/** After every edit, undo and redo: the stack's rows, the picture, the document on disk. */
function documentChanged(document, { structure }) {
  if (structure) renderStack();
  else layerEntries().forEach(syncRow);
  syncExposure();
  syncCompare();
  syncHistoryButtons();
  ensureMasks();
  requestDraw();
  schedulePersist();
  scheduleChecks(structure);
}

function syncHistoryButtons() {
  const undo = $('#undo');
  const redo = $('#redo');
  undo.disabled = !history.canUndo;
  redo.disabled = !history.canRedo;
  undo.title = history.canUndo ? `undo ${history.undoLabel} (Ctrl+Z)` : 'nothing to undo';
  redo.title = history.canRedo ? `redo ${history.redoLabel} (Ctrl+Shift+Z)` : 'nothing to redo';
}

function undo() {
  const label = history.undo();
  setStatus(label ? `undone: ${label}` : 'nothing to undo');
}

function redo() {
  const label = history.redo();
  setStatus(label ? `redone: ${label}` : 'nothing to redo');
}

let persistTimer = 0;
let persisting = Promise.resolve();
const PERSIST_DELAY_MS = 300;

/** Write the document beside the render, shortly after the last change. */
function schedulePersist() {
  if (!history) return;
  clearTimeout(persistTimer);
  persistTimer = setTimeout(persistNow, PERSIST_DELAY_MS);
}

function persistNow({ keepalive = false } = {}) {
  clearTimeout(persistTimer);
  persistTimer = 0;
  const body = structuredClone(state.doc);  // as it is now: later edits are the next write's
  persisting = persisting.then(() => api('/api/document', { method: 'PUT', keepalive, body })
    .then(() => { pxrViewer.persisted += 1; })
    .catch((error) => setStatus(`the working state is not kept: ${error.message}`, true)));
  return persisting;
}

// --- exposure and the layer stack ---------------------------------------------------------

function syncExposure() {
  const { exposure } = state.doc;
  if (Number($('#exposure').value) !== exposure) $('#exposure').value = exposure;
  if (document.activeElement !== $('#exposure-number') && Number($('#exposure-number').value) !== exposure) {
    $('#exposure-number').value = exposure;
  }
}

function setExposure(stops) {
  const value = Number.isFinite(stops) ? stops : 0;
  edit('exposure', (doc) => { doc.exposure = value; }, { key: 'exposure' });
}

function setupStack() {
  $('#exposure').addEventListener('input', (event) => setExposure(Number(event.target.value)));
  $('#exposure-number').addEventListener('input', (event) => {
    if (event.target.value !== '') setExposure(Number(event.target.value));
  });
  $('#reset').addEventListener('click', resetGrades);
  $('#undo').addEventListener('click', undo);
  $('#redo').addEventListener('click', redo);
  $('#snapshot').addEventListener('click', () => takeSnapshot());
  $('#compare-mode').addEventListener('change', (event) => setCompare({ mode: event.target.value }));
  $('#compare-against').addEventListener('change', (event) => setCompare({ against: event.target.value }));
}

/** A server layer as the page keeps it (its image comes later). */
function addSource(layer) {
  const source = {
    id: layer.id, name: layer.name ?? layer.id, kind: layer.kind, share: layer.share ?? 0,
    expression: layer.expression ?? '', product: layer.product ?? '', exposure: Number.isFinite(layer.exposure) ? layer.exposure : 0,
    tint: Array.isArray(layer.tint) && layer.tint.length === 3 ? layer.tint.map(Number) : [1, 1, 1],
    slice: layer.kind === 'beauty' ? 0 : state.sources.size + (state.sources.has('beauty') ? 0 : 1), data: null,
  };
  state.sources.set(source.id, source);
  return source;
}

async function loadSource(source) {
  source.data = await fetchImage(source.id, state.width, state.height);
  renderer.setImage(source.slice, source.data, state.width, state.height);
}

const stackNames = (except = null) => new Set(state.doc.entries.filter((entry) => entry.id !== except).map((entry) => entry.name));
const stackIds = () => new Set(state.doc.entries.map((entry) => entry.id));

/** A new entry of `source` at the end of the stack (or after `after`), named freely. */
function entryOf(source, fields = {}, after = null) {
  const name = freeName(fields.name ?? source.name, stackNames());
  const entry = newEntry(source, { ...fields, name, id: freeName(fields.id ?? source.id, stackIds()) });
  return { entry, at: after === null ? state.doc.entries.length : state.doc.entries.findIndex((e) => e.id === after) + 1 };
}

const openDetails = new Set();  // ids of the rows whose "more" is open (kept across rebuilds)
const collapsed = new Set();    // groups folded away

function renderStack() {
  const items = [];
  let group = null;
  const groups = new Set();
  for (const entry of state.doc.entries) {
    if (entry.kind !== 'beauty' && entry.group !== group) {
      group = entry.group;
      if (group) items.push(groupRow(group));
    }
    if (entry.group) groups.add(entry.group);
    if (!(entry.group && collapsed.has(entry.group))) items.push(layerRow(entry));
  }
  $('#stack').replaceChildren(...items);
  $('#groups').replaceChildren(...[...groups].map((name) => el('option', { value: name })));
  layerEntries().forEach(syncRow);
}

function groupRow(group) {
  const members = () => layerEntries().filter((entry) => entry.group === group);
  const all = (key) => members().length > 0 && members().every((entry) => entry[key]);
  const toggle = (key, word) => el('button', {
    class: `toggle ${key}`, 'aria-pressed': String(all(key)), 'aria-label': `${word} the group ${group}`,
    onclick: () => {
      const value = !all(key);
      edit(`${word.toLowerCase()} group ${group}`, (doc) => {
        for (const entry of doc.entries) if (entry.group === group) entry[key] = value;
      });
    },
  }, word);
  const folded = collapsed.has(group);
  return el('li', { class: 'group', dataset: { group } },
    el('div', { class: 'layer-head' },
      el('button', {
        class: 'fold', 'aria-expanded': String(!folded), 'aria-label': `${folded ? 'show' : 'hide'} the layers of ${group}`,
        onclick: () => { if (folded) collapsed.delete(group); else collapsed.add(group); renderStack(); },
      }, folded ? '▸' : '▾'),
      toggle('solo', 'Solo'), toggle('mute', 'Mute'),
      el('span', { class: 'group-name' }, group), el('span', { class: 'dim' }, `${members().length} layers`),
      el('button', {
        'aria-label': `ungroup ${group}`,
        onclick: () => edit(`ungroup ${group}`, (doc) => { for (const e of doc.entries) if (e.group === group) e.group = ''; },
          { structure: true }),
      }, 'Ungroup')));
}

function layerRow(entry) {
  const { id } = entry;
  const head = el('div', { class: 'layer-head' });
  const row = el('li', { dataset: { id, maskKind: entry.mask?.kind ?? '' }, class: entry.kind === 'beauty' ? 'beauty' : 'layer' }, head);
  const source = state.sources.get(entry.source);
  const share = el('span', { class: 'share', title: "share of the beauty's energy (Rec.709 luminance)" },
    shareBar(source?.share ?? 0), el('span', { class: 'percent' }, percent(source?.share ?? 0)));
  if (entry.kind === 'beauty') {
    head.append(el('span', { class: 'layer-name', title: 'what the layers leave of it stays in the composite' },
      entry.name), share);
    return row;
  }
  const toggle = (word, key) => el('button', {
    class: `toggle ${key}`, 'aria-pressed': String(entry[key]), 'aria-label': `${word} ${entry.name}`,
    title: key === 'solo' ? 'show only the soloed layers' : 'gain 0',
    onclick: () => { const e = entryById(id); setGrade(id, { [key]: !e[key] }); },
  }, word);
  head.append(toggle('Solo', 'solo'), toggle('Mute', 'mute'),
    el('span', { class: 'layer-name', title: entry.expression ? `${entry.name}: ${entry.expression}` : entry.name },
      entry.name),
    el('span', { class: 'badge', hidden: true }), el('span', { class: 'tint-value mono' }), share);
  if (entry.note) row.append(el('div', { class: 'layer-note dim' }, entry.note));
  const named = (what) => `${what} of ${entry.name}`;
  const slider = el('input', {
    type: 'range', class: 'gain', min: -10, max: 10, step: 0.05, value: entry.stops, 'aria-label': named('gain (stops)'),
    oninput: (event) => setGrade(id, { stops: Number(event.target.value) }, 'stops'),
  });
  const field = el('input', {
    type: 'number', class: 'stops', min: -30, max: 30, step: 0.1, value: entry.stops, 'aria-label': named('gain in stops'),
    oninput: (event) => event.target.value !== '' && setGrade(id, { stops: Number(event.target.value) }, 'stops'),
  });
  const colour = el('input', {
    type: 'color', class: 'tint', value: linearToHex(entry.tint), 'aria-label': named('tint (a linear RGB multiplier)'),
    oninput: (event) => setGrade(id, { tint: hexToLinear(event.target.value) }, 'tint'),
  });
  row.append(el('div', { class: 'layer-grade' }, el('span', { class: 'dim', 'aria-hidden': 'true' }, 'gain'), slider, field, colour));
  row.append(moreControls(entry));
  return row;
}

/** The rest of a layer's controls, folded: Kelvin, mask, name, group, order, copies. */
function moreControls(entry) {
  const { id } = entry;
  const named = (what) => `${what} of ${entry.name}`;
  const details = el('details', { class: 'more', open: openDetails.has(id) },
    el('summary', { 'aria-label': `more controls of ${entry.name}` }, 'more'));
  details.addEventListener('toggle', () => { if (details.open) openDetails.add(id); else openDetails.delete(id); });
  if (state.kelvin) {
    const { min, max, step } = state.kelvin;
    const kelvin = entry.kelvin ?? 6500;
    details.append(el('div', { class: 'row kelvin' },
      el('label', {}, el('input', {
        type: 'checkbox', class: 'kelvin-on', checked: entry.kelvin !== null,
        onchange: (event) => setGrade(id, { kelvin: event.target.checked ? kelvin : null }),
      }), 'colour temperature'),
      el('input', {
        type: 'range', class: 'kelvin-slider', min, max, step, value: kelvin, 'aria-label': named('colour temperature (K)'),
        oninput: (event) => setGrade(id, { kelvin: Number(event.target.value) }, 'kelvin'),
      }),
      el('input', {
        type: 'number', class: 'kelvin-value', min, max, step, value: kelvin, 'aria-label': named('colour temperature in Kelvin'),
        onchange: (event) => {
          const value = Math.round(Number(event.target.value) / step) * step;
          if (value >= min && value <= max) setGrade(id, { kelvin: value });
        },
      }), el('span', { class: 'dim', 'aria-hidden': 'true' }, 'K')));
  }
  const kinds = Object.keys(state.cryptomattes);
  if (kinds.length) {
    const kind = entry.mask?.kind ?? '';
    const names = new Set(entry.mask?.names ?? []);
    const options = kind ? state.cryptomattes[kind].names : [];
    details.append(el('div', { class: 'row mask' },
      el('label', {}, 'mask ', el('select', {
        class: 'mask-kind', 'aria-label': named('mask: the Cryptomatte it is picked from'),
        onchange: (event) => setGrade(id, { mask: event.target.value ? { kind: event.target.value, names: [] } : null }),
      }, el('option', { value: '' }, 'none'), ...kinds.map((k) => el('option', { value: k, selected: k === kind }, k)))),
      el('button', {
        class: 'pick', 'aria-pressed': String(state.picking === id), disabled: !kind,
        title: 'click objects in the image (or Enter on the keyboard cursor) to add or remove them',
        onclick: () => { state.picking = state.picking === id ? null : id; renderStack(); setStatus(state.picking ? `picking the mask of ${entry.name}: click in the image` : ''); },
      }, 'pick in image')),
    kind ? el('select', {
      class: 'mask-names', multiple: true, size: Math.min(5, Math.max(2, options.length)), 'aria-label': named(`mask: the ${kind}s`),
      onchange: (event) => setGrade(id, { mask: { kind, names: [...event.target.selectedOptions].map((o) => o.value) } }),
    }, options.map((name) => el('option', { value: name, selected: names.has(name) }, name))) : null);
  }
  const rename = el('input', {
    class: 'rename', value: entry.name, spellcheck: false, autocomplete: 'off', 'aria-label': named('name'),
    onchange: (event) => renameEntry(id, event.target),
  });
  const group = el('input', {
    class: 'group-input', value: entry.group, list: 'groups', spellcheck: false, autocomplete: 'off', placeholder: 'no group',
    'aria-label': named('group'),
    onchange: (event) => {
      const name = event.target.value.trim();
      edit(name ? `group ${entry.name} in ${name}` : `ungroup ${entry.name}`, (doc) => {
        setGroup(doc.entries, doc.entries.findIndex((e) => e.id === id), name);
      }, { structure: true });
    },
  });
  details.append(el('div', { class: 'row' }, el('label', {}, 'name ', rename), el('label', {}, 'group ', group)));
  const button = (word, action, label) => el('button', { class: word.toLowerCase().replace(/ /g, '-'), 'aria-label': label, onclick: action }, word);
  details.append(el('div', { class: 'row wrap' },
    button('Move up', () => moveBy(id, -1), `move ${entry.name} up`),
    button('Move down', () => moveBy(id, 1), `move ${entry.name} down`),
    button('Duplicate', () => duplicateEntry(id), `duplicate ${entry.name}`),
    button('Delete', () => deleteEntry(id), `delete ${entry.name}`)));
  if (entry.expression) details.append(el('div', { class: 'expression mono dim' }, entry.expression));
  return details;
}

/** Show an entry's grade in its row (the one place its controls are written). */
function syncRow(entry) {
  const row = rowOf(entry.id);
  if (!row || entry.kind === 'beauty') return;
  row.classList.toggle('muted', entry.mute);
  $('.toggle.solo', row).setAttribute('aria-pressed', String(entry.solo));
  $('.toggle.mute', row).setAttribute('aria-pressed', String(entry.mute));
  const gain = $('.gain', row);
  const field = $('.stops', row);
  if (Number(gain.value) !== entry.stops) gain.value = entry.stops;
  if (document.activeElement !== field && Number(field.value) !== entry.stops) field.value = entry.stops;
  const colour = $('.tint', row);
  if (document.activeElement !== colour) colour.value = linearToHex(entry.tint);
  const notes = [];
  if (!entry.tint.every((c) => c === 1)) notes.push(`×${entry.tint.map((c) => c.toFixed(2)).join(' ')}`);
  if (entry.kelvin !== null) notes.push(`${entry.kelvin} K`);
  if (entry.mask) notes.push(`mask: ${entry.mask.names.length} ${entry.mask.kind}s`);
  $('.tint-value', row).textContent = notes.join(' · ');
  const kelvinOn = $('.kelvin-on', row);
  if (kelvinOn) {
    kelvinOn.checked = entry.kelvin !== null;
    for (const input of [$('.kelvin-slider', row), $('.kelvin-value', row)]) {
      input.disabled = entry.kelvin === null;
      if (entry.kelvin !== null && document.activeElement !== input) input.value = entry.kelvin;
    }
  }
  if ((row.dataset.maskKind ?? '') !== (entry.mask?.kind ?? '')) {  // the row's mask controls are the other kind's
    renderStack();
    return;
  }
  const names = $('.mask-names', row);
  if (names) {
    const picked = new Set(entry.mask?.names ?? []);
    for (const option of names.options) option.selected = picked.has(option.value);
  }
  showPushable(entry, row);
}

function rowOf(id) {
  return $(`#stack li[data-id="${CSS.escape(id)}"]`);
}

function setGrade(id, change, control = null) {
  const entry = entryById(id);
  if (!entry) return;
  state.regrading = id;
  const what = Object.keys(change).join(', ');
  edit(`${what} of ${entry.name}`, (doc) => Object.assign(doc.entries.find((e) => e.id === id), change),
    { key: control ? `${id}:${control}` : null });
}

function renameEntry(id, input) {
  const entry = entryById(id);
  const name = input.value.trim();
  const problem = !LAYER_NAME.test(name) ? 'a layer name is letters, digits and _, not starting with a digit'
    : stackNames(id).has(name) ? `the stack has a layer named ${name} already` : '';
  input.setAttribute('aria-invalid', String(Boolean(problem)));
  if (problem) {
    setStatus(problem, true);
    return;
  }
  if (name !== entry.name) edit(`rename ${entry.name} to ${name}`, (doc) => { doc.entries.find((e) => e.id === id).name = name; }, { structure: true });
}

function moveBy(id, offset) {
  const at = state.doc.entries.findIndex((entry) => entry.id === id);
  const to = at + offset;
  if (to < 1 || to >= state.doc.entries.length) return;
  edit(`move ${state.doc.entries[at].name}`, (doc) => moveEntry(doc.entries, at, to), { structure: true });
  rowOf(id)?.querySelector(offset < 0 ? '.move-up' : '.move-down')?.focus();
}

function duplicateEntry(id) {
  const entry = entryById(id);
  const source = state.sources.get(entry.source);
  const grade = Object.fromEntries(GRADE_KEYS.map((key) => [key, structuredClone(entry[key])]));
  const { entry: copy, at } = entryOf(source, { ...grade, group: entry.group, name: `${entry.name}_copy`, id: `${entry.id}_copy` }, id);
  edit(`duplicate ${entry.name}`, (doc) => doc.entries.splice(at, 0, copy), { structure: true });
}

function deleteEntry(id) {
  const at = state.doc.entries.findIndex((entry) => entry.id === id);
  if (at < 1) return;
  const { name } = state.doc.entries[at];
  edit(`delete ${name}`, (doc) => doc.entries.splice(at, 1), { structure: true });
  setStatus(`deleted ${name} (Ctrl+Z brings it back)`);
  const next = state.doc.entries[Math.min(at, state.doc.entries.length - 1)];
  (rowOf(next.id)?.querySelector('button') ?? $('#reset')).focus();
}

/** Every layer back to the grade it opened with (the recipe's, the saved look's), exposure 0. */
function resetGrades() {
  edit('reset grades', (doc) => {
    doc.exposure = 0;
    for (const entry of doc.entries) {
      const source = state.sources.get(entry.source);
      Object.assign(entry, { stops: source?.exposure ?? 0, tint: [...(source?.tint ?? [1, 1, 1])], kelvin: null,
        mute: false, solo: false, mask: null });
    }
  });
}

/** Fetch the masks the entries use that the page does not hold yet. */
function ensureMasks() {
  const used = [state.doc.entries, ...state.doc.snapshots.map((s) => s.entries), state.doc.saved?.entries ?? []].flat();
  for (const entry of used) {
    if (!entry.mask || !entry.mask.names.length) continue;
    const key = maskKey(entry.mask);
    if (state.masks.has(key)) continue;
    const slot = { pending: true, slice: -1 };
    state.masks.set(key, slot);
    fetchMask(entry.mask, state.width, state.height).then((data) => {
      slot.slice = [...state.masks.values()].filter((m) => m.slice >= 0).length;
      slot.data = data;
      slot.pending = false;
      renderer.setMask(slot.slice, data, state.width, state.height);
      requestDraw();
    }).catch((error) => {
      state.masks.delete(key);
      setStatus(`mask of ${entry.name}: ${error.message}`, true);
    });
  }
}

/** A click in the image while picking: the name under it joins (or leaves) the entry's mask. */
async function pickMaskName(x, y) {
  const entry = entryById(state.picking);
  if (!entry?.mask) return;
  try {
    const reply = await api(`/api/pick?${new URLSearchParams({ x, y })}`);
    const found = reply[entry.mask.kind] ?? [];
    if (!found.length) {
      setStatus(`no ${entry.mask.kind} at ${x}, ${y}`);
      return;
    }
    const { name } = found[0];
    const names = new Set(entry.mask.names);
    if (names.has(name)) names.delete(name); else names.add(name);
    setGrade(entry.id, { mask: { kind: entry.mask.kind, names: [...names].sort() } });
    setStatus(`${entry.name}'s mask: ${names.has(name) ? 'added' : 'removed'} ${name}`);
  } catch (error) {
    setStatus(`pick: ${error.message}`, true);
  }
}

// --- snapshots and comparing --------------------------------------------------------------

function takeSnapshot() {
  const number = state.doc.snapshots.length + 1;
  edit(`snapshot ${number}`, (doc) => doc.snapshots.push(snapshotOf(doc, `snapshot ${number}`)), { structure: true });
  setStatus(`snapshot ${number} taken: compare against it, or restore it`);
}

function restoreLook(look, label) {
  edit(`restore ${label}`, (doc) => {
    doc.exposure = look.exposure;
    doc.entries = [doc.entries[0], ...look.entries.filter((entry) => state.sources.has(entry.source)).map((e) => structuredClone(e))];
  }, { structure: true });
}

function setCompare(change) {
  Object.assign(state.doc.compare, change);
  syncCompare();
  if ('mode' in change) {
    if (state.view.fit) fit(); else restoreView();
  }
  schedulePersist();
  requestDraw();
}

/** The compare controls and the snapshots' list, from the document. */
function syncCompare() {
  const { mode, against } = state.doc.compare;
  const choices = [['beauty', 'the raw beauty']];
  if (state.doc.saved) choices.push(['saved', `the saved look (${state.doc.saved.name})`]);
  state.doc.snapshots.forEach((snapshot, at) => choices.push([`snapshot:${at}`, snapshot.name]));
  const select = $('#compare-against');
  select.replaceChildren(...choices.map(([value, text]) => el('option', { value, selected: value === against }, text)));
  if (!choices.some(([value]) => value === against)) state.doc.compare.against = 'beauty';
  $('#compare-mode').value = mode;
  $('#viewer').dataset.compare = mode;
  placeWipe();
  $('#snapshots').replaceChildren(...state.doc.snapshots.map((snapshot, at) => el('li', {},
    el('span', { class: 'snapshot-name' }, snapshot.name),
    el('button', { 'aria-label': `compare against ${snapshot.name}`, onclick: () => setCompare({ against: `snapshot:${at}`, mode: mode === 'one' ? 'wipe' : mode }) }, 'Compare'),
    el('button', { 'aria-label': `restore ${snapshot.name}`, onclick: () => restoreLook(snapshot, snapshot.name) }, 'Restore'),
    el('button', {
      'aria-label': `delete ${snapshot.name}`,
      onclick: () => edit(`delete ${snapshot.name}`, (doc) => {
        doc.snapshots.splice(at, 1);
        doc.compare.against = 'beauty';
      }, { structure: true }),
    }, 'Delete'))));
}

// --- warnings: overlapping layers, which grades a light edit can carry ----------------------

let checksTimer = 0;
const CHECKS_DELAY_MS = 500;

function scheduleChecks(structure) {
  clearTimeout(checksTimer);
  checksTimer = setTimeout(() => runChecks(structure), CHECKS_DELAY_MS);
}

let checkedStructure = '';

async function runChecks(structure) {
  if (!state.index) return;
  const stack = layerEntries();
  const key = JSON.stringify(stack.map((entry) => [entry.source, entry.expression, entry.mute]));
  const work = [checkPushable(stack)];
  if (structure || key !== checkedStructure) {
    checkedStructure = key;
    work.push(checkOverlaps(stack));
  }
  await Promise.all(work);
}

/** Which grades a light edit carries (POST /api/pushable): a badge on each row. */
async function checkPushable(stack) {
  try {
    const reply = await api('/api/pushable', { method: 'POST', body: { layers: stack.map(savedEntry), exposure: state.doc.exposure } });
    state.pushable = new Map([
      ...(reply.pushed ?? []).map((item) => [item.layer, { light: item.light, edits: item.edits }]),
      ...(reply.compositing ?? []).map((item) => [item.layer, { why: item.why }]),
    ]);
  } catch (error) {
    state.pushable = new Map();
    if (error.status !== 404) setStatus(`which grades are light edits: ${error.message}`, true);
  }
  layerEntries().forEach((entry) => { const row = rowOf(entry.id); if (row) showPushable(entry, row); });
}

function showPushable(entry, row) {
  const badge = $('.badge', row);
  const verdict = state.pushable.get(entry.name);
  badge.hidden = !verdict;
  if (!verdict) return;
  badge.classList.toggle('light', Boolean(verdict.light));
  badge.textContent = verdict.light ? 'light' : 'comp';
  const text = verdict.light ? `a light edit: pushed to ${verdict.light}` : `a compositing grade: ${verdict.why}`;
  badge.title = text;
  badge.setAttribute('aria-label', text);
}

/** Layers that claim the same paths (POST /api/overlaps): a warning with what to do. */
async function checkOverlaps(stack) {
  const box = $('#overlaps');
  const layers = stack.filter((entry) => !entry.mute).map((entry) => ({ id: entry.name, expression: entry.expression }));
  if (layers.length < 2) {
    box.hidden = true;
    return;
  }
  try {
    state.overlaps = await api('/api/overlaps', { method: 'POST', body: { layers } });
  } catch (error) {
    box.hidden = true;
    if (error.status !== 404) setStatus(`overlaps: ${error.message}`, true);
    return;
  }
  renderOverlaps();
}

function renderOverlaps() {
  const box = $('#overlaps');
  const reply = state.overlaps;
  const pairs = (reply?.pairs ?? []).filter((pair) => pair.share > 0);
  box.hidden = !pairs.length;
  if (!pairs.length) return;
  box.replaceChildren(...[
    el('p', {}, `these layers claim the same light paths: ${percent(reply.double_counted ?? 0)} of the beauty is counted twice in their sum`),
    el('ul', {}, pairs.map((pair) => el('li', {}, `${pair.a} and ${pair.b}: ${percent(pair.share)}`,
      reply.exclusive?.[pair.b] ? el('button', {
        'aria-label': `make ${pair.b} leave out what ${pair.a} claims`,
        onclick: () => makeLayer(`${pair.b}_only`, reply.exclusive[pair.b], { replace: pair.b }),
      }, `${pair.b} without ${pair.a}`) : null))),
    reply.remainder_expression ? el('button', {
      onclick: () => makeLayer('remainder', reply.remainder_expression),
    }, `add the remainder (${percent(reply.remainder ?? 0)})`) : null,
  ].filter(Boolean));
}

// --- inspect ------------------------------------------------------------------------------

let inspecting = null;  // AbortController of the request in flight

async function inspect(rect) {
  state.selection = rect;
  placeSelection();
  const { x0, y0, x1, y1 } = rect;
  const single = x1 - x0 === 1 && y1 - y0 === 1;
  $('#selection-info').textContent = single
    ? `pixel ${x0}, ${y0}` : `region ${x0}, ${y0} – ${x1 - 1}, ${y1 - 1} (${(x1 - x0) * (y1 - y0)} px)`;
  if (!state.index) {
    $('#tab-body').replaceChildren(el('div', { class: 'empty' }, 'this product has no path index beside it: nothing to inspect'));
    return;
  }
  inspecting?.abort();
  inspecting = new AbortController();
  $('#selection-summary').textContent = 'reading the index…';
  try {
    const reply = await api(`/api/inspect?${new URLSearchParams({ x0, y0, x1, y1 })}`, { signal: inspecting.signal });
    state.inspection = reply;
    state.picked.clear();
    renderInspection();
  } catch (error) {
    if (error.name === 'AbortError') return;
    $('#selection-summary').textContent = '';
    setStatus(`inspect: ${error.message}`, true);
  }
}

function renderInspection() {
  const reply = state.inspection;
  if (!reply) return;
  const rgb = reply.rgb ?? [0, 0, 0];
  $('#selection-summary').replaceChildren(
    el('span', {}, `${reply.records.toLocaleString()} records`),
    el('span', {}, `energy ${number(reply.energy)}`),
    el('span', { class: 'mono' }, `rgb ${rgb.map((v) => number(v)).join(' ')}`),
    el('span', {}, `${reply.classes.length} classes listed`),
  );
  showTab(state.tab);
}

function showTab(tab) {
  state.tab = tab;
  for (const button of document.querySelectorAll('#tabs button')) {
    button.setAttribute('aria-selected', String(button.dataset.tab === tab));
  }
  const body = $('#tab-body');
  const reply = state.inspection;
  if (!reply) {
    body.replaceChildren(el('div', { class: 'empty' }, state.index
      ? 'click a pixel or drag a region of the image'
      : 'this product has no path index beside it: nothing to inspect'));
    return;
  }
  if (tab === 'classes') body.replaceChildren(classTable(reply.classes));
  else if (tab === 'norms') renderNorms(body, reply.norms);
  else body.replaceChildren(groupTable(reply.groups?.[tab] ?? []));
}

function useExpression(lpe) {
  $('#expression').value = lpe;
  scheduleCheck();
}

function classTable(classes) {
  if (!classes.length) return el('div', { class: 'empty' }, 'no light paths reach this selection');
  return el('table', { class: 'entries classes' }, classes.map((entry) => el('tr', {
    dataset: { class: entry.id, path: entry.path, share: entry.share, records: entry.records },
  },
  el('td', { class: 'pick' }, el('input', {
    type: 'checkbox', checked: state.picked.has(entry.id), title: 'tick classes, then generalise',
    dataset: { class: entry.id },
    onchange: (event) => (event.target.checked ? state.picked.add(entry.id) : state.picked.delete(entry.id)),
  })),
  el('td', { class: 'amount', title: "share of the selection's energy" },
    el('span', { class: 'percent' }, percent(entry.share)), shareBar(entry.share)),
  el('td', {}, el('div', { class: 'path' }, entry.path), el('div', { class: 'lpe' }, entry.lpe)),
  el('td', { class: 'count', title: 'records' }, entry.records.toLocaleString()),
  el('td', { class: 'use' }, el('button', { title: 'put this expression in the field below', onclick: () => useExpression(entry.lpe) }, 'use')))));
}

function groupTable(groups) {
  if (!groups.length) return el('div', { class: 'empty' }, 'nothing in this selection');
  return el('table', { class: 'entries groups' }, groups.map((group) => el('tr', {
    dataset: { key: group.key, share: group.share },
  },
  el('td', { class: 'amount' }, el('span', { class: 'percent' }, percent(group.share)), shareBar(group.share)),
  el('td', {}, el('div', { class: 'path' }, group.key), el('div', { class: 'lpe' }, group.lpe)),
  el('td', { class: 'count', title: 'records' }, group.records.toLocaleString()),
  el('td', { class: 'use' }, el('button', { onclick: () => useExpression(group.lpe) }, 'use')))));
}

// --- covariance norm histograms -----------------------------------------------------------

const NORM_UNITS = { C: '1/m', T: 'cycles/m', R: 'cycles/rad' };

/** Each bounce's C, T, R histograms (energy-weighted). `edges` are the bins' bounds (norm
 *  values, powers of 2); the zero bar (orange, left, apart) is the energy of exactly-zero
 *  norms, often most of it: the bins are scaled to the tallest bin, the zero bar to the same
 *  scale but capped, and its share is written under it. Only the span of bins holding energy is drawn, the same for every bounce of a
 *  quantity so that the rows line up. A click on a bin puts its lower edge as a minimum in
 *  that bounce's row of the query builder; shift-click its upper edge as a maximum; a click
 *  on the zero bar, "= 0". */
function renderNorms(body, norms) {
  const bounces = norms?.bounces ?? [];
  if (!bounces.length) {
    body.replaceChildren(el('div', { class: 'empty' }, 'no covariance norms in this selection'));
    return;
  }
  const { edges } = norms;
  const span = {};
  for (const quantity of ['C', 'T', 'R']) {
    const used = bounces.flatMap((entry) => (entry[quantity] ?? []).flatMap((w, bin) => (w > 0 ? [bin] : [])));
    span[quantity] = used.length ? [Math.min(...used), Math.max(...used) + 1] : [0, 0];
  }
  const grid = el('div', { class: 'norms' },
    el('span'), ...['C', 'T', 'R'].map((q) => el('span', { class: 'head' }, `|Σ_${q}| ${NORM_UNITS[q]}`)));
  const pending = [];
  for (const entry of bounces) {
    grid.append(el('span', { class: 'dim' }, `bounce ${entry.bounce}`));
    for (const quantity of ['C', 'T', 'R']) {
      const [low, high] = span[quantity];
      const histogram = el('canvas', { dataset: { bounce: entry.bounce, quantity } });
      const weights = entry[quantity] ?? [];
      const total = weights.reduce((sum, w) => sum + w, entry.zero?.[quantity] ?? 0);
      const zeroShare = total > 0 ? percent((entry.zero?.[quantity] ?? 0) / total) : '–';
      grid.append(el('div', {}, histogram, el('div', { class: 'norms-axis' },
        el('span', { class: 'zero', title: 'energy at exactly 0' }, `=0 ${zeroShare}`),
        high > low ? el('span', {}, `${number(edges[low])}…${number(edges[high])}`) : null)));
      pending.push([histogram, entry, quantity, low, high]);
    }
  }
  grid.append(el('div', { class: 'norms-help' },
    'fraction of the energy through each bounce by norm; click a bin: "≥ its lower edge" in the query builder, shift-click: "< its upper edge", the zero bar: "= 0"'));
  body.replaceChildren(grid);
  for (const args of pending) drawHistogram(edges, ...args);
}

const ZERO_BAR = 2;  // bar widths the zero bar and its gap take, at the left
const MIN_SLOTS = 16;  // bar widths of a histogram at least, so that a lone bar is not a wall

function drawHistogram(edges, histogram, entry, quantity, low, high) {
  const ratio = dpr();
  const width = Math.max(1, Math.round(histogram.clientWidth * ratio));
  const height = Math.max(1, Math.round(histogram.clientHeight * ratio));
  histogram.width = width;
  histogram.height = height;
  const all = entry[quantity] ?? [];
  const weights = all.slice(low, high);
  const zero = entry.zero?.[quantity] ?? 0;
  const total = all.reduce((sum, w) => sum + w, zero);
  const tallest = Math.max(...weights, 0) || zero || 1;
  const step = width / Math.max(weights.length + ZERO_BAR, MIN_SLOTS);
  const context = histogram.getContext('2d');
  const bar = (slot, weight, colour) => {
    const h = weight > 0 ? Math.max(1, Math.min(1, weight / tallest) * (height - 2)) : 0;
    context.fillStyle = colour;
    context.fillRect(slot * step, height - h, Math.max(1, step - (step > 3 ? 1 : 0)), h);
  };
  bar(0, zero, '#e8a33d');
  weights.forEach((weight, bin) => bar(bin + ZERO_BAR, weight, '#5f8fd0'));
  const binAt = (event) => {
    const slot = Math.floor((event.offsetX * ratio) / step);
    return slot < ZERO_BAR ? -1 : low + slot - ZERO_BAR;  // -1: the zero bar
  };
  const fraction = (w) => (total > 0 ? percent(w / total) : '–');
  histogram.addEventListener('mousemove', (event) => {
    const bin = binAt(event);
    if (bin < 0) histogram.title = `|Σ_${quantity}| = 0: ${fraction(zero)} of bounce ${entry.bounce}'s energy`;
    else if (bin < high) {
      histogram.title = `|Σ_${quantity}| in [${number(edges[bin])}, ${number(edges[bin + 1])}) ${NORM_UNITS[quantity]}: `
        + `${fraction(all[bin])} of bounce ${entry.bounce}'s energy`;
    }
  });
  histogram.addEventListener('click', (event) => {
    const bin = binAt(event);
    if (bin < 0) pickThreshold(entry.bounce, quantity, { min: '', max: '0' });
    else if (bin < high) {
      pickThreshold(entry.bounce, quantity, event.shiftKey ? { max: number(edges[bin + 1]) } : { min: number(edges[bin]) });
    }
  });
}

// --- make a layer: generalise, the query builder, the expression --------------------------

// The bounce types and scatterings come from the server (/api/session's alphabet: the one
// event alphabet of pxr_layers/paths/events.py), as [letter, shown label] after 'any'.
const EVENT_TYPES = [['.', 'any']];
const SCATTERINGS = [['.', 'any']];
const REPEATS = [['', '×1'], ['?', '0–1'], ['*', '0+'], ['+', '1+']];

function newBounce() {
  return { type: '.', scatter: '.', label: '', repeat: '', C: { min: '', max: '' }, T: { min: '', max: '' }, R: { min: '', max: '' } };
}

/** One event of the expression: as compact as the syntax allows (docs/lpe.md, "Meaning"). */
function eventText(type, scatter, label) {
  if (label) return `<${type}${scatter}'${label}'>`;
  if (scatter === '.') return type;
  if (type === '.') return scatter;
  return `<${type}${scatter}>`;
}

/** The covariance condition of a bounce row: min is "≥", max "<", a max of 0 "= 0". */
function conditionText(row) {
  const terms = [];
  for (const quantity of ['C', 'T', 'R']) {
    const { min, max } = row[quantity];
    if (max !== '' && Number(max) === 0) {
      terms.push(`|S_${quantity}| = 0`);
      continue;
    }
    if (min !== '') terms.push(`|S_${quantity}| >= ${Number(min)}`);
    if (max !== '') terms.push(`|S_${quantity}| < ${Number(max)}`);
  }
  return terms.length ? `@(${terms.join(' and ')})` : '';
}

function builderText() {
  const { rows, anyAfter } = state.builder;
  const bounces = rows.map((row) => eventText(row.type, row.scatter, row.label.trim()) + conditionText(row) + row.repeat);
  const endType = $('#end-type').value;
  const endLabel = $('#end-label').value.trim();
  const end = endLabel ? `<${endType}.'${endLabel}'>` : endType;
  return `C${bounces.join('')}${anyAfter ? '.*' : ''}${end}`;
}

function builderChanged() {
  useExpression(builderText());
}

function options(choices, selected) {
  return choices.map(([value, text]) => el('option', { value, selected: value === selected }, text));
}

function renderBuilder() {
  const rows = state.builder.rows.map((row, at) => {
    const change = (key) => (event) => { row[key] = event.target.value; builderChanged(); };
    const range = (quantity) => el('span', { class: 'range', title: `|Σ_${quantity}| (${NORM_UNITS[quantity]}): ≥ min, < max; max 0: = 0` },
      quantity,
      el('input', { type: 'number', min: 0, step: 'any', placeholder: '≥', value: row[quantity].min, dataset: { quantity, bound: 'min' },
        oninput: (event) => { row[quantity].min = event.target.value; builderChanged(); } }),
      el('input', { type: 'number', min: 0, step: 'any', placeholder: '<', value: row[quantity].max, dataset: { quantity, bound: 'max' },
        oninput: (event) => { row[quantity].max = event.target.value; builderChanged(); } }));
    return el('div', { class: 'bounce', dataset: { bounce: at + 1 } },
      el('span', { class: 'index', title: 'bounce, camera first' }, String(at + 1)),
      el('select', { title: 'event type', onchange: change('type') }, options(EVENT_TYPES, row.type)),
      el('select', { title: 'scattering', onchange: change('scatter') }, options(SCATTERINGS, row.scatter)),
      el('input', { class: 'label-input', list: 'labels', placeholder: 'any label', value: row.label, title: "a label of the index (object, material, path, lobe); a glob: '/World/*'",
        oninput: change('label') }),
      el('select', { title: 'repetition', onchange: change('repeat') }, options(REPEATS, row.repeat)),
      el('button', { title: 'remove this bounce', onclick: () => { state.builder.rows.splice(at, 1); renderBuilder(); builderChanged(); } }, '×'),
      el('div', { class: 'ranges' }, range('C'), range('T'), range('R')));
  });
  rows.push(el('label', { class: 'row dim' }, el('input', {
    type: 'checkbox', checked: state.builder.anyAfter, id: 'any-after',
    onchange: (event) => { state.builder.anyAfter = event.target.checked; builderChanged(); },
  }), 'then any further bounces (.*)'));
  $('#builder').replaceChildren(...rows);
}

/** A histogram click: a bound on bounce `bounce`'s norm, in that row of the builder. */
function pickThreshold(bounce, quantity, bounds) {
  while (state.builder.rows.length < bounce) state.builder.rows.push(newBounce());
  Object.assign(state.builder.rows[bounce - 1][quantity], bounds);
  $('#builder-box').open = true;
  renderBuilder();
  builderChanged();
}

function setupBuilder() {
  $('#add-bounce').addEventListener('click', () => {
    state.builder.rows.push(newBounce());
    renderBuilder();
    builderChanged();
  });
  $('#end-type').addEventListener('change', builderChanged);
  $('#end-label').addEventListener('input', builderChanged);
  renderBuilder();
}

let checkTimer = 0;
let checkSequence = 0;

function scheduleCheck() {
  clearTimeout(checkTimer);
  checkTimer = setTimeout(checkExpression, 150);
}

function showExpressionError(text, message, position) {
  const box = $('#expression-error');
  box.hidden = false;
  box.classList.remove('ok');
  if (Number.isInteger(position)) {
    box.textContent = `${text}\n${' '.repeat(Math.min(position, text.length))}^\n${message}`;
  } else {
    box.textContent = message;
  }
}

async function checkExpression() {
  const text = $('#expression').value;
  const box = $('#expression-error');
  if (!text.trim()) {
    box.hidden = true;
    return true;
  }
  const sequence = ++checkSequence;
  try {
    const reply = await api('/api/check', { method: 'POST', body: { expression: text } });
    if (sequence !== checkSequence) return reply.ok;
    if (reply.ok) {
      box.hidden = false;
      box.classList.add('ok');
      box.textContent = 'valid expression';
      showUnknownLabels(box, text, reply.unknown_labels);
    } else {
      showExpressionError(text, reply.error, reply.position);
    }
    return reply.ok;
  } catch (error) {
    if (sequence === checkSequence) showExpressionError(text, error.message, error.position);
    return false;
  }
}

async function generalise() {
  const classes = [...state.picked];
  if (!classes.length) {
    setStatus('tick one or more classes in the inspect panel first', true);
    return;
  }
  const keep = [...document.querySelectorAll('#keep input:checked')].map((box) => box.value);
  try {
    const reply = await api('/api/generalise', { method: 'POST', body: { classes, keep } });
    useExpression(reply.lpe);
  } catch (error) {
    setStatus(`generalise: ${error.message}`, true);
  }
}


/** Labels of an expression that name nothing in the index, with the nearest names present. */
function showUnknownLabels(box, text, unknown) {
  if (!unknown?.length) return;
  box.classList.remove('ok');
  box.textContent = '';
  for (const { label, nearest } of unknown) {
    box.append(el('div', {}, `no '${label}' in this index`,
      nearest?.length ? ': did you mean ' : '',
      ...(nearest ?? []).slice(0, 3).map((name) => el('button', {
        class: 'nearest', 'aria-label': `use ${name} for ${label}`,
        onclick: () => useExpression(text.replaceAll(`'${label}'`, `'${name}'`)),
      }, name))));
  }
}

function freeLayerName() {
  const taken = new Set([...stackNames(), ...state.sources.keys()]);
  let n = 1;
  while (taken.has(`layer_${n}`)) n += 1;
  return `layer_${n}`;
}

const timings = { layer: null };  // the last "add layer": milliseconds from the click
let confirmedUnknown = null;  // an expression with unknown labels the user was told of once

/** Extract a layer from the index (POST /api/layer) and put it in the stack (one undo step);
 *  `replace`: the entry of that name gives its place and grade, and leaves. */
async function makeLayer(name, expression, { replace = null, solo = false } = {}) {
  const start = performance.now();
  const made = await api('/api/layer', { method: 'POST', body: { name: freeName(name, new Set(state.sources.keys())), expression } });
  const extracted = performance.now();
  const source = addSource({ kind: 'layer', ...made });
  await loadSource(source);
  const fetched = performance.now();
  const old = replace ? state.doc.entries.find((entry) => entry.name === replace) : null;
  const grade = old ? Object.fromEntries(GRADE_KEYS.map((key) => [key, structuredClone(old[key])])) : {};
  const { entry, at } = entryOf(source, { ...grade, group: old?.group ?? '', name }, old?.id ?? null);
  edit(old ? `${name} in place of ${replace}` : `add ${name}`, (doc) => {
    doc.entries.splice(at, 0, entry);
    if (old) doc.entries.splice(doc.entries.findIndex((e) => e.id === old.id), 1);
    if (solo) for (const other of doc.entries) other.solo = other.id === entry.id;
  }, { structure: true });
  return { made, entry, start, extracted, fetched };
}

async function addLayer() {
  const name = $('#layer-name').value.trim() || freeLayerName();
  const expression = $('#expression').value.trim();
  const status = $('#layer-status');
  status.classList.remove('error');
  const refuse = (text) => { status.textContent = text; status.classList.add('error'); };
  if (!LAYER_NAME.test(name)) return refuse('a layer name is letters, digits and _, not starting with a digit');
  if (stackNames().has(name)) return refuse(`the stack already has a layer named ${name}`);
  if (!expression) return refuse('write an expression first (or generalise ticked classes, or use the query builder)');
  // A label that names nothing in the index (a typo) would make an empty layer: say so, with
  // the nearest names, and add it only when asked again.
  if (confirmedUnknown !== expression) {
    const checked = await api('/api/check', { method: 'POST', body: { expression } }).catch(() => null);
    if (checked?.unknown_labels?.length) {
      confirmedUnknown = expression;
      const box = $('#expression-error');
      box.hidden = false;
      showUnknownLabels(box, expression, checked.unknown_labels);
      return refuse(`not added: ${checked.unknown_labels.map((u) => `'${u.label}'`).join(', ')} names nothing in this index, `
        + 'so the layer would be empty (add layer again to add it anyway)');
    }
  }
  const button = $('#add-layer');
  button.disabled = true;
  status.textContent = `extracting ${name}…`;
  try {
    const { made, start, extracted, fetched } = await makeLayer(name, expression, { solo: $('#solo-new').checked });
    const shown = await nextFrame();
    timings.layer = {
      name, extract: extracted - start, fetch: fetched - extracted, show: shown - fetched, total: shown - start,
      server_seconds: made.seconds,
    };
    const matched = made.classes === undefined ? '' : `${made.classes.toLocaleString()} path classes, `;
    status.textContent = `${name}: ${percent(made.share ?? 0)} of the energy, ${matched}`
      + `extracted in ${number(made.seconds ?? NaN)} s, on screen ${((shown - start) / 1000).toFixed(2)} s after the click`;
    if (made.unknown_labels?.length || made.warnings?.length) {
      status.classList.add('error');
      status.textContent += ` · ${made.warnings?.[0] ?? 'a label names nothing in the index'}`;
      showUnknownLabels($('#expression-error'), expression, made.unknown_labels);
      $('#expression-error').hidden = false;
    }
    $('#layer-name').value = '';
    $('#layer-name').placeholder = freeLayerName();
  } catch (error) {
    if (Number.isInteger(error.position)) showExpressionError(expression, error.message, error.position);
    refuse(`not added: ${error.message}`);
  } finally {
    button.disabled = false;
  }
}

/** Layers found automatically (POST /api/suggest): K layers (K empty: as many as the search's
 * objective finds worth it) that partition the beauty, less those the stack has already,
 * added at unit gain (the picture does not change until they are regraded), each with its
 * one-line explanation. */
async function suggestLayers() {
  const text = $('#suggest-k').value.trim();
  const k = text === '' ? null : Number(text);
  const status = $('#suggest-status');
  const button = $('#suggest');
  button.disabled = true;
  status.textContent = k === null ? 'finding layers…' : `finding ${k} layers…`;
  try {
    const exclude = [...new Set(layerEntries().map((entry) => entry.expression).filter(Boolean))];
    const found = await api('/api/suggest', { method: 'POST', body: { k, exclude } });
    const sources = found.layers.map((layer) => addSource({ kind: 'layer', ...layer }));
    await Promise.all(sources.map(loadSource));
    const entries = sources.map((source) => entryOf(source, { note: found.explanations?.[source.id] ?? '' }).entry);
    edit(`suggest ${entries.length} layers`, (doc) => doc.entries.push(...entries), { structure: true });
    const already = Object.keys(found.already ?? {}).length;
    status.textContent = `${found.layers.length} layers${found.chosen_k === 'elbow' ? ' (K by the elbow)' : ''} in `
      + `${number(found.seconds)} s${already ? `; ${already} the stack has already, not added again` : ''}`;
    timings.suggest = { layers: entries.map((entry) => entry.id), server_seconds: found.seconds };
  } catch (error) {
    status.textContent = `not suggested: ${error.message}`;
  } finally {
    button.disabled = false;
  }
}

function setupMake() {
  $('#suggest').addEventListener('click', suggestLayers);
  $('#generalise').addEventListener('click', generalise);
  $('#expression').addEventListener('input', scheduleCheck);
  $('#expression').addEventListener('keydown', (event) => { if (event.key === 'Enter') addLayer(); });
  $('#layer-name').addEventListener('keydown', (event) => { if (event.key === 'Enter') addLayer(); });
  $('#add-layer').addEventListener('click', addLayer);
  for (const button of document.querySelectorAll('#tabs button')) {
    button.addEventListener('click', () => showTab(button.dataset.tab));
  }
  setupBuilder();
}

// --- save, push -----------------------------------------------------------------------------

/** An entry as /api/save, /api/push and /api/pushable take it. */
function savedEntry({ source, name, group, note, stops, tint, kelvin, mute, solo, mask }) {
  return { id: source, name, group, note, stops, tint, kelvin, mute, solo, mask };
}

function lookName(list) {
  const name = $('#save-name').value.trim();
  if (LOOK_NAME.test(name)) return name;
  list.replaceChildren(el('li', { class: 'error' }, 'a look name is letters, digits, _ and -, not starting with a digit'));
  $('#save-name').setAttribute('aria-invalid', 'true');
  $('#save-name').focus();
  return null;
}

const fileLink = (file) => el('a', { href: `/files/${encodeURIComponent(file)}?token=${encodeURIComponent(TOKEN)}`, download: file }, file);

async function save() {
  const list = $('#saved');
  const name = lookName(list);
  if (!name) return;
  $('#save-name').setAttribute('aria-invalid', 'false');
  const entries = layerEntries();
  const body = {
    name, exposure: state.doc.exposure, overwrite: $('#overwrite').checked, layers: entries.map(savedEntry), document: state.doc,
  };
  const button = $('#save');
  button.disabled = true;
  list.replaceChildren(el('li', { class: 'dim' }, 'writing…'));
  try {
    const written = await api('/api/save', { method: 'POST', body });
    list.replaceChildren(...Object.entries(written).map(([what, file]) => el('li', { dataset: { kind: what } }, fileLink(file))));
    state.doc.saved = { name, exposure: state.doc.exposure, entries: structuredClone(entries) };
    syncCompare();
    persistNow();
  } catch (error) {
    const hint = error.status === 409 ? ' (tick overwrite to replace it)' : '';
    list.replaceChildren(el('li', { class: 'error' }, `${error.message}${hint}`));
  } finally {
    button.disabled = false;
  }
}

/** The grades a light edit can carry, as a USD override layer on the shot's lights. */
async function push() {
  const list = $('#saved');
  const name = lookName(list);
  if (!name) return;
  const button = $('#push');
  button.disabled = true;
  list.replaceChildren(el('li', { class: 'dim' }, 'writing the light edits…'));
  try {
    const reply = await api('/api/push', {
      method: 'POST', body: { name, layers: layerEntries().map(savedEntry), exposure: state.doc.exposure, overwrite: $('#overwrite').checked },
    });
    list.replaceChildren(
      ...Object.entries(reply.files ?? {}).map(([what, file]) => el('li', { dataset: { kind: what } }, fileLink(file))),
      ...(reply.pushed ?? []).map((item) => el('li', { class: 'pushed' }, `${item.layer} → ${item.light}`)),
      ...(reply.compositing ?? []).map((item) => el('li', { class: 'compositing' }, `${item.layer} stays a compositing grade: ${item.why}`)),
      ...(reply.notes ?? []).map((note) => el('li', { class: 'compositing' }, note)));
  } catch (error) {
    list.replaceChildren(el('li', { class: 'error' }, error.message));
  } finally {
    button.disabled = false;
  }
}

// --- keyboard -------------------------------------------------------------------------------

const SHORTCUTS = [
  ['Ctrl+Z', 'undo'], ['Ctrl+Shift+Z or Ctrl+Y', 'redo'], ['f', 'fit the image in the view'],
  ['1', 'one image pixel per screen pixel'], ['r', 'reset the grades to those the stack opened with'],
  ['d', 'the denoised stack, or the stack as rendered'], ['c', 'compare: one look, wipe, side by side'],
  ['s', 'take a snapshot'], ['?', 'this help'],
  ['Tab on the image, then arrows', 'move the pixel cursor (Shift: 10 pixels)'],
  ['Enter on the image', 'list the light paths of the cursor pixel (or pick its mask name)'],
  ['+ and − on the image', 'zoom around the cursor'], ['arrows on the wipe line', 'move the wipe'],
  ['wheel, middle drag or Space + drag', 'zoom and pan'], ['drag on the image', 'the light paths of a region'],
];

function setupHelp() {
  $('#help-keys').replaceChildren(...SHORTCUTS.flatMap(([keys, what]) => [el('dt', {}, keys), el('dd', {}, what)]));
  $('#help-button').addEventListener('click', () => $('#help').showModal());
  $('#help-close').addEventListener('click', () => $('#help').close());
}

const COMPARE_ORDER = ['one', 'wipe', 'side'];

function setupKeyboard() {
  const typing = (target) => target.matches?.('input:not([type=range]):not([type=checkbox]):not([type=color]), select, textarea');
  addEventListener('keydown', (event) => {
    if ((event.ctrlKey || event.metaKey) && !event.altKey && !typing(event.target)) {
      const key = event.key.toLowerCase();
      if (key === 'z' && !event.shiftKey) undo();
      else if ((key === 'z' && event.shiftKey) || key === 'y') redo();
      else return;
      event.preventDefault();
      return;
    }
    if (event.ctrlKey || event.metaKey || event.altKey || typing(event.target)) return;
    if ($('#help').open) return;
    if (event.key === ' ' && !event.target.matches?.('button, summary, input')) {
      event.preventDefault();
      spaceHeld = true;
      $('#viewer').classList.add('panning');
    } else if (event.key === 'f') fit();
    else if (event.key === '1') oneToOne();
    else if (event.key === 'r') resetGrades();
    else if (event.key === 'd') setDenoised(!state.doc.denoised);
    else if (event.key === 'c') setCompare({ mode: COMPARE_ORDER[(COMPARE_ORDER.indexOf(state.doc.compare.mode) + 1) % 3] });
    else if (event.key === 's') takeSnapshot();
    else if (event.key === '?') $('#help').showModal();
  });
  addEventListener('keyup', (event) => {
    if (event.key === ' ') {
      spaceHeld = false;
      $('#viewer').classList.remove('panning');
    }
  });
  addEventListener('blur', () => { spaceHeld = false; $('#viewer').classList.remove('panning'); });
  addEventListener('pagehide', () => { if (persistTimer) persistNow({ keepalive: true }); });
}

// --- start ----------------------------------------------------------------------------------

function fillDatalist(list, labels) {
  list.replaceChildren(...labels.map((label) => el('option', { value: label })));
}

/** Show the denoised twins' stack (on) or the stack as rendered: every image fetched again,
 * the grades kept. */
async function setDenoised(on) {
  const button = $('#denoised');
  if (button.hidden || state.doc.denoised === on) return;
  state.doc.denoised = on;
  schedulePersist();
  button.setAttribute('aria-pressed', String(on));
  button.disabled = true;
  try {
    await Promise.all([...state.sources.values()].map(loadSource));
    setStatus(on ? 'the denoised stack' : 'the stack as rendered');
  } catch (error) {
    setStatus(error.message, true);
  } finally {
    button.disabled = false;
    requestDraw();
  }
}

/** Use a display transform (/api/display's answer): its GLSL in the shader, its table in the LUT. */
async function showDisplay(display) {
  const table = await api(display.lut.url, { binary: true });
  renderer.useDisplay(display.lut.glsl);
  renderer.setLut(display.lut.size, new Float32Array(await table.arrayBuffer()));
  $('#display').textContent = `${display.display} · ${display.view}`;
  $('#display').title = `OCIO ${display.config}: display and view, baked into a ${display.lut.size}³ LUT`
    + (display.view === display.default_view ? " (the products' and previews' own)" : '');
}

/** Show the composite through another view of the display (the choice is kept in the document
 *  and a saved look's previews use it). */
async function setDisplayView(view) {
  const choice = $('#view-transform');
  choice.disabled = true;
  try {
    const display = await api(`/api/display?${new URLSearchParams({ view })}`);
    await showDisplay(display);
    state.doc.display_view = view === display.default_view ? null : view;
    choice.value = view;
    schedulePersist();
    requestDraw();
  } catch (error) {
    setStatus(`view ${view}: ${error.message}`, true);
  } finally {
    choice.disabled = false;
  }
}

/** The document the page opens with: the one kept beside the render, else the render's stack. */
function openingDocument(session) {
  const kept = session.document;
  if (kept) return kept;
  const doc = emptyDocument();
  doc.entries = session.layers.filter((layer) => layer.kind === 'beauty' || layer.kind === 'layer')
    .map((layer) => newEntry(state.sources.get(layer.id)));
  return doc;
}

async function start() {
  const session = await api('/api/session');
  state.width = session.width;
  state.height = session.height;
  state.index = session.index;
  state.kelvin = session.kelvin ?? null;
  state.cryptomattes = session.cryptomattes ?? {};
  for (const [list, pairs] of [[EVENT_TYPES, session.alphabet.types], [SCATTERINGS, session.alphabet.scatterings]]) {
    list.push(...pairs.map(([letter, name]) => [letter, `${letter} ${name}`]));
  }
  document.title = `${session.title} · pxr-layers`;
  $('#title').textContent = session.title;
  const { display } = session;
  $('#partition-note').hidden = session.partition !== false || session.layers.length < 2;

  renderer = new Renderer(canvas, display.lut.glsl);
  canvas.addEventListener('webglcontextlost', () => setStatus('the GPU context was lost: reload the page', true));
  await showDisplay(display);

  // Data layers (anything but the beauty and light layers) do not enter the composite.
  for (const layer of session.layers) if (layer.kind === 'beauty' || layer.kind === 'layer') addSource(layer);
  state.doc = openingDocument(session);
  history = new History(state.doc, documentChanged);
  const viewChoice = $('#view-transform');
  viewChoice.replaceChildren(...display.views.map((view) => el('option', { value: view }, view)));
  viewChoice.value = state.doc.display_view ?? display.view;
  viewChoice.addEventListener('change', () => setDisplayView(viewChoice.value));
  if (state.doc.display_view && state.doc.display_view !== display.view) await setDisplayView(state.doc.display_view);
  $('#denoised').hidden = !session.denoised;
  $('#denoised').addEventListener('click', () => setDenoised(!state.doc.denoised));
  if (!session.denoised) state.doc.denoised = false;
  $('#denoised').setAttribute('aria-pressed', String(state.doc.denoised));
  renderStack();
  syncExposure();
  syncCompare();
  syncHistoryButtons();
  let loaded = 0;
  const loading = $('#loading');
  const queue = [...state.sources.values()];
  const worker = async () => {
    for (let next = queue.shift(); next; next = queue.shift()) {
      await loadSource(next);
      loading.textContent = `loading layers ${++loaded}/${state.sources.size}…`;
    }
  };
  await Promise.all([worker(), worker(), worker()]);
  ensureMasks();

  if (state.index) {
    fillDatalist($('#labels'), state.index.labels ?? []);
    fillDatalist($('#end-labels'), state.index.lights ?? []);
    $('#selection-info').textContent = `click a pixel or drag a region · ${state.index.file}, ${state.index.spp} spp`;
  } else {
    for (const panel of ['#make-panel', '#save-panel', '#suggest-row']) $(panel).classList.add('disabled');
    for (const control of document.querySelectorAll('#make-panel :is(input, button, select, summary), #save-panel :is(input, button), #suggest-row :is(input, button)')) {
      control.setAttribute('disabled', '');
      control.setAttribute('tabindex', '-1');
    }
    $('#selection-info').textContent = 'no path index beside this product';
  }
  $('#layer-name').placeholder = freeLayerName();
  showTab('classes');
  resizeCanvas();
  scheduleChecks(true);
  await nextFrame();
  loading.hidden = true;
  pxrViewer.ready = true;
}

// The hook the browser tests and the benchmark drive the page through (tests/test_view_browser.py).
const pxrViewer = {
  ready: false,
  error: null,
  persisted: 0,  // documents written by the server so far
  timings,
  frames: () => framesDrawn,
  state: () => ({
    width: state.width, height: state.height, exposure: state.doc.exposure, view: { ...state.view }, denoised: state.doc.denoised,
    canvas: [canvas.width, canvas.height], selection: state.selection, gpu: renderer?.gpu, compare: { ...state.doc.compare },
    pass: renderer?.lastPass ?? 0,
    snapshots: state.doc.snapshots.map((snapshot) => snapshot.name), saved: state.doc.saved?.name ?? null,
    undo: history?.canUndo ?? false, redo: history?.canRedo ?? false,
    layers: state.doc.entries.map(({ id, source, name, kind, group, stops, tint, kelvin, mute, solo, mask }) => ({
      id, source, name, kind, share: state.sources.get(source)?.share ?? 0, group, stops, tint, kelvin, mute, solo, mask,
    })),
    pushable: Object.fromEntries(state.pushable), overlaps: state.overlaps,
  }),
  /** The document as the page holds it (what it persists). */
  document: () => structuredClone(state.doc),
  /** Write the document now; resolves once the server has it. */
  persist: () => persistNow(),
  /** The client (CSS) coordinates of image pixel (x, y)'s centre, for a mouse click. */
  imageToClient(x, y) {
    const box = canvas.getBoundingClientRect();
    const { view } = state;
    return [box.left + (view.x + (x + 0.5) * view.scale) / dpr(), box.top + (view.y + (y + 0.5) * view.scale) / dpr()];
  },
  /** The image as drawn at 1:1: {width, height, rgba: base64 of height × width × 4 bytes}. */
  readImage() {
    const { x, y, scale } = state.view;
    if (scale !== 1 || x < 0 || y < 0 || x + state.width > panelWidth() || y + state.height > canvas.height) {
      throw new Error('readImage needs the whole image on the canvas at 1:1 (press 1, and a canvas at least as large)');
    }
    drawNow();
    return { width: state.width, height: state.height, rgba: base64(renderer.read(x, y, state.width, state.height)) };
  },
  /** A stack entry's linear RGB as uploaded (its source's): base64 of its little-endian float32 data. */
  layerData(id) {
    const entry = entryById(id);
    const data = state.sources.get(entry ? entry.source : id)?.data;
    return data ? base64(new Uint8Array(data.buffer, data.byteOffset, data.byteLength)) : null;
  },
  /** A mask's coverage as uploaded: base64 of little-endian float32, or null until fetched. */
  maskData(mask) {
    const data = state.masks.get(maskKey(mask))?.data;
    return data ? base64(new Uint8Array(data.buffer, data.byteOffset, data.byteLength)) : null;
  },
  /** Show the denoised stack or the stack as rendered, as the button does; resolves when shown. */
  setDenoised,
  /** Grade a layer as its controls would: change = {stops, tint, kelvin, mute, solo, mask}. */
  setGrade(id, change) {
    setGrade(id, change);
  },
  setCompare,
  setDisplayView,
  undo,
  redo,
  /** Draw now and wait for the GPU: milliseconds taken. */
  drawFinished() {
    const begin = performance.now();
    drawNow();
    renderer.finish();
    return performance.now() - begin;
  },
};
window.pxrViewer = pxrViewer;

setupView();
setupStack();
setupMake();
setupKeyboard();
setupHelp();
$('#save').addEventListener('click', save);
$('#push').addEventListener('click', push);
start().catch((error) => {
  pxrViewer.error = error.message;
  const loading = $('#loading');
  loading.hidden = false;
  loading.classList.add('error');
  loading.textContent = error.message;
  setStatus(error.message, true);
});
