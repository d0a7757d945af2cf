// btfquilt studio: a WebGL2 viewer that shades the decorated surface as
// `btfquilt render` does (the baked colour, or the BTF relit per pixel from
// its factorization, Σ g_i p_i with the renderer's direction interpolation),
// and paints on it through the studio's JSON API.
'use strict';

const $ = (id) => document.getElementById(id);
const hash = new URLSearchParams(location.hash.slice(1));
const studio = (window.studio = {
  ready: false, error: null, frames: 0, version: -1,
  lastApplyMs: null, lastPreviewMs: null, busy: false, changes: 0,
});

// ---------------------------------------------------------------- vectors
const sub = (a, b) => [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
const add = (a, b) => [a[0] + b[0], a[1] + b[1], a[2] + b[2]];
const mul = (a, s) => [a[0] * s, a[1] * s, a[2] * s];
const dot = (a, b) => a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
const cross = (a, b) => [a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]];
const len = (a) => Math.sqrt(dot(a, a));
const unit = (a) => { const l = len(a); return l > 1e-20 ? mul(a, 1 / l) : [0, 0, 0]; };
const numbers = (s, n) => {
  const v = (s || '').split(',').map(Number);
  return v.length === n && v.every(Number.isFinite) ? v : null;
};

// The camera in scene units: eye, target, up, vertical fov (degrees).
const cam = { eye: [0, 0, 1], target: [0, 0, 0], up: [0, 1, 0], fov: 42 };
let light = unit([0.4, 0.8, 0.6]);
let exposure = 0;

function viewProj(w, h, radius) {
  const f = unit(sub(cam.target, cam.eye));
  const s = unit(cross(f, cam.up));
  const u = cross(s, f);
  const dist = len(sub(cam.target, cam.eye));
  const near = Math.max(dist - 2 * radius, dist * 1e-3, radius * 1e-4);
  const far = dist + 2 * radius;
  const t = 1 / Math.tan((cam.fov * Math.PI) / 360);
  const a = h / w;
  const e = cam.eye;
  // column-major: projection × view
  const view = [s[0], u[0], -f[0], 0, s[1], u[1], -f[1], 0, s[2], u[2], -f[2], 0,
    -dot(s, e), -dot(u, e), dot(f, e), 1];
  const proj = [t * a, 0, 0, 0, 0, t, 0, 0, 0, 0, (far + near) / (near - far), -1,
    0, 0, (2 * far * near) / (near - far), 0];
  const out = new Float32Array(16);
  for (let c = 0; c < 4; c++) {
    for (let r = 0; r < 4; r++) {
      let v = 0;
      for (let k = 0; k < 4; k++) v += proj[k * 4 + r] * view[c * 4 + k];
      out[c * 4 + r] = v;
    }
  }
  return out;
}

// ---------------------------------------------------------------- network
async function api(path, body) {
  const init = body === undefined ? {} : {
    method: 'POST', headers: { 'Content-Type': 'application/json' }, body: JSON.stringify(body),
  };
  const r = await fetch(path, init);
  const kind = r.headers.get('Content-Type') || '';
  const data = kind.startsWith('application/json') ? await r.json() : await r.arrayBuffer();
  if (!r.ok) throw new Error((data && data.error) || `${path}: HTTP ${r.status}`);
  return data;
}

// ---------------------------------------------------------------- WebGL
const canvas = $('view');
const gl = canvas.getContext('webgl2', { antialias: false, preserveDrawingBuffer: true });

const VERTEX = `#version 300 es
in vec3 aPos; in vec3 aNrm; in vec2 aUv; in vec3 aDx; in vec3 aDy; in float aValid;
uniform mat4 uViewProj;
out vec3 vPos; out vec3 vNrm; out vec2 vUv; out vec3 vDx; out vec3 vDy; out float vValid;
void main() {
  vPos = aPos; vNrm = aNrm; vUv = aUv; vDx = aDx; vDy = aDy; vValid = aValid;
  gl_Position = uViewProj * vec4(aPos, 1.0);
}`;

// Shared by both shadings: inputs, overlays and the sRGB encoding of the
// PNG writer.
const HEAD = `#version 300 es
precision highp float; precision highp int;
precision highp sampler2D; precision highp sampler2DArray;
in vec3 vPos; in vec3 vNrm; in vec2 vUv; in vec3 vDx; in vec3 vDy; in float vValid;
out vec4 outColor;
uniform int uR;
uniform vec3 uEye; uniform vec3 uLight; uniform float uExposure;
uniform sampler2D uTexA; uniform sampler2D uTexB;
uniform highp sampler2D uStrokes; uniform int uStrokeCount;
uniform vec4 uBrush; uniform int uOverlay; uniform sampler2D uOverlayTex; uniform int uPick;
vec3 unitOr(vec3 v) { float l = length(v); return l > 1e-20 ? v / l : vec3(0.0); }
vec3 srgb(vec3 v) {
  vec3 c = clamp(v, 0.0, 1.0);
  return mix(c * 12.92, 1.055 * pow(c, vec3(1.0 / 2.4)) - 0.055, step(vec3(0.0031308), c));
}
vec3 normalAt() {
  vec3 n = unitOr(vNrm);
  if (dot(n, n) < 0.5) n = unitOr(cross(dFdx(vPos), dFdy(vPos)));
  return n;
}
vec3 decorate(vec3 c, vec3 n) {
  if (uOverlay == 1) {
    ivec2 t = clamp(ivec2(floor(vUv * float(uR))), ivec2(0), ivec2(uR - 1));
    vec4 o = texelFetch(uOverlayTex, t, 0);
    if (o.a > 0.5) {
      vec3 lin = mix(o.rgb / 12.92, pow((o.rgb + 0.055) / 1.055, vec3(2.4)), step(vec3(0.04045), o.rgb));
      c = lin * (0.18 + 0.82 * max(dot(n, normalize(uLight)), 0.0)) * exp2(uExposure);
    }
  }
  bool marked = false;
  for (int i = 0; i < uStrokeCount; i++) {
    vec4 s = texelFetch(uStrokes, ivec2(i, 0), 0);
    if (distance(vPos, s.xyz) < s.w) { marked = true; break; }
  }
  if (marked) c = mix(c, vec3(1.0, 0.45, 0.1), 0.35);
  if (uBrush.w > 0.0) {
    float d = abs(distance(vPos, uBrush.xyz) - uBrush.w);
    if (d < uBrush.w * 0.06) c = vec3(1.0, 0.8, 0.2);
  }
  return c;
}
void finish(vec3 linear, vec3 n) {
  if (uPick == 1) { outColor = vec4(vUv, 1.0, 0.0); return; }
  if (uPick == 2) { outColor = vec4(vPos, 1.0); return; }
  outColor = vec4(srgb(decorate(linear * exp2(uExposure), n)), 1.0);
}
`;

// Colour: the dilated preview, bilinear in the atlas, × 0.18 + 0.82 n·l.
const COLOUR = HEAD + `
vec3 texel(int x, int y) { return texelFetch(uTexA, ivec2(x, y), 0).rgb; }
void main() {
  vec3 n = normalAt();
  float last = float(uR - 1);
  vec2 a = clamp(vUv * float(uR) - 0.5, 0.0, last);
  ivec2 i0 = ivec2(floor(a));
  ivec2 i1 = min(i0 + 1, ivec2(uR - 1));
  vec2 f = a - vec2(i0);
  vec3 top = texel(i0.x, i0.y) + (texel(i1.x, i0.y) - texel(i0.x, i0.y)) * f.x;
  vec3 bottom = texel(i0.x, i1.y) + (texel(i1.x, i1.y) - texel(i0.x, i1.y)) * f.x;
  vec3 c = top + (bottom - top) * f.y;
  float e = max(dot(n, unitOr(uLight)), 0.0);
  finish(c * (0.18 + 0.82 * e), n);
}`;

// BTF: see src/output/render.rs (`shade_btf`); the same steps in the same
// order.
const btfShader = (layers) => HEAD + `
#define MAXL ${layers}
uniform sampler2DArray uGeo; uniform sampler2D uApp; uniform sampler2D uDirs;
uniform int uNV; uniform int uNL; uniform int uNS; uniform int uAppWidth;
uniform ivec4 uSW; uniform ivec4 uSH; uniform ivec4 uSLayers; uniform ivec4 uSFirstLayer; uniform ivec4 uSFirstTexel;
uniform float uViewCosMax; uniform float uLightCosMax;
const float EXACT_HIT = 1e-4;
int pick4(ivec4 v, int k) { return k == 0 ? v.x : k == 1 ? v.y : k == 2 ? v.z : v.w; }
vec4 texA(int x, int y) { return texelFetch(uTexA, ivec2(x, y), 0); }
vec4 texB(int x, int y) { return texelFetch(uTexB, ivec2(x, y), 0); }
float rnd(float v) { return v >= 0.0 ? floor(v + 0.5) : -floor(-v + 0.5); }

vec3 clampDir(vec3 d, float cosMax) {
  if (d.z >= cosMax) return d;
  float sinMax = sqrt(max(1.0 - cosMax * cosMax, 0.0));
  float h = length(d.xy);
  if (h < 1e-12) return vec3(sinMax, 0.0, cosMax);
  return vec3(sinMax * d.xy / h, cosMax);
}

// The (up to) 3 nearest measured directions of row 'row' and their weights
// 1/α_k − 1/α_4, normalised.
void nearest(int row, int count, vec3 d, out int idx[3], out float w[3], out int n) {
  float bc[4]; int bi[4];
  for (int k = 0; k < 4; k++) { bc[k] = -1e30; bi[k] = 0; }
  for (int j = 0; j < count; j++) {
    float c = dot(d, texelFetch(uDirs, ivec2(j, row), 0).xyz);
    if (c > bc[3]) {
      int k = 3;
      while (k > 0 && c > bc[k - 1]) { bc[k] = bc[k - 1]; bi[k] = bi[k - 1]; k--; }
      bc[k] = c; bi[k] = j;
    }
  }
  float ang[4];
  for (int k = 0; k < 4; k++) {
    float chord = distance(d, texelFetch(uDirs, ivec2(bi[k], row), 0).xyz);
    ang[k] = 2.0 * asin(min(0.5 * chord, 1.0));
  }
  n = min(count, 3);
  float cut = count > 3 ? 1.0 / max(ang[3], EXACT_HIT) : 0.0;
  float total = 0.0;
  for (int k = 0; k < 3; k++) { idx[k] = bi[k]; w[k] = 0.0; }
  for (int k = 0; k < n; k++) {
    if (ang[k] < EXACT_HIT) { idx[0] = bi[k]; w[0] = 1.0; n = 1; return; }
    w[k] = max(1.0 / ang[k] - cut, 0.0);
    total += w[k];
  }
  if (!(total > 0.0)) { for (int k = 0; k < n; k++) w[k] = 1.0 / float(n); return; }
  for (int k = 0; k < n; k++) w[k] /= total;
}

// Adds weight × sample k's g vector at (sx, sy) (bilinear, clamped).
void addGeometry(int k, float sx, float sy, float weight, inout vec4 g[MAXL]) {
  int w = pick4(uSW, k), h = pick4(uSH, k), layers = pick4(uSLayers, k), first = pick4(uSFirstLayer, k);
  float gx = clamp(sx, 0.0, float(w - 1)), gy = clamp(sy, 0.0, float(h - 1));
  int x0 = int(floor(gx)), y0 = int(floor(gy));
  int x1 = min(x0 + 1, w - 1), y1 = min(y0 + 1, h - 1);
  float fx = gx - float(x0), fy = gy - float(y0);
  ivec2 at[4] = ivec2[4](ivec2(x0, y0), ivec2(x1, y0), ivec2(x0, y1), ivec2(x1, y1));
  float ww[4] = float[4]((1.0 - fx) * (1.0 - fy), fx * (1.0 - fy), (1.0 - fx) * fy, fx * fy);
  for (int c = 0; c < 4; c++) {
    for (int l = 0; l < MAXL; l++) {
      if (l >= layers) break;
      g[l] += weight * ww[c] * texelFetch(uGeo, ivec3(at[c], first + l), 0);
    }
  }
}

vec4 app(int t) { return texelFetch(uApp, ivec2(t % uAppWidth, t / uAppWidth), 0); }

void main() {
  vec3 n = normalAt();
  float rf = float(uR);
  float xa = vUv.x * rf - 0.5, ya = vUv.y * rf - 0.5;
  // the nearest covered texel (up to 3 rings out)
  float last = rf - 1.0;
  int tx = int(clamp(rnd(xa), 0.0, last)), ty = int(clamp(rnd(ya), 0.0, last));
  int bx = -1, by = -1; float bdx = 0.0, bdy = 0.0;
  if (texA(tx, ty).w > 0.5) { bx = tx; by = ty; bdx = xa - float(tx); bdy = ya - float(ty); }
  for (int ring = 1; ring <= 3 && bx < 0; ring++) {
    float best = 1e30;
    for (int y = ty - ring; y <= ty + ring; y++) {
      for (int x = tx - ring; x <= tx + ring; x++) {
        if (max(abs(x - tx), abs(y - ty)) != ring || x < 0 || y < 0 || x >= uR || y >= uR) continue;
        if (texA(x, y).w < 0.5) continue;
        float dx = xa - float(x), dy = ya - float(y), d = dx * dx + dy * dy;
        if (d < best) { best = d; bx = x; by = y; bdx = dx; bdy = dy; }
      }
    }
  }
  if (bx < 0) { finish(vec3(0.0), n); return; }
  vec4 ta = texA(bx, by); vec4 j = texB(bx, by);
  float sx = ta.x + j.x * bdx + j.z * bdy, sy = ta.y + j.y * bdx + j.w * bdy;
  int sampleT = int(ta.z + 0.5);
  // local frame: the sample's +x and +y on the surface
  float det = j.x * j.w - j.y * j.z;
  vec2 ax = vec2(j.w / det, -j.y / det), ay = vec2(-j.z / det, j.x / det);
  vec3 x3 = vec3(0.0), y3 = vec3(0.0);
  if (vValid > 0.5) { x3 = ax.x * vDx + ax.y * vDy; y3 = ay.x * vDx + ay.y * vDy; }
  vec3 xh = unitOr(x3 - n * dot(x3, n));
  if (dot(xh, xh) < 0.5) {
    vec3 other = abs(n.x) < 0.9 ? vec3(1.0, 0.0, 0.0) : vec3(0.0, 1.0, 0.0);
    xh = unitOr(cross(n, other));
  }
  vec3 yh = cross(n, xh);
  if (dot(yh, y3) < 0.0) yh = -yh;
  // the four texels around the pixel, each continuing its own patch
  float fbx = floor(xa), fby = floor(ya), fxa = xa - fbx, fya = ya - fby;
  int es[4]; float ex[4]; float ey[4]; float ew[4]; int ne = 0; float total = 0.0;
  vec3 offs[4] = vec3[4](vec3(0.0, 0.0, (1.0 - fxa) * (1.0 - fya)), vec3(1.0, 0.0, fxa * (1.0 - fya)),
                         vec3(0.0, 1.0, (1.0 - fxa) * fya), vec3(1.0, 1.0, fxa * fya));
  for (int k = 0; k < 4; k++) {
    float cx = fbx + offs[k].x, cy = fby + offs[k].y, wgt = offs[k].z;
    if (wgt <= 0.0 || cx < 0.0 || cy < 0.0 || cx >= rf || cy >= rf) continue;
    vec4 a = texA(int(cx), int(cy));
    if (a.w < 0.5) continue;
    vec4 jk = texB(int(cx), int(cy));
    float ddx = xa - cx, ddy = ya - cy;
    es[ne] = int(a.z + 0.5); ex[ne] = a.x + jk.x * ddx + jk.z * ddy; ey[ne] = a.y + jk.y * ddx + jk.w * ddy;
    ew[ne] = wgt; ne++; total += wgt;
  }
  if (!(total > 0.0)) { es[0] = sampleT; ex[0] = sx; ey[0] = sy; ew[0] = 1.0; ne = 1; total = 1.0; }
  vec3 view = unitOr(uEye - vPos);
  vec3 lv = vec3(dot(view, xh), dot(view, yh), dot(view, n));
  int vi[3]; float vw[3]; int vn;
  nearest(0, uNV, clampDir(lv, uViewCosMax), vi, vw, vn);
  vec3 l = unitOr(uLight);
  vec3 ll = vec3(dot(l, xh), dot(l, yh), dot(l, n));
  vec3 acc = vec3(0.0);
  if (ll.z > 0.0) {
    float fade = ll.z < uLightCosMax ? ll.z / max(uLightCosMax, 1e-3) : 1.0;
    int li[3]; float lw[3]; int ln;
    nearest(1, uNL, clampDir(ll, uLightCosMax), li, lw, ln);
    for (int e = 0; e < 4; e++) {
      if (e >= ne) break;
      int k = es[e];
      bool seen = false;
      for (int q = 0; q < 4; q++) { if (q < e && es[q] == k) seen = true; }
      if (seen) continue;
      vec4 g[MAXL];
      for (int i = 0; i < MAXL; i++) g[i] = vec4(0.0);
      for (int q = 0; q < 4; q++) {
        if (q < ne && es[q] == k) addGeometry(k, ex[q], ey[q], ew[q] / total, g);
      }
      int layers = pick4(uSLayers, k), first = pick4(uSFirstTexel, k);
      for (int a = 0; a < 3; a++) {
        if (a >= vn) break;
        for (int b = 0; b < 3; b++) {
          if (b >= ln) break;
          float wgt = vw[a] * lw[b] * fade;
          int pair = vi[a] * uNL + li[b];
          for (int ch = 0; ch < 3; ch++) {
            int base = first + (pair * 3 + ch) * layers;
            float s = 0.0;
            for (int i = 0; i < MAXL; i++) {
              if (i >= layers) break;
              s += dot(g[i], app(base + i));
            }
            acc[ch] += wgt * s;
          }
        }
      }
    }
  }
  finish(acc, n);
}`;

function compile(fragment) {
  const make = (type, src) => {
    const s = gl.createShader(type);
    gl.shaderSource(s, src);
    gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  };
  const p = gl.createProgram();
  gl.attachShader(p, make(gl.VERTEX_SHADER, VERTEX));
  gl.attachShader(p, make(gl.FRAGMENT_SHADER, fragment));
  ['aPos', 'aNrm', 'aUv', 'aDx', 'aDy', 'aValid'].forEach((n, i) => gl.bindAttribLocation(p, i, n));
  gl.linkProgram(p);
  if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
  return p;
}

function floatTexture(unitIndex, w, h, data, depth) {
  gl.activeTexture(gl.TEXTURE0 + unitIndex);
  const t = gl.createTexture();
  const target = depth ? gl.TEXTURE_2D_ARRAY : gl.TEXTURE_2D;
  gl.bindTexture(target, t);
  gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
  if (depth) gl.texImage3D(target, 0, gl.RGBA32F, w, h, depth, 0, gl.RGBA, gl.FLOAT, data);
  else gl.texImage2D(target, 0, gl.RGBA32F, w, h, 0, gl.RGBA, gl.FLOAT, data);
  for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(target, p, gl.NEAREST);
  return t;
}

// ---------------------------------------------------------------- scene
const S = {
  info: null, samples: [], texelSize: 0, program: null, layers: 0, vao: null, count: 0,
  centre: [0, 0, 0], radius: 1, textures: {}, strokes: [], overlay: null, pickFbo: null,
};

async function loadMesh() {
  const data = new Float32Array(await api('/api/mesh'));
  const n = data.length / 15;
  S.count = n;
  S.mesh = data;
  S.vao = gl.createVertexArray();
  gl.bindVertexArray(S.vao);
  const buf = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, buf);
  gl.bufferData(gl.ARRAY_BUFFER, data, gl.STATIC_DRAW);
  [[3, 0], [3, 3], [2, 6], [3, 8], [3, 11], [1, 14]].forEach(([size, off], i) => {
    gl.enableVertexAttribArray(i);
    gl.vertexAttribPointer(i, size, gl.FLOAT, false, 60, off * 4);
  });
  const lo = [Infinity, Infinity, Infinity], hi = [-Infinity, -Infinity, -Infinity];
  for (let i = 0; i < n; i++) {
    for (let k = 0; k < 3; k++) {
      lo[k] = Math.min(lo[k], data[i * 15 + k]);
      hi[k] = Math.max(hi[k], data[i * 15 + k]);
    }
  }
  S.centre = mul(add(lo, hi), 0.5);
  S.radius = Math.max(0.5 * len(sub(hi, lo)), 1e-6);
}

// Scene info, atlas texels and (for a BTF) the factorization: everything
// a new version of the surface may change. The factorization is fetched
// again only when the samples changed. Returns whether what the canvas
// shows can have changed only where texels did (the samples drawn before
// are where they were), so that a redraw of what those cover is the
// whole change.
async function loadSurface() {
  const meta = await api('/api/scene');
  const info = meta.scene;
  const prev = S.info;
  S.info = info; S.samples = meta.samples; S.texelSize = meta.texel_size;
  studio.version = meta.version;
  const r = info.resolution;
  const basisKey = JSON.stringify([info.btf, info.samples, info.geometry_size, info.appearance_rows,
    info.views, info.lights, info.view_cos_max, info.light_cos_max]);
  const texels = new Float32Array(await api('/api/texels'));
  const old = S.texelData;
  // the samples drawn before keep their place in the factorization (a
  // sample painted with for the first time comes after them)
  const layoutKey = JSON.stringify([info.btf, (info.geometry_size || []).slice(0, 2), info.views, info.lights,
    info.view_cos_max, info.light_cos_max]);
  const samplesBefore = (prev && prev.samples) || [];
  const samplesKept = !!prev && S.layoutKey === layoutKey
    && JSON.stringify((info.samples || []).slice(0, samplesBefore.length)) === JSON.stringify(samplesBefore);
  const layers = info.btf ? Math.max(...info.samples.map((x) => x.layers)) : 0;
  const onlyTexels = samplesKept && prev.resolution === r && !!old && old.length === texels.length
    && !!S.textures.a && (!info.btf || S.layers === layers);
  const keepBasis = info.btf && S.basisKey === basisKey && S.textures.geo;
  S.changed = onlyTexels ? changedTexels(old, texels, r) : null;
  for (const [k, t] of Object.entries(S.textures)) {
    if (keepBasis && (k === 'geo' || k === 'app' || k === 'dirs')) continue;
    if (onlyTexels && (k === 'a' || k === 'b')) continue;
    gl.deleteTexture(t);
    delete S.textures[k];
  }
  const planes = info.btf ? [['a', 0], ['b', 1]] : [['a', 0]];
  for (const [k, unit] of planes) {
    const data = texels.subarray(unit * r * r * 4, (unit + 1) * r * r * 4);
    if (!onlyTexels) {
      S.textures[k] = floatTexture(unit, r, r, data);
    } else if (S.changed.box) {
      // only the box of changed texels goes to the texture again
      const [x0, y0, w, h] = S.changed.box;
      const part = new Float32Array(w * h * 4);
      for (let y = 0; y < h; y++) part.set(data.subarray(((y0 + y) * r + x0) * 4, ((y0 + y) * r + x0 + w) * 4), y * w * 4);
      gl.activeTexture(gl.TEXTURE0 + unit);
      gl.bindTexture(gl.TEXTURE_2D, S.textures[k]);
      gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
      gl.texSubImage2D(gl.TEXTURE_2D, 0, x0, y0, w, h, gl.RGBA, gl.FLOAT, part);
    }
  }
  if (info.btf) {
    if (!keepBasis) {
      const basis = new Float32Array(await api('/api/basis'));
      const [gw, gh, gl_] = info.geometry_size;
      S.textures.geo = floatTexture(2, gw, gh, basis.subarray(0, gw * gh * gl_ * 4), gl_);
      S.textures.app = floatTexture(3, 2048, info.appearance_rows, basis.subarray(gw * gh * gl_ * 4));
      const nd = Math.max(info.views.length, info.lights.length);
      const dirs = new Float32Array(nd * 2 * 4);
      info.views.forEach((d, i) => dirs.set([...d, 0], i * 4));
      info.lights.forEach((d, i) => dirs.set([...d, 0], (nd + i) * 4));
      S.textures.dirs = floatTexture(4, nd, 2, dirs);
    }
    if (!S.program || S.layers !== layers) {
      S.program = compile(btfShader(layers));
      S.layers = layers;
    }
  } else if (!S.program) {
    S.program = compile(COLOUR);
  }
  S.basisKey = basisKey;
  S.layoutKey = layoutKey;
  S.texelData = texels;
  gl.activeTexture(gl.TEXTURE6);
  S.overlay = gl.createTexture();
  S.textures.overlay = S.overlay;
  gl.bindTexture(gl.TEXTURE_2D, S.overlay);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA8, r, r, 0, gl.RGBA, gl.UNSIGNED_BYTE, null);
  for (const p of [gl.TEXTURE_MIN_FILTER, gl.TEXTURE_MAG_FILTER]) gl.texParameteri(gl.TEXTURE_2D, p, gl.NEAREST);
  S.overlayOn = false;
  fillSamples();
  return onlyTexels;
}

// The texels that differ between two versions of the viewer's texel
// arrays (`planes` RGBA planes of r × r): a mask, how many it marks and
// their bounding box [x, y, w, h] (null when none changed).
function changedTexels(before, after, r) {
  const rr = r * r;
  const planes = after.length / (rr * 4);
  const mask = new Uint8Array(rr);
  let count = 0, x0 = r, y0 = r, x1 = -1, y1 = -1;
  for (let p = 0; p < planes; p++) {
    const o = p * rr * 4;
    for (let i = 0; i < rr; i++) {
      const k = o + i * 4;
      // (bit-exact: NaN against NaN is unchanged)
      if (before[k] === after[k] && before[k + 1] === after[k + 1] && before[k + 2] === after[k + 2]
        && before[k + 3] === after[k + 3]) continue;
      if ([0, 1, 2, 3].every((c) => Object.is(before[k + c], after[k + c]))) continue;
      if (mask[i]) continue;
      mask[i] = 1;
      count++;
      const x = i % r, y = (i - x) / r;
      x0 = Math.min(x0, x); y0 = Math.min(y0, y); x1 = Math.max(x1, x); y1 = Math.max(y1, y);
    }
  }
  return { mask, count, box: x1 >= 0 ? [x0, y0, x1 - x0 + 1, y1 - y0 + 1] : null };
}

// Texels around a changed one whose change a pixel may see: the BTF
// shading looks up to 3 rings out for a covered texel, then filters
// bilinearly.
const DAMAGE_TEXELS = 5;

// The canvas rectangles [x, y, w, h] (GL's bottom-left origin) that a
// change of the texels in `changedMask` (r × r) repaints, plus
// an atlas texel box [x, y, w, h] no longer overlaid and the world
// spheres [centre, radius] of strokes no longer marked; null when it
// cannot be bounded (a vertex behind the eye): then the whole canvas.
function damageRects(changedMask, box, spheres) {
  const r = S.info.resolution;
  const texels = !!changedMask || !!box;
  if (!changedMask) changedMask = new Uint8Array(0);
  // changed texels, then their summed-area table (none for spheres alone)
  const sat = new Int32Array(texels ? (r + 1) * (r + 1) : 1);
  for (let y = 0; texels && y < r; y++) {
    let row = 0;
    for (let x = 0; x < r; x++) {
      let changed = changedMask[y * r + x] || 0;
      if (box && x >= box[0] && x < box[0] + box[2] && y >= box[1] && y < box[1] + box[3]) changed = 1;
      row += changed;
      sat[(y + 1) * (r + 1) + x + 1] = sat[y * (r + 1) + x + 1] + row;
    }
  }
  const count = (x0, y0, x1, y1) => {
    x0 = Math.max(x0, 0); y0 = Math.max(y0, 0); x1 = Math.min(x1, r - 1); y1 = Math.min(y1, r - 1);
    if (x0 > x1 || y0 > y1) return 0;
    const w = r + 1;
    return sat[(y1 + 1) * w + x1 + 1] - sat[y0 * w + x1 + 1] - sat[(y1 + 1) * w + x0] + sat[y0 * w + x0];
  };
  const w = canvas.width, h = canvas.height;
  const m = viewProj(w, h, S.radius);
  let bounded = true;
  const boxes = [];
  // the canvas box of points given one by one, then closed by `done`
  let cur = null;
  const addPoint = (x, y, z) => {
    const cw = m[3] * x + m[7] * y + m[11] * z + m[15];
    if (!(cw > 1e-6)) { bounded = false; return; }
    const px = ((m[0] * x + m[4] * y + m[8] * z + m[12]) / cw * 0.5 + 0.5) * w;
    const py = ((m[1] * x + m[5] * y + m[9] * z + m[13]) / cw * 0.5 + 0.5) * h;
    cur = cur || [Infinity, Infinity, -Infinity, -Infinity];
    cur[0] = Math.min(cur[0], px); cur[1] = Math.min(cur[1], py);
    cur[2] = Math.max(cur[2], px); cur[3] = Math.max(cur[3], py);
  };
  const done = () => {
    if (!cur) return;
    // whole pixels, a margin of two for rasterization and derivative quads
    const b = [Math.max(Math.floor(cur[0]) - 2, 0), Math.max(Math.floor(cur[1]) - 2, 0),
      Math.min(Math.ceil(cur[2]) + 2, w), Math.min(Math.ceil(cur[3]) + 2, h)];
    if (b[2] > b[0] && b[3] > b[1]) boxes.push(b);
    cur = null;
  };
  const d = S.mesh, D = DAMAGE_TEXELS;
  const any = texels && sat[(r + 1) * (r + 1) - 1] > 0;
  for (let t = 0; any && t < S.count && bounded; t += 3) {
    let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
    for (let k = 0; k < 3; k++) {
      const u = d[(t + k) * 15 + 6] * r - 0.5, v = d[(t + k) * 15 + 7] * r - 0.5;
      x0 = Math.min(x0, u); y0 = Math.min(y0, v); x1 = Math.max(x1, u); y1 = Math.max(y1, v);
    }
    if (!(x1 >= x0 && y1 >= y0)) continue;
    if (count(Math.floor(x0) - D, Math.floor(y0) - D, Math.ceil(x1) + D, Math.ceil(y1) + D) === 0) continue;
    for (let k = 0; k < 3; k++) addPoint(d[(t + k) * 15], d[(t + k) * 15 + 1], d[(t + k) * 15 + 2]);
    done();
  }
  for (const [c, rad] of spheres) {
    for (let k = 0; k < 8 && bounded; k++) {
      addPoint(c[0] + (k & 1 ? rad : -rad), c[1] + (k & 2 ? rad : -rad), c[2] + (k & 4 ? rad : -rad));
    }
    done();
  }
  if (!bounded) return null;
  return mergeBoxes(boxes).map((b) => [b[0], b[1], b[2] - b[0], b[3] - b[1]]);
}

// Canvas boxes [x0, y0, x1, y1] merged where they touch or lie within
// DAMAGE_GAP pixels of each other, and all into one when more than
// DAMAGE_BOXES remain.
const DAMAGE_GAP = 8;
const DAMAGE_BOXES = 16;
function mergeBoxes(boxes) {
  let out = boxes.slice();
  for (let merged = true; merged;) {
    merged = false;
    const next = [];
    for (const b of out) {
      const near = next.find((a) => b[0] <= a[2] + DAMAGE_GAP && a[0] <= b[2] + DAMAGE_GAP
        && b[1] <= a[3] + DAMAGE_GAP && a[1] <= b[3] + DAMAGE_GAP);
      if (near) {
        near[0] = Math.min(near[0], b[0]); near[1] = Math.min(near[1], b[1]);
        near[2] = Math.max(near[2], b[2]); near[3] = Math.max(near[3], b[3]);
        merged = true;
      } else {
        next.push(b.slice());
      }
    }
    out = next;
  }
  if (out.length > DAMAGE_BOXES) {
    out = [out.reduce((a, b) => [Math.min(a[0], b[0]), Math.min(a[1], b[1]), Math.max(a[2], b[2]), Math.max(a[3], b[3])])];
  }
  return out;
}

function bindTextures() {
  const t = S.textures;
  const bind = (i, target, tex) => { gl.activeTexture(gl.TEXTURE0 + i); gl.bindTexture(target, tex || null); };
  bind(0, gl.TEXTURE_2D, t.a);
  bind(1, gl.TEXTURE_2D, t.b);
  bind(2, gl.TEXTURE_2D_ARRAY, t.geo);
  bind(3, gl.TEXTURE_2D, t.app);
  bind(4, gl.TEXTURE_2D, t.dirs);
  bind(5, gl.TEXTURE_2D, t.strokes);
  bind(6, gl.TEXTURE_2D, t.overlay);
}

function setUniforms(p, w, h, pick) {
  const u = (n) => gl.getUniformLocation(p, n);
  gl.uniformMatrix4fv(u('uViewProj'), false, viewProj(w, h, S.radius));
  gl.uniform1i(u('uR'), S.info.resolution);
  gl.uniform3fv(u('uEye'), cam.eye);
  gl.uniform3fv(u('uLight'), light);
  gl.uniform1f(u('uExposure'), exposure);
  gl.uniform1i(u('uPick'), pick);
  [['uTexA', 0], ['uTexB', 1], ['uGeo', 2], ['uApp', 3], ['uDirs', 4], ['uStrokes', 5], ['uOverlayTex', 6]]
    .forEach(([n, i]) => gl.uniform1i(u(n), i));
  gl.uniform1i(u('uStrokeCount'), S.textures.strokes ? Math.min(S.strokes.length, 1024) : 0);
  gl.uniform4fv(u('uBrush'), brush.on ? [...brush.at, brush.radius * S.info.unit] : [0, 0, 0, 0]);
  gl.uniform1i(u('uOverlay'), S.overlayOn ? 1 : 0);
  const info = S.info;
  if (info.btf) {
    const s = [0, 1, 2, 3].map((k) => info.samples[Math.min(k, info.samples.length - 1)]);
    gl.uniform1i(u('uNV'), info.views.length);
    gl.uniform1i(u('uNL'), info.lights.length);
    gl.uniform1i(u('uAppWidth'), 2048);
    gl.uniform4iv(u('uSW'), s.map((x) => x.width));
    gl.uniform4iv(u('uSH'), s.map((x) => x.height));
    gl.uniform4iv(u('uSLayers'), s.map((x) => x.layers));
    gl.uniform4iv(u('uSFirstLayer'), s.map((x) => x.first_layer));
    gl.uniform4iv(u('uSFirstTexel'), s.map((x) => x.first_texel));
    gl.uniform1f(u('uViewCosMax'), info.view_cos_max);
    gl.uniform1f(u('uLightCosMax'), info.light_cos_max);
  }
}

// Waits until the GPU has drawn: reads one pixel back (gl.finish does not
// wait in every browser).
function sync() {
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.readPixels(0, 0, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(4));
}

const BACKGROUND = [0.02, 0.02, 0.025];
const toSrgb = (v) => (v <= 0.0031308 ? v * 12.92 : 1.055 * Math.pow(v, 1 / 2.4) - 0.055);

// The canvas's size as the last whole frame records it (`studio.sizeDrawn`):
// a part drawn over a frame of another size would leave the rest wrong.
const canvasSize = () => `${canvas.width}x${canvas.height}`;

// Draws the frame, or with `rects` ([x, y, w, h] each, GL's origin) only
// those parts of it over the frame drawn before (the canvas keeps its
// pixels).
function draw(rects) {
  if (!S.program) return;
  if (rects) {
    gl.enable(gl.SCISSOR_TEST);
    for (const r of rects) {
      gl.scissor(r[0], r[1], r[2], r[3]);
      drawFrame();
    }
    gl.disable(gl.SCISSOR_TEST);
  } else {
    drawFrame();
    studio.sizeDrawn = canvasSize();
  }
  studio.frames++;
  studio.lastFrame = rects ? rects.map((r) => r.slice()) : null;
}

// The frame, within the scissor box when its test is on.
function drawFrame() {
  const w = canvas.width, h = canvas.height;
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  gl.viewport(0, 0, w, h);
  const bg = BACKGROUND.map((v) => toSrgb(v * Math.pow(2, exposure)));
  gl.clearColor(bg[0], bg[1], bg[2], 1);
  gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
  gl.enable(gl.DEPTH_TEST);
  gl.useProgram(S.program);
  bindTextures();
  setUniforms(S.program, w, h, 0);
  gl.bindVertexArray(S.vao);
  gl.drawArrays(gl.TRIANGLES, 0, S.count);
}

// The canvas's pixels (RGBA, GL's row order).
function canvasPixels() {
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  const px = new Uint8Array(canvas.width * canvas.height * 4);
  gl.readPixels(0, 0, canvas.width, canvas.height, gl.RGBA, gl.UNSIGNED_BYTE, px);
  return px;
}

let queued = false;
function redraw() {
  if (queued) return;
  queued = true;
  requestAnimationFrame(() => { queued = false; draw(); });
}

// A redraw of what lies within world spheres [centre, radius] only (the
// brush's ring and stroke marks as they move): the rest of the frame on
// the canvas stays right while the camera and the surface do not change.
let around = null;
function redrawAround(spheres) {
  if (queued) return;
  if (studio.sizeDrawn !== canvasSize()) { redraw(); return; }
  if (around) { around.push(...spheres); return; }
  around = spheres.slice();
  requestAnimationFrame(() => {
    const sp = around;
    around = null;
    // (a whole redraw queued meanwhile draws these too)
    if (!queued && sp.length) draw(damageRects(null, null, sp));
  });
}

// The world sphere holding the brush's ring.
const ringSphere = () => [brush.at.slice(), brush.radius * S.info.unit * 1.07];
// The world sphere a stroke point marks (as the shading's `uStrokes`).
const markSphere = (s) => [s.at, s.radius * S.info.unit];

// What lies under canvas pixel (x, y): the atlas uv and the surface point
// (scene units), or null. Two one-pixel passes into a float target.
function pickAt(x, y) {
  if (!S.pickFbo) {
    S.pickFbo = gl.createFramebuffer();
    S.pickTex = gl.createTexture();
    S.pickDepth = gl.createRenderbuffer();
  }
  const w = canvas.width, h = canvas.height;
  gl.bindTexture(gl.TEXTURE_2D, S.pickTex);
  if (S.pickSize !== `${w}x${h}`) {
    gl.texImage2D(gl.TEXTURE_2D, 0, gl.RGBA32F, w, h, 0, gl.RGBA, gl.FLOAT, null);
    gl.bindRenderbuffer(gl.RENDERBUFFER, S.pickDepth);
    gl.renderbufferStorage(gl.RENDERBUFFER, gl.DEPTH_COMPONENT24, w, h);
    S.pickSize = `${w}x${h}`;
  }
  gl.bindFramebuffer(gl.FRAMEBUFFER, S.pickFbo);
  gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, S.pickTex, 0);
  gl.framebufferRenderbuffer(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.RENDERBUFFER, S.pickDepth);
  gl.viewport(0, 0, w, h);
  gl.enable(gl.SCISSOR_TEST);
  const py = h - 1 - y;
  gl.scissor(x, py, 1, 1);
  gl.useProgram(S.program);
  bindTextures();
  gl.bindVertexArray(S.vao);
  const out = [];
  for (const pass of [1, 2]) {
    gl.clearColor(0, 0, 0, 0);
    gl.clear(gl.COLOR_BUFFER_BIT | gl.DEPTH_BUFFER_BIT);
    setUniforms(S.program, w, h, pass);
    gl.drawArrays(gl.TRIANGLES, 0, S.count);
    const px = new Float32Array(4);
    gl.readPixels(x, py, 1, 1, gl.RGBA, gl.FLOAT, px);
    out.push(px);
  }
  gl.disable(gl.SCISSOR_TEST);
  gl.bindFramebuffer(gl.FRAMEBUFFER, null);
  if (out[0][2] < 0.5) return null;
  return { uv: [out[0][0], out[0][1]], at: [out[1][0], out[1][1], out[1][2]] };
}

// ---------------------------------------------------------------- painting
const brush = { on: false, at: [0, 0, 0], radius: 0.05 };
let mode = 'view';

function radiusFromSlider() {
  // log scale from 2 texels to a third of the mesh (in the user's units)
  const lo = Math.max(S.texelSize * 2, 1e-9), hi = Math.max((S.radius / S.info.unit) / 3, lo * 2);
  const t = $('radius').value / 1000;
  brush.radius = lo * Math.pow(hi / lo, t);
  $('radius-text').textContent = `${brush.radius.toPrecision(3)} (${(brush.radius / S.texelSize).toFixed(1)} texels)`;
}

function uploadStrokes() {
  const n = Math.min(S.strokes.length, 1024);
  if (S.textures.strokes) gl.deleteTexture(S.textures.strokes);
  S.textures.strokes = null;
  if (n === 0) return;
  const d = new Float32Array(n * 4);
  S.strokes.slice(0, n).forEach((s, i) => d.set([...s.at, s.radius * S.info.unit], i * 4));
  S.textures.strokes = floatTexture(5, n, 1, d);
}

function addStrokePoint(hit) {
  const last = S.strokes[S.strokes.length - 1];
  if (last && len(sub(last.at, hit.at)) < 0.3 * brush.radius * S.info.unit) return;
  if (S.strokes.length >= 4096) return;
  S.strokes.push({ uv: hit.uv, at: hit.at, radius: brush.radius });
  uploadStrokes();
}

function setStatus(text, fraction) {
  $('message').textContent = text;
  $('bar').firstElementChild.style.width = `${Math.round((fraction || 0) * 100)}%`;
}

async function pollStatus() {
  try {
    const s = await api('/api/status');
    const j = s.job;
    if (j.running) setStatus(`${j.stage}${j.total ? ` ${j.done}/${j.total}` : ''}…`, j.total ? j.done / j.total : 0);
    $('undo').disabled = !s.can_undo || studio.busy;
    $('redo').disabled = !s.can_redo || studio.busy;
    return s;
  } catch (e) { return null; }
}

// Runs a change of the surface (paint, verbatim, undo, redo), showing
// progress, then reloads what the viewer draws.
// `erased`: world spheres [centre, radius] of stroke marks the change
// takes off.
async function change(path, body, erased) {
  if (studio.busy) return;
  studio.busy = true;
  const t0 = performance.now();
  const timer = setInterval(pollStatus, 200);
  try {
    setStatus(`${path.slice(5)}…`, 0);
    const r = await api(path, body || {});
    const overlay = S.overlayOn ? S.overlayBox : null;
    const sizeDrawn = studio.sizeDrawn;
    const t1 = performance.now();
    const onlyTexels = await loadSurface();
    const t2 = performance.now();
    // the frame on the canvas is of the current camera and canvas size
    // unless a redraw is queued: then only what the change repaints is
    // drawn again, else all
    const rects = onlyTexels && !queued && sizeDrawn === canvasSize()
      ? damageRects(S.changed.mask, overlay, (erased || []).concat(around || []))
      : null;
    const t3 = performance.now();
    draw(rects);
    if (S.changed) studio.lastChanged = [S.changed.box, S.changed.count];
    S.changed = null;
    sync();
    // milliseconds: the request, reloading the surface, bounding the
    // change, drawing
    studio.lastApplySteps = [t1 - t0, t2 - t1, t3 - t2, performance.now() - t3].map(Math.round);
    studio.lastApplyMs = performance.now() - t0;
    setStatus(`${r.report || 'done'} (${(studio.lastApplyMs / 1000).toFixed(2)} s)`, 1);
  } catch (e) {
    setStatus(`error: ${e.message}`, 0);
    studio.error = e.message;
  } finally {
    clearInterval(timer);
    studio.busy = false;
    await pollStatus();
    studio.changes++;
  }
}

async function apply() {
  if (!S.strokes.length) return;
  const strokes = S.strokes.map((s) => ({ uv: s.uv, radius: s.radius }));
  const erased = S.strokes.map(markSphere);
  S.strokes = [];
  uploadStrokes();
  await change('/api/paint', {
    strokes, sample: Number($('sample').value), transition: Number($('transition').value),
  }, erased);
}

let previewing = false;
async function preview(hit) {
  if (previewing || studio.busy) return;
  previewing = true;
  const t0 = performance.now();
  try {
    const buf = await api('/api/preview', { uv: hit.uv, angle: Number($('angle').value), sample: Number($('sample').value) });
    studio.lastPreviewFetchMs = performance.now() - t0;
    const head = new Uint32Array(buf, 0, 4);
    const [x0, y0, w, h] = head;
    const r = S.info.resolution;
    gl.activeTexture(gl.TEXTURE6);
    gl.bindTexture(gl.TEXTURE_2D, S.overlay);
    gl.pixelStorei(gl.UNPACK_ALIGNMENT, 1);
    if (S.overlayBox) {
      const [bx, by, bw, bh] = S.overlayBox;
      gl.texSubImage2D(gl.TEXTURE_2D, 0, bx, by, bw, bh, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(bw * bh * 4));
    }
    if (x0 + w <= r && y0 + h <= r) {
      gl.texSubImage2D(gl.TEXTURE_2D, 0, x0, y0, w, h, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array(buf, 16));
      S.overlayBox = [x0, y0, w, h];
      S.overlayOn = true;
    }
    draw();
    sync();
    studio.lastPreviewMs = performance.now() - t0;
    setStatus(`preview ${studio.lastPreviewMs.toFixed(0)} ms`, 0);
  } catch (e) {
    setStatus(`preview: ${e.message}`, 0);
  } finally {
    previewing = false;
  }
}

function fillSamples() {
  const sel = $('sample');
  const keep = sel.value;
  sel.innerHTML = '';
  S.samples.forEach((name, i) => {
    const o = document.createElement('option');
    o.value = i; o.textContent = name;
    sel.appendChild(o);
  });
  if (keep !== '' && Number(keep) < S.samples.length) sel.value = keep;
  $('what').textContent = `${S.info.btf ? 'BTF' : 'colour'}, atlas ${S.info.resolution}²`;
}

// ---------------------------------------------------------------- controls
function setMode(m) {
  mode = m;
  for (const k of ['view', 'brush', 'verbatim']) $(`mode-${k}`).classList.toggle('on', k === m);
  brush.on = false;
  S.overlayOn = false;
  redraw();
}

function orbit(dx, dy) {
  const off = sub(cam.eye, cam.target);
  const up = unit(cam.up);
  const rot = (v, axis, a) => {
    const c = Math.cos(a), s = Math.sin(a);
    return add(add(mul(v, c), mul(cross(axis, v), s)), mul(axis, dot(axis, v) * (1 - c)));
  };
  let o = rot(off, up, -dx * 0.008);
  const right = unit(cross(o, up));
  const o2 = rot(o, right, dy * 0.008);
  if (Math.abs(dot(unit(o2), up)) < 0.995) o = o2;
  cam.eye = add(cam.target, o);
}

function pan(dx, dy) {
  const f = unit(sub(cam.target, cam.eye));
  const s = unit(cross(f, cam.up));
  const u = cross(s, f);
  const k = (2 * len(sub(cam.eye, cam.target)) * Math.tan((cam.fov * Math.PI) / 360)) / canvas.height;
  const d = add(mul(s, -dx * k), mul(u, dy * k));
  cam.eye = add(cam.eye, d);
  cam.target = add(cam.target, d);
}

let drag = null;
canvas.addEventListener('contextmenu', (e) => e.preventDefault());
canvas.addEventListener('pointerdown', (e) => {
  canvas.setPointerCapture(e.pointerId);
  const act = e.button === 0 && !e.shiftKey && mode !== 'view' ? mode : (e.shiftKey || e.button === 1 ? 'pan' : 'orbit');
  drag = { x: e.offsetX, y: e.offsetY, act };
  if (act === 'brush') {
    const hit = pickAt(e.offsetX, e.offsetY);
    const n = S.strokes.length;
    if (hit) addStrokePoint(hit);
    redrawAround(S.strokes.slice(n).map(markSphere));
  }
  if (act === 'verbatim') {
    const hit = pickAt(e.offsetX, e.offsetY);
    if (hit) change('/api/verbatim', { uv: hit.uv, angle: Number($('angle').value), sample: Number($('sample').value) });
    drag = null;
  }
});
canvas.addEventListener('pointermove', (e) => {
  if (mode !== 'view') {
    const hit = pickAt(e.offsetX, e.offsetY);
    // what changes on the canvas: the ring where it was and where it is,
    // and the stroke's new marks
    const spheres = brush.on ? [ringSphere()] : [];
    const n = S.strokes.length;
    brush.on = !!hit && mode === 'brush';
    if (hit) brush.at = hit.at;
    if (hit && mode === 'verbatim' && !drag) preview(hit);
    if (drag && drag.act === 'brush' && hit) addStrokePoint(hit);
    if (brush.on) spheres.push(ringSphere());
    spheres.push(...S.strokes.slice(n).map(markSphere));
    if (mode === 'brush') redrawAround(spheres); else redraw();
  }
  if (!drag || drag.act === 'brush') return;
  const dx = e.offsetX - drag.x, dy = e.offsetY - drag.y;
  drag.x = e.offsetX; drag.y = e.offsetY;
  if (drag.act === 'orbit') orbit(dx, dy); else pan(dx, dy);
  redraw();
});
canvas.addEventListener('pointerup', () => {
  const wasBrush = drag && drag.act === 'brush';
  drag = null;
  if (wasBrush && $('auto').checked) apply();
});
canvas.addEventListener('wheel', (e) => {
  e.preventDefault();
  const off = sub(cam.eye, cam.target);
  cam.eye = add(cam.target, mul(off, Math.exp(e.deltaY * 0.001)));
  redraw();
}, { passive: false });

// The light widget: the hemisphere facing the viewer; its dot is the
// light's direction in the camera's right/up/back frame.
const lightCanvas = $('light');
function cameraFrame() {
  const back = unit(sub(cam.eye, cam.target));
  const right = unit(cross(cam.up, back));
  return { right, up: cross(back, right), back };
}
function drawLight() {
  const c = lightCanvas.getContext('2d');
  const R = 65, cx = 75, cy = 75;
  c.clearRect(0, 0, 150, 150);
  c.fillStyle = '#222'; c.beginPath(); c.arc(cx, cy, R, 0, 2 * Math.PI); c.fill();
  c.strokeStyle = '#555'; c.stroke();
  const f = cameraFrame();
  const x = dot(light, f.right), y = dot(light, f.up), z = dot(light, f.back);
  c.fillStyle = z >= 0 ? '#ffcc44' : 'transparent';
  c.strokeStyle = '#ffcc44';
  c.beginPath(); c.arc(cx + x * R, cy - y * R, 6, 0, 2 * Math.PI); c.fill(); c.stroke();
}
function lightFrom(e) {
  let x = (e.offsetX - 75) / 65, y = -(e.offsetY - 75) / 65;
  const r = Math.hypot(x, y);
  if (r > 1) { x /= r; y /= r; }
  const z = Math.sqrt(Math.max(0, 1 - x * x - y * y));
  const f = cameraFrame();
  light = unit(add(add(mul(f.right, x), mul(f.up, y)), mul(f.back, z)));
  drawLight();
  redraw();
}
let lightDrag = false;
lightCanvas.addEventListener('pointerdown', (e) => { lightDrag = true; lightCanvas.setPointerCapture(e.pointerId); lightFrom(e); });
lightCanvas.addEventListener('pointermove', (e) => { if (lightDrag) lightFrom(e); });
lightCanvas.addEventListener('pointerup', () => { lightDrag = false; });

$('mode-view').onclick = () => setMode('view');
$('mode-brush').onclick = () => setMode('brush');
$('mode-verbatim').onclick = () => setMode('verbatim');
$('radius').oninput = radiusFromSlider;
$('apply').onclick = apply;
$('clear').onclick = () => { S.strokes = []; uploadStrokes(); redraw(); };
$('undo').onclick = () => change('/api/undo');
$('redo').onclick = () => change('/api/redo');
$('exposure').oninput = () => { exposure = $('exposure').value / 10; redraw(); };
const named = async (path, what) => {
  const name = prompt(`${what}: a name (saved beside the surface)`);
  if (!name) return;
  try {
    const r = await api(path, { name });
    setStatus(`wrote ${r.saved || (r.written || []).join(', ')}`, 1);
  } catch (e) { setStatus(`error: ${e.message}`, 0); }
};
$('save').onclick = () => named('/api/save', 'Save the surface');
$('export').onclick = () => named('/api/export', 'Export glTF');

function resize() {
  const bare = hash.has('bare');
  const w = Number(hash.get('w')) || (bare ? 1280 : innerWidth);
  const h = Number(hash.get('h')) || (bare ? 720 : innerHeight);
  canvas.width = w; canvas.height = h;
  canvas.style.width = `${w}px`; canvas.style.height = `${h}px`;
  redraw();
}

// Frames per second over `n` frames drawn back to back.
studio.measureFps = (n) => {
  const t0 = performance.now();
  for (let i = 0; i < n; i++) { draw(); sync(); }
  return (n * 1000) / (performance.now() - t0);
};
studio.pick = (x, y) => pickAt(x, y);
// How many bytes of the canvas a whole redraw changes (0 when the frame on
// it, drawn whole or in part, is the whole frame).
studio.redrawDiff = () => {
  const before = canvasPixels();
  draw();
  const after = canvasPixels();
  let n = 0;
  for (let i = 0; i < after.length; i++) n += before[i] !== after[i];
  return n;
};
studio.apply = apply;
studio.change = change;
studio.preview = async (x, y) => { const hit = pickAt(x, y); if (hit) await preview(hit); return hit; };
studio.setMode = setMode;
studio.setRadius = (r) => { brush.radius = r; };

async function main() {
  if (!gl) throw new Error('this browser has no WebGL2');
  if (!gl.getExtension('EXT_color_buffer_float')) throw new Error('WebGL2 without EXT_color_buffer_float');
  if (hash.has('bare')) document.body.classList.add('bare');
  await loadMesh();
  await loadSurface();
  const unitScale = S.info.unit;
  const c = S.info.camera;
  const given = numbers(hash.get('camera'), 10);
  const src = given ? { eye: given.slice(0, 3), target: given.slice(3, 6), up: given.slice(6, 9), fov: given[9] } : c;
  cam.eye = mul(src.eye, unitScale); cam.target = mul(src.target, unitScale); cam.up = src.up; cam.fov = src.fov;
  const l = numbers(hash.get('light'), 3);
  if (l) light = unit(l);
  const ex = Number(hash.get('exposure'));
  if (Number.isFinite(ex)) exposure = ex;
  radiusFromSlider();
  addEventListener('resize', resize);
  resize();
  draw();
  sync();
  drawLight();
  await pollStatus();
  setStatus('ready: drag to orbit, shift-drag to pan, wheel to zoom', 0);
  studio.ready = true;
}
main().catch((e) => { studio.error = e.message; setStatus(`error: ${e.message}`, 0); });
