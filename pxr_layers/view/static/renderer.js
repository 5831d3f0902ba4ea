// The inspector's WebGL2 renderer: the stack's images in one TEXTURE_2D_ARRAY of RGB32F, the
// Cryptomatte masks in one of R32F, the display LUT in a 3D RGB32F texture, one
// full-viewport triangle. The composite rule lives in FRAGMENT_MAIN below and in
// pxr_layers/view/composite.py (the numpy reference), nowhere else.

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

// The composite rule (pxr_layers/view/composite.py is its numpy reference), per look (set):
//   w_i = 1 + m_i · (g_i − 1), g_i = gain_i · tint_i (· blackbody(kelvin_i)), 0 when muted;
//         m_i the layer's mask coverage at the pixel, 1 without a mask
//   no layer soloed:   out = beauty + Σ_i (w_i − 1) · layer_i
//   some layer soloed: out = Σ_{i soloed} w_i · layer_i
//   then · 2^exposure, then the display LUT. At unit gains this is the beauty exactly:
//   the weights are exactly 0, so each (finite: renders hold no NaN) layer adds exactly 0.
// Renderer.draw computes what does not vary over the image, each entry's a_i: g_i − 1 (no
// solo), g_i (soloed), 0 (not soloed while others are); the shader applies the masks:
//   unmasked: weight a_i;  masked: m_i · a_i (no solo), 1 + m_i · (a_i − 1) (soloed).
// Two looks (sets 0 and 1) can be shown at once: split by a wipe line, or side by side.
// While one entry is regraded alone (a slider dragged), the rest of the look is summed once
// into a float texture (the base, pass 1) and each frame adds that entry only (pass 2): a
// frame then reads two layers, not all of them. It is the same sum, in another order (within
// float32 rounding); at unit gains, and with the entry's weight back at 0, it is the beauty
// exactly again.
// The pass, the compare mode, each look's entries and which of them are masked are compiled
// in (programFor): a software WebGL (SwiftShader, on machines without a GPU) runs a shader
// with a uniform loop, every pass's and mode's code and a mask test per entry two to four
// times as slowly as one unrolled for its stack with only its own code and its masks' tests.
const FRAGMENT_MAIN = `
uniform sampler2DArray u_images;  // slice 0 the beauty, then the layers: linear RGB, top row first
uniform sampler2DArray u_masks;   // mask coverages (red), top row first
uniform highp sampler3D u_lut;
uniform vec3 u_weight[2 * MAX_ENTRIES];  // a_i of each entry: look 0's, then look 1's
uniform ivec2 u_slices[2 * MAX_ENTRIES]; // (image slice, mask slice or -1)
uniform bool u_any_solo[2];
uniform float u_exposure_gain[2];  // 2^exposure
uniform float u_wipe;              // device pixels from the canvas's left edge to the wipe line
uniform vec2 u_origin;             // device pixels from the canvas's (or the half's) top-left corner to the image's
uniform float u_scale;             // device pixels per image pixel
uniform vec2 u_canvas;             // the canvas's size, device pixels
uniform vec3 u_background;
uniform int u_active;              // look 0's entry being regraded, when the base serves
uniform highp sampler2D u_base;    // look 0 less entry u_active, linear, before exposure (pass 1's output)
out vec4 colour;

// Entry i of a look at a pixel: its weight (the mask applied) times its layer.
vec3 contribution(int set, int i, ivec2 texel, bool soloing) {
  vec3 weight = u_weight[set * MAX_ENTRIES + i];
  ivec2 slices = u_slices[set * MAX_ENTRIES + i];
  if (slices.y >= 0) {
    float m = texelFetch(u_masks, ivec3(texel, slices.y), 0).r;
    weight = soloing ? (weight == vec3(0.0) ? weight : 1.0 + m * (weight - 1.0)) : m * weight;
  }
  return weight * texelFetch(u_images, ivec3(texel, slices.x), 0).rgb;
}

LOOKS

void main() {
#if PASS == 1  // the base: look 0 less its active entry, one fragment an image pixel
  colour = vec4(look0(ivec2(gl_FragCoord.xy)), 1.0);
#else
  // gl_FragCoord counts rows from the bottom; the images' rows run from the top.
  vec2 canvas_px = vec2(gl_FragCoord.x, u_canvas.y - gl_FragCoord.y);
  int set = 0;
#if MODE == 1
  set = canvas_px.x >= u_wipe ? 1 : 0;
#elif MODE == 2
  if (canvas_px.x >= floor(u_canvas.x / 2.0)) {
    set = 1;
    canvas_px.x -= floor(u_canvas.x / 2.0);
  }
#endif
  vec2 image_px = floor((canvas_px - u_origin) / u_scale);
  ivec2 size = textureSize(u_images, 0).xy;
  if (any(lessThan(image_px, vec2(0.0))) || any(greaterThanEqual(image_px, vec2(size)))) {
    colour = vec4(u_background, 1.0);
    return;
  }
  ivec2 texel = ivec2(image_px);
#if PASS == 2
  vec3 rgb = texelFetch(u_base, texel, 0).rgb + contribution(0, u_active, texel, u_any_solo[0]);
#elif MODE == 0
  vec3 rgb = look0(texel);
#else
  vec3 rgb = set == 0 ? look0(texel) : look1(texel);
#endif
  colour = vec4(displayLut(rgb * u_exposure_gain[set], u_lut), 1.0);  // NaN and infinities: as the previews
#endif
}
`;

/** GLSL of `vec3 lookS(ivec2 texel)`: look S at a pixel, linear, before its exposure, its
 *  entries unrolled (masked[i]: entry i has a mask; an unmasked one's weight is its a_i);
 *  `skip`: entry u_active left out (pass 1). */
function lookSource(set, masked, skip) {
  const terms = masked.map((mask, i) => {
    const at = `${set} * MAX_ENTRIES + ${i}`;
    const term = mask ? `contribution(${set}, ${i}, texel, soloing)`
      : `u_weight[${at}] * texelFetch(u_images, ivec3(texel, u_slices[${at}].x), 0).rgb`;
    return `  ${skip ? `if (u_active != ${i}) ` : ''}rgb += ${term};\n`;
  });
  return `vec3 look${set}(ivec2 texel) {
  bool soloing = u_any_solo[${set}];
  vec3 rgb = soloing ? vec3(0.0) : texelFetch(u_images, ivec3(texel, 0), 0).rgb;
${terms.join('')}  return rgb;
}`;
}

/** At most this many compiled programs are kept (a pass and a stack's masked entries each). */
const PROGRAMS_KEPT = 16;

export const BACKGROUND = [0.09, 0.094, 0.102];
export const MODES = { one: 0, wipe: 1, side: 2 };

/** A growable TEXTURE_2D_ARRAY of one format, with CPU copies to refill it when it grows
 *  (immutable storage cannot grow). */
class SliceArray {
  constructor(gl, unit, internalFormat, format) {
    Object.assign(this, { gl, unit, internalFormat, format, images: [], capacity: 0, width: 0, height: 0, texture: null });
  }

  set(slice, data, width, height, maxSlices) {
    if (slice >= maxSlices) throw new Error(`at most ${maxSlices} images fit in this browser's texture array`);
    this.images[slice] = data;
    const { gl } = this;
    if (slice >= this.capacity || width !== this.width || height !== this.height) {
      this.width = width;
      this.height = height;
      this.capacity = Math.min(maxSlices, Math.max(slice + 4, Math.ceil(this.images.length * 1.5)));
      if (this.texture) gl.deleteTexture(this.texture);
      this.texture = gl.createTexture();
      this.bind();
      Renderer.nearest(gl, gl.TEXTURE_2D_ARRAY);
      gl.texStorage3D(gl.TEXTURE_2D_ARRAY, 1, this.internalFormat, width, height, this.capacity);
      this.images.forEach((image, at) => image && this.upload(at, image));
      return;
    }
    this.upload(slice, data);
  }

  bind() {
    this.gl.activeTexture(this.gl.TEXTURE0 + this.unit);
    this.gl.bindTexture(this.gl.TEXTURE_2D_ARRAY, this.texture);
  }

  upload(slice, data) {
    const { gl } = this;
    this.bind();
    gl.texSubImage3D(gl.TEXTURE_2D_ARRAY, 0, 0, 0, slice, this.width, this.height, 1, this.format, gl.FLOAT, data);
  }
}

export class Renderer {
  constructor(canvas, lutGlsl) {
    this.canvas = canvas;
    const gl = canvas.getContext('webgl2', {
      alpha: false, antialias: false, depth: false, stencil: false, premultipliedAlpha: false,
      preserveDrawingBuffer: false, powerPreference: 'high-performance',
    });
    if (!gl) throw new Error('this browser has no WebGL2: the inspector needs it');
    this.gl = gl;
    // Each entry of each of the two looks takes two uniform vectors (weight, slices); leave some for the rest.
    this.maxEntries = Math.min(128, Math.floor((gl.getParameter(gl.MAX_FRAGMENT_UNIFORM_VECTORS) - 16) / 4));
    this.maxSlices = gl.getParameter(gl.MAX_ARRAY_TEXTURE_LAYERS);
    this.programs = new Map();  // programFor's key (pass, mode, masked entries) → {program, uniforms}, oldest first
    this.useDisplay(lutGlsl);
    this.images = new SliceArray(gl, 0, gl.RGB32F, gl.RGB);
    this.masks = new SliceArray(gl, 2, gl.R32F, gl.RED);
    // The base (see FRAGMENT_MAIN) needs a float render target: WebGL2 has it with this extension.
    this.baseAllowed = Boolean(gl.getExtension('EXT_color_buffer_float'));
    this.base = null;      // {texture, framebuffer, width, height, key}
    this.lastKey = null;   // what the last frame's look 0 was, less its active entry
    this.contents = 0;     // bumped when an image or a mask changes: a base of older ones is stale
    this.weight = new Float32Array(2 * this.maxEntries * 3);
    this.slices = new Int32Array(2 * this.maxEntries * 2);
    this.onePixel = new Uint8Array(4);
    const debug = gl.getExtension('WEBGL_debug_renderer_info');
    this.gpu = gl.getParameter(debug ? debug.UNMASKED_RENDERER_WEBGL : gl.RENDERER);  // for the benchmark's report
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 4);
    // An empty mask array until the first mask: a sampler must have a complete texture.
    this.masks.set(0, new Float32Array(1), 1, 1, this.maxSlices);
    this.masks.images = [];
  }

  /** The shaders use this display transform's GLSL (pxr_layers/layers/display_lut.py). It is
   *  compiled at once, so a bad transform fails here rather than at the next frame. */
  useDisplay(lutGlsl) {
    for (const { program } of this.programs.values()) this.gl.deleteProgram(program);
    this.programs.clear();
    this.lutGlsl = lutGlsl;
    this.programFor(0, MODES.one, [[false], []]);
  }

  /** The program of pass `pass` in mode `mode` (MODES) for looks whose entries are masked or
   *  not (`masked`: per look, a bool per entry), compiled on first use. */
  programFor(pass, mode, masked) {
    if (pass === 2) masked = [[], []];  // pass 2 reads no look
    const key = `${pass} ${mode} ${masked.map((look) => look.map(Number).join('')).join(' ')}`;
    let compiled = this.programs.get(key);
    if (compiled) {  // most recently used last
      this.programs.delete(key);
      this.programs.set(key, compiled);
      return compiled;
    }
    const looks = pass === 2 ? '' : `${lookSource(0, masked[0], pass === 1)}\n${lookSource(1, masked[1], false)}`;
    const program = this.link(`${FRAGMENT_HEAD}${this.lutGlsl}\n#define MAX_ENTRIES ${this.maxEntries}\n`
      + `#define PASS ${pass}\n#define MODE ${mode}\n${FRAGMENT_MAIN.replace('LOOKS', looks)}`);
    const uniforms = {};
    for (const name of ['u_images', 'u_masks', 'u_lut', 'u_weight', 'u_slices', 'u_any_solo', 'u_exposure_gain',
      'u_wipe', 'u_origin', 'u_scale', 'u_canvas', 'u_background', 'u_active', 'u_base']) {
      uniforms[name] = this.gl.getUniformLocation(program, name);
    }
    compiled = { program, uniforms };
    this.programs.set(key, compiled);
    if (this.programs.size > PROGRAMS_KEPT) {
      const [oldest, { program: dropped }] = this.programs.entries().next().value;
      this.gl.deleteProgram(dropped);
      this.programs.delete(oldest);
    }
    return compiled;
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
    if (this.lut) gl.deleteTexture(this.lut);
    this.lut = gl.createTexture();
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_3D, this.lut);
    Renderer.nearest(gl, gl.TEXTURE_3D);
    gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGB32F, size, size, size, 0, gl.RGB, gl.FLOAT, data);
  }

  /** Image slice `slice` (0: the beauty): height × width × 3 floats, top row first. */
  setImage(slice, data, width, height) {
    this.contents += 1;
    this.images.set(slice, data, width, height, this.maxSlices);
    this.width = width;
    this.height = height;
  }

  /** Mask slice `slice`: height × width floats (coverage), top row first. */
  setMask(slice, data, width, height) {
    this.contents += 1;
    this.masks.set(slice, data, width, height, this.maxSlices);
  }

  /** Draw one look, or two. looks: [{entries: [{slice, grade: [r, g, b], mute, solo, maskSlice}],
   *  exposure}] (the beauty is not an entry); view: {x, y, scale} in device pixels, relative
   *  to the canvas (side by side: to each half); mode: MODES; wipe: the wipe line's device x;
   *  active: the index of look 0's entry being regraded (-1: none), whose frames may add it to
   *  a base of the rest (FRAGMENT_MAIN). */
  draw(looks, view, mode = MODES.one, wipe = 0, active = -1) {
    const gl = this.gl;
    const masked = [[], []];  // per look, per entry: its mask applies (programFor)
    const anySolo = [0, 0];
    const gains = [1, 1];
    looks.forEach((look, set) => {
      if (look.entries.length > this.maxEntries) {
        throw new Error(`at most ${this.maxEntries} layers fit in this browser's shader`);
      }
      gains[set] = 2 ** look.exposure;
      anySolo[set] = look.entries.some((entry) => entry.solo) ? 1 : 0;
      look.entries.forEach((entry, i) => {
        const at = set * this.maxEntries + i;
        const graded = entry.mute ? [0, 0, 0] : entry.grade;
        // a_i (the rule above), in float32 as the numpy reference computes g_i − 1
        const weight = anySolo[set] ? (entry.solo ? graded : [0, 0, 0]) : graded.map((g) => Math.fround(g) - 1);
        this.weight.set(weight, at * 3);
        const maskSlice = anySolo[set] && !entry.solo ? -1 : (entry.maskSlice ?? -1);
        this.slices.set([entry.slice, maskSlice], at * 2);
        masked[set].push(maskSlice >= 0);
      });
    });
    if (looks.length === 1) mode = MODES.one;
    const plan = this.planBase(looks, mode, active);
    // The background is cleared; the shader runs on the image's pixels only (a software
    // WebGL pays for every fragment, early return or not).
    const { width, height } = this.canvas;
    gl.viewport(0, 0, width, height);
    gl.disable(gl.SCISSOR_TEST);
    gl.clearColor(...BACKGROUND, 1);
    gl.clear(gl.COLOR_BUFFER_BIT);
    const panels = mode === MODES.side ? [0, Math.floor(width / 2)] : [0];
    this.images.bind();
    this.masks.bind();
    gl.activeTexture(gl.TEXTURE1);
    gl.bindTexture(gl.TEXTURE_3D, this.lut);
    gl.activeTexture(gl.TEXTURE3);
    gl.bindTexture(gl.TEXTURE_2D, null);  // not read while it is written
    const use = (pass) => {
      const { program, uniforms: u } = this.programFor(pass, mode, masked);
      gl.useProgram(program);
      gl.uniform1i(u.u_images, 0);
      gl.uniform1i(u.u_lut, 1);
      gl.uniform1i(u.u_masks, 2);
      gl.uniform1i(u.u_base, 3);
      gl.uniform3fv(u.u_weight, this.weight);
      gl.uniform2iv(u.u_slices, this.slices);
      gl.uniform1iv(u.u_any_solo, anySolo);
      gl.uniform1fv(u.u_exposure_gain, gains);
      gl.uniform1f(u.u_wipe, wipe);
      gl.uniform2f(u.u_origin, view.x, view.y);
      gl.uniform1f(u.u_scale, view.scale);
      gl.uniform2f(u.u_canvas, width, height);
      gl.uniform3fv(u.u_background, BACKGROUND);
      gl.uniform1i(u.u_active, active);
    };
    if (plan.fill) {
      use(1);
      gl.bindFramebuffer(gl.FRAMEBUFFER, this.base.framebuffer);
      gl.viewport(0, 0, this.width, this.height);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
      gl.bindFramebuffer(gl.FRAMEBUFFER, null);
      gl.viewport(0, 0, width, height);
      this.base.key = plan.key;
    }
    use(plan.pass);
    this.lastPass = plan.pass;  // for the tests: 2 when the frame added one entry to the base
    gl.bindTexture(gl.TEXTURE_2D, plan.pass === 2 ? this.base.texture : null);
    gl.enable(gl.SCISSOR_TEST);
    for (const offset of panels) {
      const left = Math.max(offset, Math.floor(offset + view.x));
      const top = Math.max(0, Math.floor(view.y));
      const end = mode === MODES.side && offset === 0 ? panels[1] : width;
      const right = Math.min(end, Math.ceil(offset + view.x + this.width * view.scale));
      const bottom = Math.min(height, Math.ceil(view.y + this.height * view.scale));
      if (right <= left || bottom <= top) continue;
      gl.scissor(left, height - bottom, right - left, bottom - top);
      gl.drawArrays(gl.TRIANGLES, 0, 3);
    }
  }

  /** {pass, fill, key}: pass 2 when this frame adds look 0's active entry to the base (fill:
   *  the base is filled first), 0 when it draws the looks whole. A base pays when the rest of
   *  the look stayed as it was since the last frame (a slider being dragged), not when
   *  everything changes every frame. */
  planBase(looks, mode, active) {
    if (!this.baseAllowed || mode !== MODES.one || active < 0 || looks[0].entries.length < 2) {
      this.lastKey = null;
      return { pass: 0, fill: false, key: null };
    }
    const entries = looks[0].entries;
    const key = JSON.stringify([this.contents, this.width, this.height, active, entries.map((entry, i) => (i === active
      ? [entry.slice, entry.solo, entry.maskSlice] : [entry.slice, entry.grade, entry.mute, entry.solo, entry.maskSlice]))]);
    const steady = key === this.lastKey;
    this.lastKey = key;
    if (this.base?.key === key) return { pass: 2, fill: false, key };
    if (!steady || !this.makeBase()) return { pass: 0, fill: false, key };
    return { pass: 2, fill: true, key };
  }

  /** The base's float texture and framebuffer, at the images' size; false if the browser
   *  cannot draw into one (the looks are then always drawn whole). */
  makeBase() {
    const gl = this.gl;
    if (this.base && this.base.width === this.width && this.base.height === this.height) return true;
    if (this.base) {
      gl.deleteFramebuffer(this.base.framebuffer);
      gl.deleteTexture(this.base.texture);
      this.base = null;
    }
    const texture = gl.createTexture();
    gl.activeTexture(gl.TEXTURE3);
    gl.bindTexture(gl.TEXTURE_2D, texture);
    Renderer.nearest(gl, gl.TEXTURE_2D);
    gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA32F, this.width, this.height);
    gl.bindTexture(gl.TEXTURE_2D, null);
    const framebuffer = gl.createFramebuffer();
    gl.bindFramebuffer(gl.FRAMEBUFFER, framebuffer);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, texture, 0);
    const complete = gl.checkFramebufferStatus(gl.FRAMEBUFFER) === gl.FRAMEBUFFER_COMPLETE;
    gl.bindFramebuffer(gl.FRAMEBUFFER, null);
    if (!complete) {
      gl.deleteFramebuffer(framebuffer);
      gl.deleteTexture(texture);
      this.baseAllowed = false;
      return false;
    }
    this.base = { texture, framebuffer, width: this.width, height: this.height, key: null };
    return true;
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
