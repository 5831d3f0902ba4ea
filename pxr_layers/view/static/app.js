// The layer inspector's page: see the composite through the display LUT, regrade the layer
// stack live, inspect the light paths of a pixel or region, make a layer, save the look.
// Plain ES2022 and WebGL2, no build step. The HTTP API is the server's
// (pxr_layers/view/server.py); the composite rule lives in FRAGMENT_MAIN below and in
// pxr_layers/view/composite.py (the numpy reference), nowhere else.

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

async function api(path, { method = 'GET', body, signal, binary = false } = {}) {
  const headers = { 'X-Pxr-Token': TOKEN };
  if (body !== undefined) headers['Content-Type'] = 'application/json';
  const response = await fetch(path, {
    method, headers, signal, body: body === undefined ? undefined : JSON.stringify(body),
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

/** An image of the stack: Float32Array of height × width × 3 linear RGB, top row first. */
async function fetchImage(id, width, height) {
  const version = state.denoised ? 'denoised' : 'raw';
  const response = await api(`/api/image/${encodeURIComponent(id)}?version=${version}`, { binary: true });
  const data = new Float32Array(await response.arrayBuffer());
  if (data.length !== width * height * 3) {
    throw new Error(`image ${id}: ${data.length} floats, expected ${width}×${height}×3`);
  }
  return data;
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

// --- the renderer -------------------------------------------------------------------------

const VERTEX_SHADER = `#version 300 es
void main() {  // one triangle over the whole viewport, no vertex buffer
  vec2 corner = vec2(float((gl_VertexID & 1) << 2), float((gl_VertexID & 2) << 1));
  gl_Position = vec4(corner - 1.0, 0.0, 1.0);
}`;

const FRAGMENT_HEAD = `#version 300 es
precision highp float;
precision highp int;
precision highp sampler2DArray;
precision highp sampler3D;
`;  // then the session's displayLut (pxr_layers/layers/display_lut.py), then FRAGMENT_MAIN

// The composite rule (pxr_layers/view/composite.py is its numpy reference):
//   no layer soloed:   out = beauty + Σ_i (gain_i · tint_i − 1) · layer_i   (muted: gain_i = 0)
//   some layer soloed: out = Σ_{i soloed, not muted} gain_i · tint_i · layer_i
//   then · 2^exposure, then the display LUT. At unit gains this is the beauty exactly:
//   the weights are exactly 0 and the layers are not even read.
const FRAGMENT_MAIN = `
uniform sampler2DArray u_images;  // slice 0 the beauty, then the layers: linear RGB, top row first
uniform highp sampler3D u_lut;
uniform int u_slices;             // slices in the stack, the beauty included
uniform vec3 u_grade[MAX_LAYERS]; // gain · tint of each slice (2^stops · linear tint)
uniform int u_flags[MAX_LAYERS];  // MUTED | SOLOED
uniform bool u_any_solo;
uniform float u_exposure_gain;    // 2^exposure
uniform vec2 u_origin;            // device pixels from the canvas's top-left corner to the image's
uniform float u_scale;            // device pixels per image pixel
uniform float u_canvas_height;
uniform vec3 u_background;
out vec4 colour;

const int MUTED = 1;
const int SOLOED = 2;

void main() {
  // gl_FragCoord counts rows from the bottom; the images' rows run from the top.
  vec2 canvas_px = vec2(gl_FragCoord.x, u_canvas_height - gl_FragCoord.y);
  vec2 image_px = floor((canvas_px - u_origin) / u_scale);
  ivec2 size = textureSize(u_images, 0).xy;
  if (any(lessThan(image_px, vec2(0.0))) || any(greaterThanEqual(image_px, vec2(size)))) {
    colour = vec4(u_background, 1.0);
    return;
  }
  ivec2 texel = ivec2(image_px);
  vec3 rgb = u_any_solo ? vec3(0.0) : texelFetch(u_images, ivec3(texel, 0), 0).rgb;
  for (int i = 1; i < u_slices; ++i) {
    vec3 graded = (u_flags[i] & MUTED) != 0 ? vec3(0.0) : u_grade[i];
    vec3 weight = u_any_solo ? ((u_flags[i] & SOLOED) != 0 ? graded : vec3(0.0)) : graded - 1.0;
    if (weight != vec3(0.0)) rgb += weight * texelFetch(u_images, ivec3(texel, i), 0).rgb;
  }
  colour = vec4(displayLut(rgb * u_exposure_gain, u_lut), 1.0);  // NaN and infinities: as the previews
}
`;

const BACKGROUND = [0.09, 0.094, 0.102];
const MUTED = 1;
const SOLOED = 2;

/** WebGL2: the stack's images in one TEXTURE_2D_ARRAY of RGB32F (slice i = stack entry i),
 *  the display LUT in a 3D RGB32F texture, one full-viewport triangle. */
class Renderer {
  constructor(canvas, lutGlsl) {
    this.canvas = canvas;
    const gl = canvas.getContext('webgl2', {
      alpha: false, antialias: false, depth: false, stencil: false, premultipliedAlpha: false,
      preserveDrawingBuffer: false, powerPreference: 'high-performance',
    });
    if (!gl) throw new Error('this browser has no WebGL2: the inspector needs it');
    this.gl = gl;
    // Each slice takes two uniform vectors (grade, flags); leave some for the rest.
    this.maxLayers = Math.min(256, Math.floor((gl.getParameter(gl.MAX_FRAGMENT_UNIFORM_VECTORS) - 16) / 2),
      gl.getParameter(gl.MAX_ARRAY_TEXTURE_LAYERS));
    this.program = this.link(`${FRAGMENT_HEAD}${lutGlsl}\n#define MAX_LAYERS ${this.maxLayers}\n${FRAGMENT_MAIN}`);
    this.uniforms = {};
    for (const name of ['u_images', 'u_lut', 'u_slices', 'u_grade', 'u_flags', 'u_any_solo', 'u_exposure_gain',
      'u_origin', 'u_scale', 'u_canvas_height', 'u_background']) {
      this.uniforms[name] = gl.getUniformLocation(this.program, name);
    }
    this.images = [];  // CPU copies, to fill a bigger array when the stack outgrows this one
    this.capacity = 0;
    this.grade = new Float32Array(this.maxLayers * 3);
    this.flags = new Int32Array(this.maxLayers);
    this.onePixel = new Uint8Array(4);
    const debug = gl.getExtension('WEBGL_debug_renderer_info');
    this.gpu = gl.getParameter(debug ? debug.UNMASKED_RENDERER_WEBGL : gl.RENDERER);  // for the benchmark's report
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 4);
  }

  link(fragmentSource) {
    const gl = this.gl;
    const compile = (type, source) => {
      const shader = gl.createShader(type);
      gl.shaderSource(shader, source);
      gl.compileShader(shader);
      if (!gl.getShaderParameter(shader, gl.COMPILE_STATUS)) {
        throw new Error(`shader does not compile: ${gl.getShaderInfoLog(shader)}`);
      }
      return shader;
    };
    const program = gl.createProgram();
    gl.attachShader(program, compile(gl.VERTEX_SHADER, VERTEX_SHADER));
    gl.attachShader(program, compile(gl.FRAGMENT_SHADER, fragmentSource));
    gl.linkProgram(program);
    if (!gl.getProgramParameter(program, gl.LINK_STATUS)) {
      throw new Error(`shader does not link: ${gl.getProgramInfoLog(program)}`);
    }
    return program;
  }

  static nearest(gl, target) {
    // RGB32F is not filterable without an extension; everything is read with texelFetch.
    for (const parameter of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(target, parameter, gl.NEAREST);
    for (const parameter of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T, gl.TEXTURE_WRAP_R]) {
      gl.texParameteri(target, parameter, gl.CLAMP_TO_EDGE);
    }
  }

  /** The baked display transform: size³ × 3 floats, r fastest (width r, height g, depth b). */
  setLut(size, data) {
    const gl = this.gl;
    this.lut = gl.createTexture();
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_3D, this.lut);
    Renderer.nearest(gl, gl.TEXTURE_3D);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGB32F, size, size, size, 0, gl.RGB, gl.FLOAT, data);
  }

  /** Put `data` (height × width × 3 floats) at slice `slot`, growing the array if needed. */
  setImage(slot, data, width, height) {
    if (slot >= this.maxLayers) throw new Error(`at most ${this.maxLayers - 1} layers fit in this browser's shader`);
    this.images[slot] = data;
    const gl = this.gl;
    if (slot >= this.capacity || width !== this.width || height !== this.height) {
      // Immutable storage cannot grow: allocate room for some more, refill from the CPU copies.
      this.width = width;
      this.height = height;
      this.capacity = Math.min(this.maxLayers, Math.max(slot + 4, Math.ceil(this.images.length * 1.5)));
      if (this.array) gl.deleteTexture(this.array);
      this.array = gl.createTexture();
      gl.activeTexture(gl.TEXTURE0);
      gl.bindTexture(gl.TEXTURE_2D_ARRAY, this.array);
      Renderer.nearest(gl, gl.TEXTURE_2D_ARRAY);
      gl.texStorage3D(gl.TEXTURE_2D_ARRAY, 1, gl.RGB32F, width, height, this.capacity);
      this.images.forEach((image, at) => image && this.upload(at, image));
      return;
    }
    this.upload(slot, data);
  }

  upload(slot, data) {
    const gl = this.gl;
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, this.array);
    gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, 0, 0, 0, slot, this.width, this.height, 1, gl.RGB, gl.FLOAT, data);
  }

  /** Draw the stack. layers: [{gain, tint, mute, solo}] in slice order (0: the beauty, whose
   *  grade the rule ignores); view: {x, y, scale} in device pixels. */
  draw(layers, exposure, view) {
    const gl = this.gl;
    const u = this.uniforms;
    let anySolo = false;
    layers.forEach((layer, slot) => {
      const gain = 2 ** layer.stops;
      for (let c = 0; c < 3; ++c) this.grade[slot * 3 + c] = gain * layer.tint[c];
      this.flags[slot] = (layer.mute ? MUTED : 0) | (layer.solo ? SOLOED : 0);
      anySolo ||= slot > 0 && layer.solo;
    });
    // The background is cleared; the shader runs on the image's pixels only (a software
    // WebGL pays for every fragment, early return or not).
    const { width, height } = this.canvas;
    gl.viewport(0, 0, width, height);
    gl.disable(gl.SCISSOR_TEST);
    gl.clearColor(...BACKGROUND, 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    const left = Math.max(0, Math.floor(view.x));
    const top = Math.max(0, Math.floor(view.y));
    const right = Math.min(width, Math.ceil(view.x + this.width * view.scale));
    const bottom = Math.min(height, Math.ceil(view.y + this.height * view.scale));
    if (right <= left || bottom <= top) return;
    gl.enable(gl.SCISSOR_TEST);
    gl.scissor(left, height - bottom, right - left, bottom - top);
    gl.useProgram(this.program);
    gl.activeTexture(gl.TEXTURE0);
    gl.bindTexture(gl.TEXTURE_2D_ARRAY, this.array);
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_3D, this.lut);
    gl.uniform1i(u.u_images, 0);
    gl.uniform1i(u.u_lut, 1);
    gl.uniform1i(u.u_slices, layers.length);
    gl.uniform3fv(u.u_grade, this.grade);
    gl.uniform1iv(u.u_flags, this.flags);
    gl.uniform1i(u.u_any_solo, anySolo ? 1 : 0);
    gl.uniform1f(u.u_exposure_gain, 2 ** exposure);
    gl.uniform2f(u.u_origin, view.x, view.y);
    gl.uniform1f(u.u_scale, view.scale);
    gl.uniform1f(u.u_canvas_height, height);
    gl.uniform3fv(u.u_background, BACKGROUND);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
  }

  /** Wait until the GPU has drawn what was asked. gl.finish() returns at once in Chromium (its
   *  GPU process runs the commands later); reading a pixel back waits for them. */
  finish() {
    this.gl.readPixels(0, 0, 1, 1, this.gl.RGBA, this.gl.UNSIGNED_BYTE, this.onePixel);
  }

  /** RGBA bytes of a canvas rectangle (device pixels, top-left origin), top row first. Call
   *  right after draw(): the drawing buffer is not preserved past the frame. */
  read(x, y, width, height) {
    const gl = this.gl;
    const bottomUp = new Uint8Array(width * height * 4);
    gl.readPixels(x, this.canvas.height - y - height, width, height, gl.RGBA, gl.UNSIGNED_BYTE, bottomUp);
    const rows = new Uint8Array(bottomUp.length);
    const stride = width * 4;
    for (let row = 0; row < height; ++row) {
      rows.set(bottomUp.subarray((height - 1 - row) * stride, (height - row) * stride), row * stride);
    }
    return rows;
  }
}

// --- state --------------------------------------------------------------------------------

const state = {
  width: 0,
  height: 0,
  index: null,          // the session's index description, or null
  layers: [],           // the stack: {id, name, kind, share, expression, stops, tint, mute, solo, data}
  exposure: 0,
  denoised: false,      // showing the denoised twins' stack (the session has them)
  view: { x: 0, y: 0, scale: 1, fit: true },  // device pixels
  selection: null,      // {x0, y0, x1, y1}, image pixels, exclusive end
  inspection: null,     // the last /api/inspect reply
  picked: new Set(),    // ticked class ids of that reply
  tab: 'classes',
  builder: { rows: [], anyAfter: true },
};

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

function drawNow() {
  renderer.draw(state.layers, state.exposure, state.view);
  framesDrawn += 1;
}

/** Resolves once the next frame is drawn and finished on the GPU, with its time. */
function nextFrame() {
  return new Promise((resolve) => { afterDraw.push(resolve); requestDraw(); });
}

// --- the view: fit, 1:1, zoom, pan --------------------------------------------------------

const dpr = () => window.devicePixelRatio || 1;

function resizeCanvas() {
  const box = canvas.getBoundingClientRect();
  const width = Math.max(1, Math.round(box.width * dpr()));
  const height = Math.max(1, Math.round(box.height * dpr()));
  if (canvas.width !== width || canvas.height !== height) {
    canvas.width = width;
    canvas.height = height;
  }
  if (state.view.fit) fit();
  requestDraw();
}

function setView(x, y, scale, fitted = false) {
  Object.assign(state.view, { x, y, scale, fit: fitted });
  const shown = scale * 100 / dpr();
  $('#zoom').textContent = `${shown >= 10 ? Math.round(shown) : shown.toFixed(1)} %`;
  requestDraw();
}

/** The whole image; enlarged by a whole factor only, so that pixels stay equal squares. */
function fit() {
  if (!state.width) return;
  let scale = Math.min(canvas.width / state.width, canvas.height / state.height);
  if (scale >= 1) scale = Math.floor(scale);
  setView(Math.round((canvas.width - state.width * scale) / 2), Math.round((canvas.height - state.height * scale) / 2),
    scale, true);
}

/** One image pixel per device pixel, centred, on whole pixels. */
function oneToOne() {
  setView(Math.round((canvas.width - state.width) / 2), Math.round((canvas.height - state.height) / 2), 1);
}

function zoomAt(deviceX, deviceY, factor) {
  const { x, y, scale } = state.view;
  const next = Math.min(256, Math.max(1 / 64, scale * factor));
  const imageX = (deviceX - x) / scale;
  const imageY = (deviceY - y) / scale;
  setView(deviceX - imageX * next, deviceY - imageY * next, next);
}

function deviceAt(event) {
  const box = canvas.getBoundingClientRect();
  return [(event.clientX - box.left) * dpr(), (event.clientY - box.top) * dpr()];
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

const placeSelection = () => placeBox($('#selection'), state.selection);

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
    if (rect) inspect(rect);
  };
  canvas.addEventListener('pointerup', end);
  canvas.addEventListener('pointercancel', end);
  canvas.addEventListener('auxclick', (event) => event.preventDefault());  // no paste or autoscroll on middle
  canvas.addEventListener('pointerleave', () => { $('#readout').textContent = ''; });
  $('#fit').addEventListener('click', fit);
  $('#one-to-one').addEventListener('click', oneToOne);
}

function showReadout(point) {
  const [ix, iy] = imageAt(...point).map(Math.floor);
  const beauty = state.layers[0]?.data;
  if (!beauty || ix < 0 || iy < 0 || ix >= state.width || iy >= state.height) {
    $('#readout').textContent = '';
    return;
  }
  const at = (iy * state.width + ix) * 3;
  const rgb = Array.from(beauty.subarray(at, at + 3), (v) => number(v, 4));
  $('#readout').textContent = `${ix}, ${iy}  beauty ${rgb.join(' ')}`;
}

// --- exposure and the layer stack ---------------------------------------------------------

function setExposure(stops) {
  state.exposure = Number.isFinite(stops) ? stops : 0;
  $('#exposure').value = state.exposure;
  $('#exposure-number').value = state.exposure;
  requestDraw();
}

function setupExposure() {
  $('#exposure').addEventListener('input', (event) => setExposure(Number(event.target.value)));
  $('#exposure-number').addEventListener('input', (event) => {
    if (event.target.value !== '') setExposure(Number(event.target.value));
  });
  $('#reset').addEventListener('click', resetGrades);
}

function stackEntry(layer) {
  const stops = Number.isFinite(layer.exposure) ? layer.exposure : 0;
  const tint = Array.isArray(layer.tint) && layer.tint.length === 3 ? layer.tint.map(Number) : [1, 1, 1];
  return {
    id: layer.id, name: layer.name ?? layer.id, kind: layer.kind, share: layer.share ?? 0,
    expression: layer.expression ?? '', stops, tint, mute: false, solo: false, data: null,
  };
}

function layerRow(layer) {
  const head = el('div', { class: 'layer-head' });
  const row = el('li', { dataset: { id: layer.id }, class: layer.kind === 'beauty' ? 'beauty' : '' }, head);
  const share = el('span', { class: 'share', title: "share of the beauty's energy (Rec.709 luminance)" },
    shareBar(layer.share), el('span', { class: 'percent' }, percent(layer.share)));
  if (layer.kind === 'beauty') {
    head.append(el('span', { class: 'layer-name', title: 'what the layers leave of it stays in the composite' },
      layer.name), share);
    return row;
  }
  const toggle = (letter, key, title) => el('button', {
    class: `toggle ${key}`, title, 'aria-pressed': String(layer[key]),
    onclick: () => setGrade(layer, { [key]: !layer[key] }),
  }, letter);
  head.append(toggle('S', 'solo', 'solo: show only the soloed layers'), toggle('M', 'mute', 'mute: gain 0'),
    el('span', { class: 'layer-name', title: layer.expression ? `${layer.name}: ${layer.expression}` : layer.name },
      layer.name), el('span', { class: 'tint-value mono', title: 'the linear tint' }), share);
  const slider = el('input', {
    type: 'range', class: 'gain', min: -10, max: 10, step: 0.05, value: layer.stops, title: 'gain (stops)',
    oninput: (event) => setGrade(layer, { stops: Number(event.target.value) }),
  });
  const field = el('input', {
    type: 'number', class: 'stops', min: -30, max: 30, step: 0.1, value: layer.stops, title: 'gain (stops)',
    oninput: (event) => event.target.value !== '' && setGrade(layer, { stops: Number(event.target.value) }),
  });
  const colour = el('input', {
    type: 'color', class: 'tint', value: linearToHex(layer.tint), title: 'tint: a linear RGB multiplier',
    oninput: (event) => setGrade(layer, { tint: hexToLinear(event.target.value) }),
  });
  row.append(el('div', { class: 'layer-grade' }, el('span', { class: 'dim' }, 'gain'), slider, field, colour));
  return row;
}

function rowOf(layer) {
  return $(`#stack li[data-id="${CSS.escape(layer.id)}"]`);
}

/** Show `layer`'s grade in its row (the one place its controls are written). */
function syncRow(layer) {
  const row = rowOf(layer);
  if (!row || layer.kind === 'beauty') return;
  row.classList.toggle('muted', layer.mute);
  $('.toggle.solo', row).setAttribute('aria-pressed', String(layer.solo));
  $('.toggle.mute', row).setAttribute('aria-pressed', String(layer.mute));
  const gain = $('.gain', row);
  const field = $('.stops', row);
  if (Number(gain.value) !== layer.stops) gain.value = layer.stops;
  if (document.activeElement !== field && Number(field.value) !== layer.stops) field.value = layer.stops;
  const colour = $('.tint', row);
  if (document.activeElement !== colour) colour.value = linearToHex(layer.tint);
  $('.tint-value', row).textContent = layer.tint.every((c) => c === 1) ? '' : `×${layer.tint.map((c) => c.toFixed(2)).join(' ')}`;
}

function setGrade(layer, change) {
  Object.assign(layer, change);
  syncRow(layer);
  requestDraw();
}

function renderStack() {
  $('#stack').replaceChildren(...state.layers.map(layerRow));
  state.layers.forEach(syncRow);
}

function resetGrades() {
  for (const layer of state.layers) setGrade(layer, { stops: 0, tint: [1, 1, 1], mute: false, solo: false });
  setExposure(0);
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

function freeLayerName() {
  const taken = new Set(state.layers.map((layer) => layer.id));
  let n = 1;
  while (taken.has(`layer_${n}`)) n += 1;
  return `layer_${n}`;
}

const timings = { layer: null };  // the last "add layer": milliseconds from the click

async function addLayer() {
  const start = performance.now();
  const name = $('#layer-name').value.trim() || freeLayerName();
  const expression = $('#expression').value.trim();
  const status = $('#layer-status');
  if (!LAYER_NAME.test(name)) {
    status.textContent = 'a layer name is letters, digits and _, not starting with a digit';
    return;
  }
  if (state.layers.some((layer) => layer.id === name || layer.name === name)) {
    status.textContent = `the stack already has a layer named ${name}`;
    return;
  }
  if (!expression) {
    status.textContent = 'write an expression first (or generalise ticked classes, or use the query builder)';
    return;
  }
  const button = $('#add-layer');
  button.disabled = true;
  status.textContent = `extracting ${name}…`;
  try {
    const made = await api('/api/layer', { method: 'POST', body: { name, expression } });
    const extracted = performance.now();
    const entry = stackEntry({ kind: 'layer', ...made });
    entry.data = await fetchImage(made.id, state.width, state.height);
    const fetched = performance.now();
    renderer.setImage(state.layers.length, entry.data, state.width, state.height);
    state.layers.push(entry);
    renderStack();
    if ($('#solo-new').checked) {
      for (const layer of state.layers) setGrade(layer, { solo: layer === entry });
    }
    const shown = await nextFrame();
    timings.layer = {
      name, extract: extracted - start, fetch: fetched - extracted, show: shown - fetched, total: shown - start,
      server_seconds: made.seconds,
    };
    const matched = made.classes === undefined ? '' : `${made.classes.toLocaleString()} path classes, `;
    status.textContent = `${name}: ${percent(made.share ?? 0)} of the energy, ${matched}`
      + `extracted in ${number(made.seconds ?? NaN)} s, on screen ${((shown - start) / 1000).toFixed(2)} s after the click`;
    $('#layer-name').value = '';
  } catch (error) {
    if (Number.isInteger(error.position)) showExpressionError(expression, error.message, error.position);
    status.textContent = `not added: ${error.message}`;
  } finally {
    button.disabled = false;
  }
}

/** Layers found automatically (POST /api/suggest): K layers that partition the beauty, added to
 * the stack at unit gain (the picture does not change until they are regraded). */
async function suggestLayers() {
  const k = Number($('#suggest-k').value);
  const status = $('#suggest-status');
  const button = $('#suggest');
  button.disabled = true;
  status.textContent = `finding ${k} layers…`;
  try {
    const found = await api('/api/suggest', { method: 'POST', body: { k } });
    for (const made of found.layers) {
      const entry = stackEntry({ kind: 'layer', ...made });
      entry.data = await fetchImage(made.id, state.width, state.height);
      renderer.setImage(state.layers.length, entry.data, state.width, state.height);
      state.layers.push(entry);
    }
    renderStack();
    requestDraw();
    status.textContent = `${found.layers.length} layers (${found.strategy}) in ${number(found.seconds)} s`;
    timings.suggest = { layers: found.layers.map((layer) => layer.id), server_seconds: found.seconds };
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

// --- save ---------------------------------------------------------------------------------

async function save() {
  const name = $('#save-name').value.trim();
  const list = $('#saved');
  if (!LOOK_NAME.test(name)) {
    list.replaceChildren(el('li', { class: 'error' }, 'a look name is letters, digits, _ and -, not starting with a digit'));
    return;
  }
  const body = {
    name,
    exposure: state.exposure,
    overwrite: $('#overwrite').checked,
    layers: state.layers.filter((layer) => layer.kind !== 'beauty').map(({ id, stops, tint, mute, solo }) => ({ id, stops, tint, mute, solo })),
  };
  const button = $('#save');
  button.disabled = true;
  list.replaceChildren(el('li', { class: 'dim' }, 'writing…'));
  try {
    const written = await api('/api/save', { method: 'POST', body });
    list.replaceChildren(...Object.entries(written).map(([what, file]) => el('li', { dataset: { kind: what } },
      el('a', { href: `/files/${encodeURIComponent(file)}?token=${encodeURIComponent(TOKEN)}`, download: file }, file))));
  } catch (error) {
    const hint = error.status === 409 ? ' (tick overwrite to replace it)' : '';
    list.replaceChildren(el('li', { class: 'error' }, `${error.message}${hint}`));
  } finally {
    button.disabled = false;
  }
}

// --- keyboard -----------------------------------------------------------------------------

function setupKeyboard() {
  const typing = (target) => target.matches?.('input:not([type=range]):not([type=checkbox]):not([type=color]), select, textarea');
  addEventListener('keydown', (event) => {
    if (event.ctrlKey || event.metaKey || event.altKey || typing(event.target)) return;
    if (event.key === ' ' && !event.target.matches?.('button, summary')) {
      event.preventDefault();
      spaceHeld = true;
      $('#viewer').classList.add('panning');
    } else if (event.key === 'f') fit();
    else if (event.key === '1') oneToOne();
    else if (event.key === 'r') resetGrades();
    else if (event.key === 'd') setDenoised(!state.denoised);
  });
  addEventListener('keyup', (event) => {
    if (event.key === ' ') {
      spaceHeld = false;
      $('#viewer').classList.remove('panning');
    }
  });
  addEventListener('blur', () => { spaceHeld = false; $('#viewer').classList.remove('panning'); });
}

// --- start --------------------------------------------------------------------------------

function fillDatalist(list, labels) {
  list.replaceChildren(...labels.map((label) => el('option', { value: label })));
}

/** Show the denoised twins' stack (on) or the stack as rendered: every image fetched again,
 * the grades kept. */
async function setDenoised(on) {
  const button = $('#denoised');
  if (button.hidden || state.denoised === on) return;
  state.denoised = on;
  button.setAttribute('aria-pressed', String(on));
  button.disabled = true;
  try {
    await Promise.all(state.layers.map(async (layer, slot) => {
      layer.data = await fetchImage(layer.id, state.width, state.height);
      renderer.setImage(slot, layer.data, state.width, state.height);
    }));
    setStatus(on ? 'the denoised stack' : 'the stack as rendered');
  } catch (error) {
    setStatus(error.message, true);
  } finally {
    button.disabled = false;
    requestDraw();
  }
}

async function start() {
  const session = await api('/api/session');
  $('#denoised').hidden = !session.denoised;
  $('#denoised').addEventListener('click', () => setDenoised(!state.denoised));
  state.width = session.width;
  state.height = session.height;
  state.index = session.index;
  for (const [list, pairs] of [[EVENT_TYPES, session.alphabet.types], [SCATTERINGS, session.alphabet.scatterings]]) {
    list.push(...pairs.map(([letter, name]) => [letter, `${letter} ${name}`]));
  }
  document.title = `${session.title} · pxr-layers`;
  $('#title').textContent = session.title;
  const { display } = session;
  $('#display').textContent = `${display.display} · ${display.view}`;
  $('#display').title = `OCIO ${display.config}: the previews' display and view, baked into a ${display.lut.size}³ LUT`;
  $('#partition-note').hidden = session.partition !== false || session.layers.length < 2;

  renderer = new Renderer(canvas, display.lut.glsl);
  canvas.addEventListener('webglcontextlost', () => setStatus('the GPU context was lost: reload the page', true));
  const lutResponse = await api(display.lut.url, { binary: true });
  renderer.setLut(display.lut.size, new Float32Array(await lutResponse.arrayBuffer()));

  // Data layers (anything but the beauty and light layers) do not enter the composite.
  state.layers = session.layers.filter((layer) => layer.kind === 'beauty' || layer.kind === 'layer').map(stackEntry);
  renderStack();
  let loaded = 0;
  const loading = $('#loading');
  const queue = state.layers.map((layer, slot) => [layer, slot]);
  const worker = async () => {
    for (let next = queue.shift(); next; next = queue.shift()) {
      const [layer, slot] = next;
      layer.data = await fetchImage(layer.id, state.width, state.height);
      renderer.setImage(slot, layer.data, state.width, state.height);
      loading.textContent = `loading layers ${++loaded}/${state.layers.length}…`;
    }
  };
  await Promise.all([worker(), worker(), worker()]);

  if (state.index) {
    fillDatalist($('#labels'), state.index.labels ?? []);
    fillDatalist($('#end-labels'), state.index.lights ?? []);
    $('#selection-info').textContent = `click a pixel or drag a region · ${state.index.file}, ${state.index.spp} spp`;
  } else {
    for (const panel of ['#make-panel', '#save-panel', '#suggest-row']) $(panel).classList.add('disabled');
    $('#selection-info').textContent = 'no path index beside this product';
  }
  $('#layer-name').placeholder = freeLayerName();
  showTab('classes');
  resizeCanvas();
  fit();
  await nextFrame();
  loading.hidden = true;
  pxrViewer.ready = true;
}

// The hook the browser tests and the benchmark drive the page through (tests/test_view_browser.py).
const pxrViewer = {
  ready: false,
  error: null,
  timings,
  frames: () => framesDrawn,
  state: () => ({
    width: state.width, height: state.height, exposure: state.exposure, view: { ...state.view }, denoised: state.denoised,
    canvas: [canvas.width, canvas.height], selection: state.selection, gpu: renderer?.gpu,
    layers: state.layers.map(({ id, name, kind, share, stops, tint, mute, solo }) => ({ id, name, kind, share, stops, tint, mute, solo })),
  }),
  /** The client (CSS) coordinates of image pixel (x, y)'s centre, for a mouse click. */
  imageToClient(x, y) {
    const box = canvas.getBoundingClientRect();
    const { view } = state;
    return [box.left + (view.x + (x + 0.5) * view.scale) / dpr(), box.top + (view.y + (y + 0.5) * view.scale) / dpr()];
  },
  /** The image as drawn at 1:1: {width, height, rgba: base64 of height × width × 4 bytes}. */
  readImage() {
    const { x, y, scale } = state.view;
    if (scale !== 1 || x < 0 || y < 0 || x + state.width > canvas.width || y + state.height > canvas.height) {
      throw new Error('readImage needs the whole image on the canvas at 1:1 (press 1, and a canvas at least as large)');
    }
    drawNow();
    return { width: state.width, height: state.height, rgba: base64(renderer.read(x, y, state.width, state.height)) };
  },
  /** A stack entry's linear RGB as uploaded: base64 of its little-endian float32 data. */
  layerData(id) {
    const layer = state.layers.find((entry) => entry.id === id);
    return layer ? base64(new Uint8Array(layer.data.buffer, layer.data.byteOffset, layer.data.byteLength)) : null;
  },
  /** Show the denoised stack or the stack as rendered, as the button does; resolves when shown. */
  setDenoised,
  /** Grade a layer as its controls would: change = {stops, tint, mute, solo}. */
  setGrade(id, change) {
    setGrade(state.layers.find((layer) => layer.id === id), change);
  },
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
setupExposure();
setupMake();
setupKeyboard();
$('#save').addEventListener('click', save);
start().catch((error) => {
  pxrViewer.error = error.message;
  const loading = $('#loading');
  loading.hidden = false;
  loading.classList.add('error');
  loading.textContent = error.message;
  setStatus(error.message, true);
});
